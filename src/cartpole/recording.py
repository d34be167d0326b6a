"""Videos of a saved agent: greedy episodes rendered with Gymnasium's ``rgb_array`` mode.

``render_episodes`` plays episode ``i`` from ``reset(seed=seed + i)`` of Gymnasium's own env, exactly
the start states ``cartpole.evaluation.evaluate`` uses for the same seed, so a video shows the episodes
of the evaluation report with that seed. Rendering draws off-screen (pygame surfaces, no window), so it
works on a machine without a display. ``write_video`` writes a GIF with Pillow, or an MP4 with
imageio-ffmpeg (the optional ``video`` extra). Files are written to a temp file and moved into place.
"""

from __future__ import annotations

import functools
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cartpole.core.errors import InputError
from cartpole.core.memory import SHARE, describe_bytes, fits_in_memory
from cartpole.envs import EnvInfo, as_env_info, env_info, fast_env_id, judged_env, registered_spec
from cartpole.envs.judged import make_judged_env
from cartpole.envs.registration import PIXEL_REFERENCE_IDS
from cartpole.evaluation import Policy
from cartpole.runs.atomic import replace_atomically

VIDEO_SUFFIXES = (".gif", ".mp4")
VIDEO_EXTRA = "pip install 'cartpole[video]'"
DEFAULT_FPS = 50
"""CartPole's ``metadata["render_fps"]``; used when an env does not say."""


class RecordingError(InputError, ValueError):
    """A video cannot be made: unknown format, missing optional dependency, or no rgb_array mode."""


@dataclass
class Recording:
    """Frames of consecutive greedy episodes, and what happened in each."""

    env_id: str
    fps: int
    frames: list[np.ndarray] = field(default_factory=list)
    """RGB uint8 frames [H, W, 3]: each episode's start state, then one frame per step."""
    seeds: list[int] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)


