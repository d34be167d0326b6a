"""What a pixel agent sees, for the Watch page and the notebook's ``show()``: its frame stacks.

A run on a pixel env (``cartpole/CartPolePixels-v1``, -v0) acts on stacks of gray frames. Watch and
``show()`` play its episodes from CartPole states (our stepper, or Gymnasium's CartPole), so the
frames are drawn here from each step's state with the env's own renderer
(:class:`~cartpole.envs.pixels.PixelRenderer`, its frame size, the episode's physics) and stacked as
:class:`~cartpole.envs.pixels.CartPolePixelsEnv` stacks them: at the start the whole stack is the
first frame, then each step drops the oldest. Nudges and changed physics therefore show in the
frames exactly as they would in the env.

The pages get only each step's newest frame (:func:`view_json`); the stack at step t is frames
``t - stack + 1 .. t``, oldest first, with the first frame standing in before step 0
(:func:`stacks_of`, which the page's ``FrameStackDraw.stackAt`` mirrors).
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.envs.params import CartPoleParams


class ViewError(ValueError):
    """The agent's frames cannot be drawn for these physics (e.g. a pole too long for the frame)."""


@dataclass(frozen=True)
class PixelView:
    """The shape of a pixel env's observations: ``stack`` frames of ``frame_size`` (height, width)."""

    stack: int
    frame_size: tuple[int, int]

    @classmethod
    def of(cls, env_id: str) -> PixelView | None:
        """The view of a pixel env id (from its registered observation space); None for any other
        env, whose agents see states."""
        try:
            info = env_info(env_id)
        except ValueError:
            return None
        if not info.pixels_of or len(info.obs_shape) != 3:
            return None
        stack, height, width = info.obs_shape
        return cls(stack, (height, width))


class FrameStacker:
    """The observations a pixel env hands its agent, one step at a time, from CartPole states.

    ``reset(state)`` fills the stack with the state's frame; ``push(state)`` drops the oldest frame
    and appends the new one. ``frames`` keeps every step's newest frame (what :func:`view_json`
    sends). ``params`` sets the drawn pole length and track width, as the env's ``set_params`` does.
    """

    def __init__(self, view: PixelView, params: CartPoleParams | None = None):
        from cartpole.envs.pixels import FrameStack, PixelRenderer  # numba kernels: only for pixel runs

        self.view = view
        try:
            self._renderer = PixelRenderer(view.frame_size, params)
        except ConfigError as err:  # the pole reaches above the frame's band of rows
            length = (params or CartPoleParams()).length
            height, width = view.frame_size
            raise ViewError(
                f"the agent's {height}x{width} frames cannot show a pole of half-length {length:g} m (it "
                f"reaches above them): choose a shorter pole (the default is {CartPoleParams().length:g} m)"
            ) from err
        self._stack = FrameStack(view.stack, view.frame_size)
        self.frames: list[NDArray[np.uint8]] = []

    def frame(self, state: NDArray[Any]) -> NDArray[np.uint8]:
        """One state's frame ``[height, width]`` uint8."""
        frame: NDArray[np.uint8] = self._renderer.render(np.asarray(state, dtype=np.float64)[None])[0]
        return frame

    def reset(self, state: NDArray[Any]) -> NDArray[np.uint8]:
        """The first observation of an episode: its first frame, ``stack`` times."""
        frame = self.frame(state)
        self.frames = [frame]
        return self._stack.start(frame)

    def push(self, state: NDArray[Any]) -> NDArray[np.uint8]:
        """The observation after a step that reached ``state``."""
        frame = self.frame(state)
        self.frames.append(frame)
        return self._stack.push(frame)


def stacks_of(frames: NDArray[np.uint8], stack: int) -> NDArray[np.uint8]:
    """Every step's observation ``[T, stack, height, width]`` from its newest frames ``[T, height,
    width]``: step t sees frames ``t - stack + 1 .. t``, the first frame repeated before step 0."""
    frames = np.asarray(frames)
    steps = np.arange(len(frames))[:, None] + np.arange(-stack + 1, 1)[None, :]
    return frames[np.maximum(steps, 0)]


def view_json(view: PixelView, frames: list[NDArray[np.uint8]]) -> dict[str, Any]:
    """The agent's view for a page: its shape and each step's newest frame as base64 of the uint8
    pixels, row-major (a 501-frame episode of 30x100 frames is 2 MB of text, against 6 MB for whole
    stacks or 8 MB as JSON numbers)."""
    height, width = view.frame_size
    return {
        "stack": view.stack,
        "height": height,
        "width": width,
        "frames": [base64.b64encode(np.ascontiguousarray(f).tobytes()).decode("ascii") for f in frames],
    }


def decode_frames(view: dict[str, Any]) -> NDArray[np.uint8]:
    """The frames ``[T, height, width]`` of a :func:`view_json` payload."""
    shape = (int(view["height"]), int(view["width"]))
    rows = [np.frombuffer(base64.b64decode(text), dtype=np.uint8).reshape(shape) for text in view["frames"]]
    return np.stack(rows) if rows else np.zeros((0, *shape), dtype=np.uint8)


__all__ = ["FrameStacker", "PixelView", "ViewError", "decode_frames", "stacks_of", "view_json"]
