"""``cartpole record``: a GIF or MP4 of a saved agent's greedy episodes, made without a display."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cartpole.envs import EnvInfo


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "record",
        help="record a video (GIF or MP4) of a saved agent",
        description=(
            "Play greedy episodes of a saved agent (a checkpoint .pt file, or a run folder: its best "
            "checkpoint) on Gymnasium's own env and write them as a video. Episode i starts from "
            "reset(seed=S+i), the same start states as `cartpole eval --seed S`. No display is needed."
        ),
    )
    parser.add_argument("path", metavar="RUN_OR_CHECKPOINT", help="run folder or checkpoint file")
    parser.add_argument("--episodes", type=int, default=1, metavar="N", help="episodes (default: 1)")
    parser.add_argument(
        "--out",
        metavar="FILE",
        help="FILE.gif (Pillow) or FILE.mp4 (needs the video extra); "
        "default: ./<run>-<checkpoint>-seed<S>.gif",
    )
    parser.add_argument(
        "--seed", type=int, metavar="S", help="episode i starts from reset(seed=S+i); default: a fresh seed"
    )
    parser.add_argument("--fps", type=int, metavar="F", help="frames per second (default: the env's, 50)")
    parser.add_argument(
        "--max-steps", type=int, metavar="N", help="cut each episode after N steps (default: play it out)"
    )
    parser.add_argument("--no-caption", action="store_true", help="no episode/step/return line on frames")
    parser.set_defaults(run=run)


def load_saved_policy(path_text: str) -> tuple[Path, Any, EnvInfo]:
    """(checkpoint path, greedy policy, env as configured) of a run folder or checkpoint file."""
    from cartpole.agents.registry import open_policy

    opened = open_policy(path_text)
    tell_skipped(opened.skipped, opened.path)
    return opened.path, opened.policy, opened.env


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cartpole.cli.errors import UsageError
    from cartpole.core.seeding import fresh_eval_seed
    from cartpole.recording import (
        RecordingError,
        check_video_path,
        default_video_path,
        render_episodes,
        write_video,
    )

    if args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if args.fps is not None and args.fps < 1:
        raise UsageError(f"--fps must be >= 1, got {args.fps}")
    if args.max_steps is not None and args.max_steps < 1:
        raise UsageError(f"--max-steps must be >= 1, got {args.max_steps}")
    path, policy, env = load_saved_policy(args.path)
    seed = fresh_eval_seed() if args.seed is None else args.seed
    out = Path(args.out) if args.out else default_video_path(path, seed)
    console = Console(stderr=True)
    try:
        check_video_path(out)  # fail before playing, not after
        with console.status(f"playing {args.episodes} episode(s) of {env.label} ..."):
            recording = render_episodes(
                policy,
                env,
                args.episodes,
                seed,
                caption=not args.no_caption,
                max_steps=args.max_steps,
            )
        with console.status(f"writing {len(recording.frames)} frames to {out} ..."):
            write_video(recording.frames, out, args.fps or recording.fps)
    except RecordingError as err:
        raise UsageError(str(err)) from None
    returns = ", ".join(f"{r:g}" for r in recording.returns)
    print(
        f"wrote {out}: {args.episodes} episode(s) of {env.label} from seed {seed} "
        f"(returns {returns}), {len(recording.frames)} frames"
    )
    return 0


EVAL_VIDEO_EPISODES = 3
"""`cartpole eval --render` films the first few episodes of the evaluation, not all of them."""


def eval_video_path(checkpoint: Path, seed: int, out_text: str) -> Path:
    """Where ``cartpole eval --render`` writes its video, checked before any episode is played
    (UsageError naming it if it cannot be written)."""
    from cartpole.cli.errors import UsageError
    from cartpole.recording import RecordingError, check_video_path

    out = Path(out_text) if out_text else default_eval_video_path(checkpoint, seed)
    try:
        check_video_path(out)
    except RecordingError as err:
        raise UsageError(str(err)) from None
    return out


def write_eval_video(policy: Any, env_id: str | EnvInfo, seed: int, episodes: int, out: Path) -> Path:
    """The video of ``cartpole eval --render``: its first episodes, from the report's own seeds."""
    from cartpole.cli.errors import UsageError
    from cartpole.recording import RecordingError, render_episodes, write_video

    try:
        recording = render_episodes(policy, env_id, min(episodes, EVAL_VIDEO_EPISODES), seed)
        return write_video(recording.frames, out, recording.fps)
    except RecordingError as err:
        raise UsageError(str(err)) from None


def default_eval_video_path(checkpoint: Path, seed: int) -> Path:
    from cartpole.recording import default_video_path

    return default_video_path(checkpoint, seed)


def tell_skipped(skipped: list[str], used: Path) -> None:
    """Say on stderr which checkpoints of a run were unusable, and which one is used instead."""
    for problem in skipped:
        print(f"warning: {problem}", file=sys.stderr)
    if skipped:
        print(f"warning: using {used} instead", file=sys.stderr)
