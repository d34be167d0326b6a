"""Greedy episodes of any saved agent, animated inline in a notebook.

On CartPole the episodes play on Gymnasium's own env and are drawn on a canvas by the web app's own
drawing code (``web/static/cartpole-draw.js``), with the policy's per-action scores as bars under
the cart: a few kilobytes of states, animated in the browser. A pixel agent
(``cartpole/CartPolePixels-v1``) plays the same CartPole, seeing frame stacks drawn from its states
(:mod:`cartpole.web.agent_view`), and its frames are drawn beside the scene
(``web/static/frame-stack-draw.js``). Where scripts do not run (a notebook shown on a code host) or
for other envs, ``mode="gif"`` embeds the rendered frames as an animated
GIF (Gymnasium's ``rgb_array`` frames, through :mod:`cartpole.recording`).
"""

from __future__ import annotations

import base64
import html
import io
import json
import uuid
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from cartpole.core.errors import InputError
from cartpole.envs import env_info
from cartpole.evaluation import Policy, act_once
from cartpole.web.agent_view import FrameStacker, PixelView, view_json

Mode = Literal["auto", "canvas", "gif"]

MAX_EPISODES = 20
"""The most episodes one animation holds (each is kept in the notebook)."""

GIF_WIDTH = 300
"""Pixels across of a GIF's frames (Gymnasium renders 600): small enough that a 500-step episode
embeds in a notebook."""

GIF_MAX_FPS = 25
"""A GIF keeps at most this many frames a second of play (every other frame of CartPole's 50)."""


class ShowError(InputError, ValueError):
    """What was asked to be shown cannot be: a bad count, mode or env."""


@dataclass
class PlayedEpisode:
    """One greedy episode: the observations (one more than the actions), actions and scores."""

    seed: int
    observations: list[list[float]]
    actions: list[int]
    scores: list[list[float]] | None
    episode_return: float
    frames: list[np.ndarray] | None = None
    """A pixel agent's frame of each state (what it saw, stacked); None for state agents."""


@dataclass
class Animation:
    """Greedy episodes of one policy, shown inline by a notebook (``_repr_html_``)."""

    env_id: str
    mode: Literal["canvas", "gif"]
    score_label: str
    episodes: list[PlayedEpisode] = field(default_factory=list)
    limits: dict[str, float] = field(default_factory=dict)
    gif: bytes | None = None
    view: PixelView | None = None
    """The shape of a pixel agent's observations (its frames are in the episodes); None otherwise."""

    @property
    def returns(self) -> list[float]:
        return [e.episode_return for e in self.episodes]

    def __repr__(self) -> str:
        returns = ", ".join(f"{r:g}" for r in self.returns)
        return f"<Animation of {len(self.episodes)} {self.env_id} episodes ({self.mode}), returns {returns}>"

    def _repr_html_(self) -> str:
        if self.mode == "gif":
            assert self.gif is not None
            data = base64.b64encode(self.gif).decode("ascii")
            caption = html.escape(f"{self.env_id}: returns {', '.join(f'{r:g}' for r in self.returns)}")
            image = f'<img src="data:image/gif;base64,{data}" alt="{caption}">'
            return f"<figure>{image}<figcaption>{caption}</figcaption></figure>"
        return canvas_html(self)