def _headless() -> None:
    """Keep pygame from looking for a display or a sound card, and from greeting on stdout."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


def render_episodes(
    policy: Policy,
    env_id: str | EnvInfo,
    episodes: int,
    seed: int,
    *,
    caption: bool = True,
    max_steps: int | None = None,
) -> Recording:
    """Play ``episodes`` greedy episodes from seeds ``seed, seed + 1, ...`` and keep every frame.

    With ``caption`` each frame carries a line: episode, seed, step and return so far.
    ``max_steps`` cuts each episode short (for previews); by default it runs to its end.
    """
    if episodes < 1:
        raise RecordingError(f"episodes must be >= 1, got {episodes}")
    _headless()
    import gymnasium as gym

    info = as_env_info(env_id)
    env_id = info.env_id
    gym_id = PIXEL_REFERENCE_IDS.get(fast_env_id(env_id)) or env_id.removeprefix("cartpole/")
    try:
        if info.configured:  # through its wrappers, with the env's own reward (as its verdict plays it)
            env = make_judged_env(judged_env(info), render_mode="rgb_array")
        else:
            env = gym.make(registered_spec(gym_id), render_mode="rgb_array")
        if gym_id != env_id.removeprefix("cartpole/"):  # a pixel env: its agent sees the pictures
            env = seen_as_pixels(env, env_id)
    except gym.error.DependencyNotInstalled as err:
        raise RecordingError(f"rendering {gym_id} needs pygame: pip install pygame-ce ({err})") from err
    except (gym.error.Error, TypeError, ValueError) as err:
        raise RecordingError(f"{gym_id} cannot render rgb_array frames: {err}") from err
    fps = int(env.metadata.get("render_fps") or DEFAULT_FPS)
    recording = Recording(env_id=gym_id, fps=fps)
    try:
        env.reset(seed=seed)
        limits = [n for n in (max_steps, env.spec.max_episode_steps if env.spec else None) if n is not None]
        check_frames_fit(episodes, min(limits, default=None), env)
        for i in range(episodes):
            episode_seed = seed + i
            observation, _ = env.reset(seed=episode_seed)
            total, steps = 0.0, 0
            label = f"episode {i + 1}/{episodes}  seed {episode_seed}"
            recording.frames.append(_frame(env, f"{label}  step 0  return 0" if caption else None))
            while max_steps is None or steps < max_steps:
                action = int(np.asarray(policy.act(np.asarray(observation)[None])).reshape(-1)[0])
                observation, reward, terminated, truncated, _ = env.step(action)
                total += float(reward)
                steps += 1
                text = f"{label}  step {steps}  return {total:g}" if caption else None
                recording.frames.append(_frame(env, text))
                if terminated or truncated:
                    break
            recording.seeds.append(episode_seed)
            recording.returns.append(total)
            recording.lengths.append(steps)
    except gym.error.DependencyNotInstalled as err:
        raise RecordingError(f"rendering {gym_id} needs pygame: pip install pygame-ce ({err})") from err
    finally:
        env.close()
    return recording


def seen_as_pixels(env: Any, pixel_env_id: str) -> Any:
    """Gymnasium's CartPole ``env`` observed as ``pixel_env_id``'s frame stacks (its ``rgb_array``
    pictures, preprocessed as the pixel env's): what a pixel agent's verdicts show it too."""
    from cartpole.envs.pixels import GymnasiumPixels  # numba kernels: only for pixel agents

    stack, height, width = env_info(pixel_env_id).obs_shape
    return GymnasiumPixels(env, frame_size=(height, width), stack=stack)


def check_frames_fit(episodes: int, steps: int | None, env: Any) -> None:
    """RecordingError, before any episode is played, when every frame of ``episodes`` episodes of up to
    ``steps`` steps (None: no limit known, no check) would not fit in memory."""
    if steps is None:
        return
    frames = episodes * (steps + 1)
    needed = frames * np.asarray(env.render()).nbytes
    fits, free = fits_in_memory(needed)
    if not fits and free is not None:
        fit = max(1, int(SHARE * free // (needed // episodes)))
        raise RecordingError(
            f"{episodes:,} episodes of up to {steps:,} steps would hold {frames:,} frames, about "
            f"{describe_bytes(needed)} in memory, but {describe_bytes(free)} is available: record at most "
            f"{fit:,} episodes, or cut them shorter with --max-steps"
        )


def _frame(env: Any, caption: str | None) -> np.ndarray:
    image = np.asarray(env.render(), dtype=np.uint8)
    return image if caption is None else draw_caption(image, caption)


@functools.lru_cache(maxsize=4)
def _font(size: int) -> Any:
    """Pillow's bundled font at ``size`` pixels (loading it costs more than drawing a frame)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has one bitmap size only
        return ImageFont.load_default()


def draw_caption(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in a white band along its top edge."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    size = max(10, image.shape[0] // 25)
    font = _font(size)
    left, top, _, bottom = draw.textbbox((0, 0), text, font=font)
    pad = max(3, size // 3)
    draw.rectangle((0, 0, image.shape[1], bottom - top + 2 * pad), fill=(255, 255, 255))
    draw.text((pad - left, pad - top), text, fill=(40, 40, 40), font=font)
    return np.asarray(picture)


def check_video_path(path: Path) -> None:
    """Raise RecordingError now (before any episode is played) if ``path`` cannot be written."""
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise RecordingError(f"cannot write {path}: use a .gif or .mp4 file name")
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise RecordingError(
                f"writing MP4 needs imageio and imageio-ffmpeg: {VIDEO_EXTRA} (or write a .gif)"
            ) from None
    check_writable(path)


def check_writable(path: Path) -> None:
    """RecordingError naming ``path`` unless a file can be written there: its nearest existing folder
    must be a folder we may write in (a file is written there and removed, which also finds a
    read-only disk). Its missing folders are made only when the video is written."""
    folder = next(p for p in [path.parent, *path.parent.parents] if p.exists() or p == p.parent)
    if not folder.is_dir():
        raise RecordingError(f"{path}: {folder} is a file, not a folder; choose another file name")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise RecordingError(
            f"{path}: cannot write in {folder} ({err.strerror or err}); choose another file name"
        ) from None


def write_video(frames: list[np.ndarray], path: Path | str, fps: int = DEFAULT_FPS) -> Path:
    """Write ``frames`` as a looping GIF (Pillow) or an MP4 (imageio-ffmpeg), atomically."""
    path = Path(path)
    check_video_path(path)
    if not frames:
        raise RecordingError("no frames to write")
    if path.suffix.lower() == ".gif":
        replace_atomically(path, lambda tmp: _write_gif(frames, tmp, fps), suffix=path.suffix)
    else:
        replace_atomically(path, lambda tmp: _write_mp4(frames, tmp, fps), suffix=path.suffix)
    return path


def _write_gif(frames: list[np.ndarray], path: Path, fps: int) -> None:
    from PIL import Image

    # One shared palette: the frames are a few flat colours, and a per-frame palette would flicker.
    first = Image.fromarray(frames[0]).quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    images = [first] + [
        Image.fromarray(f).quantize(palette=first, dither=Image.Dither.NONE) for f in frames[1:]
    ]
    # GIF delays are in 1/100 s; keep every frame (no merging of equal ones) so the count is exact.
    duration = max(2, round(100 / fps)) * 10
    images[0].save(
        path,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=duration,
        loop=0,
        optimize=False,
        disposal=1,
    )


def _write_mp4(frames: list[np.ndarray], path: Path, fps: int) -> None:
    import imageio.v2 as imageio

    # H.264 in yuv420p (what browsers and phones play) needs even sizes; 8-pixel blocks keep 600x400.
    writer = imageio.get_writer(
        path, format="FFMPEG", fps=fps, codec="libx264", quality=7, macro_block_size=8
    )
    try:
        for frame in frames:
            writer.append_data(frame)
    finally:
        writer.close()


def default_video_path(checkpoint: Path, seed: int, suffix: str = ".gif") -> Path:
    """``<run name>-<checkpoint>-seed<S>.gif`` in the current folder (run folders are only read)."""
    checkpoint = Path(checkpoint)
    name = f"{checkpoint.stem}-seed{seed}{suffix}"
    if checkpoint.parent.name == "checkpoints" and (checkpoint.parent.parent / "config.json").is_file():
        name = f"{checkpoint.parent.parent.name}-{name}"
    return Path(name)


__all__ = [
    "VIDEO_EXTRA",
    "VIDEO_SUFFIXES",
    "Recording",
    "RecordingError",
    "check_video_path",
    "default_video_path",
    "draw_caption",
    "render_episodes",
    "write_video",
]