def show(
    agent: Policy | str | Path,
    env: str | None = None,
    *,
    episodes: int = 3,
    seed: int = 0,
    mode: Mode = "auto",
) -> Animation:
    """Play ``episodes`` greedy episodes of ``agent`` (a policy, a checkpoint file or a run folder)
    from seeds ``seed, seed + 1, ...`` on Gymnasium's own ``env`` (default: the checkpoint's env,
    else CartPole-v1), for a notebook to animate. ``mode``: ``canvas`` (CartPole: drawn in the
    browser, with the per-action scores; a pixel agent's frame stacks beside the scene), ``gif``
    (any state env: rendered frames), ``auto`` (canvas on CartPole and its pixels, else gif)."""
    if not 1 <= episodes <= MAX_EPISODES:
        raise ShowError(f"episodes must be between 1 and {MAX_EPISODES}, got {episodes}")
    if mode not in ("auto", "canvas", "gif"):
        raise ShowError(f"mode must be auto, canvas or gif, got {mode!r}")
    policy, env_id, score_label = resolve_agent(agent, env)
    info = env_info(env_id)
    drawn = info.is_cartpole or info.pixels_of is not None  # a pixel env's scene is CartPole's
    if mode == "canvas" and not drawn:
        raise ShowError(f"mode canvas draws CartPole only; show {env_id} with mode='gif'")
    if mode == "gif" and info.pixels_of:  # the recorder plays state envs only
        raise ShowError(f"mode gif records state envs only; show {env_id} with mode='canvas'")
    chosen: Literal["canvas", "gif"] = "canvas" if mode != "gif" and drawn else "gif"
    if chosen == "gif":
        return gif_animation(policy, env_id, episodes, seed, score_label)
    played, limits = play_cartpole(policy, env_id, episodes, seed)
    return Animation(env_id, "canvas", score_label, played, limits, view=PixelView.of(env_id))


def resolve_agent(agent: Policy | str | Path, env: str | None) -> tuple[Policy, str, str]:
    """The policy to show, the env to show it on and what its scores are called."""
    if isinstance(agent, str | Path):
        from cartpole.agents.registry import get_agent, open_policy

        opened = open_policy(agent, env)
        spec = get_agent(opened.checkpoint.agent)
        return opened.policy, env or opened.checkpoint.env_id, spec.score_label
    if not callable(getattr(agent, "act", None)):
        raise ShowError(f"cannot show a {type(agent).__name__}: pass a policy, a checkpoint or a run folder")
    return agent, env or "CartPole-v1", "scores"


def play_cartpole(
    policy: Policy, env_id: str, episodes: int, seed: int
) -> tuple[list[PlayedEpisode], dict[str, float]]:
    """Greedy episodes on Gymnasium's own CartPole, each from ``reset(seed=seed + i)`` as
    :func:`~cartpole.evaluation.evaluate` starts it, and the limits the drawing needs. On a pixel env,
    the CartPole it shows, the policy seeing frame stacks drawn from its states."""
    import gymnasium as gym

    view = PixelView.of(env_id)
    env = gym.make(env_info(env_id).pixels_of or env_id.removeprefix("cartpole/"))
    scored = callable(getattr(policy, "scores", None))
    try:
        played = [
            play_one(env, policy, seed + i, scored, FrameStacker(view) if view else None)
            for i in range(episodes)
        ]
        cartpole: Any = env.unwrapped
        limits = {
            "x_threshold": float(cartpole.x_threshold),
            "theta_threshold": float(cartpole.theta_threshold_radians),
            "length": float(cartpole.length),
            "fps": round(1.0 / float(cartpole.tau), 6),
        }
    finally:
        env.close()
    return played, limits


def play_one(
    env: Any, policy: Policy, seed: int, scored: bool, stacker: FrameStacker | None = None
) -> PlayedEpisode:
    """One greedy episode; with ``stacker`` the policy sees the frame stacks of the env's states."""
    observation, _ = env.reset(seed=seed)
    seen = stacker.reset(env.unwrapped.state) if stacker else observation
    observations, actions, scores, total = [observation.tolist()], [], [], 0.0
    while True:
        action, row = act_once(policy, seen)
        if row is not None:
            scores.append(row.tolist())
        observation, reward, terminated, truncated, _ = env.step(action)
        seen = stacker.push(env.unwrapped.state) if stacker else observation
        observations.append(observation.tolist())
        actions.append(action)
        total += float(reward)
        if terminated or truncated:
            frames = stacker.frames if stacker else None
            return PlayedEpisode(seed, observations, actions, scores if scored else None, total, frames)


def gif_animation(policy: Policy, env_id: str, episodes: int, seed: int, score_label: str) -> Animation:
    """The episodes rendered by Gymnasium (captioned frames) and encoded as one looping GIF."""
    from cartpole.recording import render_episodes

    recording = render_episodes(policy, env_id, episodes, seed)
    stride = max(1, round(recording.fps / GIF_MAX_FPS))
    fps = recording.fps / stride
    played = [
        PlayedEpisode(s, [], [], None, float(r))
        for s, r in zip(recording.seeds, recording.returns, strict=True)
    ]
    gif = encode_gif(recording.frames[::stride], fps)
    return Animation(env_id, "gif", score_label, played, {"fps": fps}, gif)


def encode_gif(frames: list[np.ndarray], fps: float) -> bytes:
    """``frames`` (RGB arrays) scaled to :data:`GIF_WIDTH` across, as a looping GIF."""
    from PIL import Image

    images = []
    for frame in frames:
        image = Image.fromarray(frame)
        height = round(image.height * GIF_WIDTH / image.width)
        small = image.resize((GIF_WIDTH, height), Image.Resampling.BILINEAR)
        images.append(small.convert("P", dither=Image.Dither.NONE))
    buffer = io.BytesIO()
    duration = round(1000 / fps)
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=duration, loop=0)
    return buffer.getvalue()


def static_text(package: str, name: str) -> str:
    """A script of ``package``'s static folder: the web app's CartPole drawing
    (``CartPoleDraw.draw``, shared so both look the same) or the notebook's player."""
    return resources.files(package).joinpath("static", name).read_text(encoding="utf-8")


def canvas_html(animation: Animation) -> str:
    """A canvas, score bars and a caption, animated by a script that holds the episodes: each
    output its own element id and its own function scope, so several can share a notebook."""
    uid = f"cartpole-show-{uuid.uuid4().hex[:12]}"
    data = {
        "env_id": animation.env_id,
        "score_label": animation.score_label,
        "limits": animation.limits,
        "episodes": [
            {
                "seed": e.seed,
                "states": np.round(e.observations, 5).tolist(),  # far below a pixel
                "actions": e.actions,
                "scores": None if e.scores is None else np.round(e.scores, 4).tolist(),
                "return": e.episode_return,
                "view": view_json(animation.view, e.frames) if animation.view and e.frames else None,
            }
            for e in animation.episodes
        ],
    }
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    scripts = {
        "__DRAW__": static_text("cartpole.web", "cartpole-draw.js"),
        "__VIEW__": static_text("cartpole.web", "frame-stack-draw.js"),
        "__PLAYER__": static_text("cartpole.notebook", "player.js"),
    }
    width = "900px" if animation.view else "600px"  # room for the frames beside the scene
    page = PLAYER_HTML.replace("__UID__", uid).replace("__WIDTH__", width)
    for marker, text in scripts.items():
        page = page.replace(marker, text)
    return page.replace("__DATA__", payload)


PLAYER_HTML = """<div id="__UID__" class="cartpole-show" style="max-width:__WIDTH__;font:13px sans-serif">
<div style="display:flex;gap:10px;align-items:flex-start">
<canvas class="cp-scene" style="flex:2;min-width:0;width:100%;display:block;border-radius:6px"></canvas>
<div class="cp-view" style="flex:1;min-width:0;display:none">
<div style="font-weight:600">what the agent sees</div>
<canvas style="width:100%;display:block;image-rendering:pixelated"></canvas>
<div style="color:#5d6678">its last frames, oldest first</div></div>
</div>
<div class="cp-bars" style="display:flex;gap:8px;margin:6px 0"></div>
<div class="cp-caption" style="color:#3b4357"></div>
<noscript>This animation needs JavaScript: show it with mode="gif" where scripts do not run.</noscript>
</div>
<script>
(function (ROOT_ID, DATA) {
__DRAW__
__VIEW__
__PLAYER__
})("__UID__", __DATA__);
</script>"""
"""The output: the drawing code and the player in one function scope (so several outputs can share
a notebook), called with this output's element id and its episodes."""


__all__ = ["Animation", "PlayedEpisode", "ShowError", "show"]
