"""CartPole from pixels: Gymnasium's picture of the cart-pole, small and gray, drawn fast.

## What an observation is

Gymnasium's ``CartPole-v1`` with ``render_mode="rgb_array"`` draws a 600x400 RGB picture: a white
screen, a black track line, a black cart, a brown pole and a blue-gray axle. An observation here is
that picture after :func:`preprocess_frames`, the one preprocessing of this module:

1. gray levels, ``0.299 R + 0.587 G + 0.114 B`` (ITU-R BT.601 luma, as Pillow's ``convert("L")``
   and OpenCV's ``RGB2GRAY`` compute them);
2. the full width of the screen and a band of rows around the cart and pole (the rows above the
   upright pole's tip and below the cart are always white), cut so that output pixels stay square:
   a ``(height, width)`` frame shows ``600 / width`` screen pixels per output pixel in both
   directions;
3. an area (box) average of the screen pixels under each output pixel, rounded to uint8.

The last ``stack`` frames, oldest first, make an observation ``[stack, height, width]`` uint8.

## Default: 30x100 gray frames, 4 deep

At 600/100 = 6 screen pixels per output pixel, the 180 screen rows around the scene (rows 154-334,
out of 400) become 30 rows, so the frame is 30x100 = 3,000 pixels. The pole is 1.7 pixels wide and
21 long, the cart 8.5x5: the angle shows in the pole's anti-aliased edges to a fraction of a
degree, and one step's motion of cart or pole tip (0.2-2 screen pixels at typical speeds) changes
gray levels. The full screen at a similar pixel count (40x60, 48x72) spends 55% of its pixels on
rows that are always white and draws the pole 1 pixel wide (40x60). ``python
benchmarks/renderer.py --probe`` trains one small CNN per size, for the same CPU time, to read the
state from two stacked frames: the crops around the scene read the angle at least as well as the
whole screen, and among the crops the differences are within one seed's noise. 30x100 also has a whole
number of screen pixels per output pixel, so its box average is Pillow's too. Four frames give
velocities (differences) and accelerations (second differences), as in DQN's Atari stack.

Sizes are parameters: ``frame_size=(height, width)`` with 16 <= height <= 200, width <= 600 and
width/height between 1.5 (the whole screen) and 4 (150 rows around the scene); ``stack`` from 1 to
8. Anything else raises :class:`~cartpole.core.errors.ConfigError` at construction.

## The renderer

:class:`PixelRenderer` draws states ``[N, 4]`` straight at the small size, without drawing the
600x400 picture: each output pixel gets the areas of the cart, pole, axle and line that fall in it
(see :mod:`cartpole.envs._pixel_kernels`; numba, compiled on first use and cached on disk), far
faster than Gymnasium's drawing (benchmarks/README.md#renderer). Against Gymnasium's own
pictures through :func:`preprocess_frames`, at 30x100 on random states: 0.02 gray levels apart on
average (0.25 over the pixels that are not plain background), at most 9 levels within the
termination bounds and 12 beyond them, on edges: pygame's anti-aliased outlines are modelled, not
copied, and differ most at the pole's corners and where the cart leaves the screen. Coarser frames
differ less; finer ones more at single edge pixels (at most about 25 levels at 60x200, and about
120 at the full 200x600, where an output pixel is one screen pixel). ``tests/test_pixels.py``
checks the mean and the largest difference on states in and beyond the termination bounds.

## The envs

- :class:`CartPolePixelsVectorEnv`: ``num_envs`` cart-poles stepped by
  :class:`~cartpole.envs.fast.CartPoleVectorEnv` (the same physics, seeds, rewards and next-step
  autoreset), observed as frame stacks ``[num_envs, stack, height, width]``;
- :class:`CartPolePixelsEnv`: one, stepped by :class:`~cartpole.envs.fast.CartPoleEnv`;
  ``render_mode="rgb_array"`` draws Gymnasium's 600x400 picture through it;
- :class:`GymnasiumPixels`: Gymnasium's own env (made with ``render_mode="rgb_array"``), observed the
  same way through its own pictures: the reference for verdicts.

On reset, and on an env's autoreset step, the whole stack is filled with the first frame. The state
stays reachable: ``states`` (vector env) and ``state`` (single env) read it; ``simulator`` is the
state simulator itself.

```python
>>> import gymnasium as gym
>>> import cartpole  # registers cartpole/CartPolePixels-v1 and -v0
>>> envs = gym.make_vec("cartpole/CartPolePixels-v1", num_envs=8, vectorization_mode="vector_entry_point")
>>> observations, _ = envs.reset(seed=0)
>>> observations.shape, observations.dtype
((8, 4, 30, 100), dtype('uint8'))
>>> reference = GymnasiumPixels(gym.make("CartPole-v1", render_mode="rgb_array"))

```
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from types import ModuleType
from typing import Any, SupportsFloat, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import ArrayLike, DTypeLike, NDArray

from cartpole.core.errors import ConfigError
from cartpole.envs.fast import CartPoleEnv, CartPoleVectorEnv
from cartpole.envs.params import CartPoleParams

DEFAULT_FRAME_SIZE: tuple[int, int] = (30, 100)
"""(height, width) of a frame: see the module docstring for why."""
DEFAULT_STACK = 4
"""Frames per observation, oldest first."""
MIN_HEIGHT, MAX_HEIGHT = 16, 200
MIN_STACK, MAX_STACK = 1, 8

# Gymnasium's screen and drawing (gymnasium/envs/classic_control/cartpole.py, CartPoleEnv.render):
# written there as literals; the tests compare our frames with its pictures, so a change shows.
SCREEN_WIDTH, SCREEN_HEIGHT = 600, 400
_CART_WIDTH, _CART_HEIGHT, _POLE_WIDTH, _CART_Y = 50.0, 30.0, 10.0, 100
_AXLE_OFFSET = _CART_HEIGHT / 4.0
_RGB_POLE, _RGB_AXLE = (202, 152, 101), (129, 132, 203)

GRAY_WEIGHTS: tuple[float, float, float] = (0.299, 0.587, 0.114)
"""ITU-R BT.601 luma weights of R, G, B."""
_GRAY_WEIGHTS_INT = np.round(1000 * np.asarray(GRAY_WEIGHTS)).astype(np.int64)  # 299, 587, 114


def _pole_tip_row(params: CartPoleParams) -> int:
    """The screen row of the upright pole's tip (Gymnasium's drawing, after its vertical flip)."""
    pole_length = SCREEN_WIDTH / (2 * params.x_threshold) * 2 * params.length
    return SCREEN_HEIGHT - 1 - math.trunc(_CART_Y + _AXLE_OFFSET + pole_length - _POLE_WIDTH / 2)


# The scene's rows on the screen for Gymnasium's cart-pole: from the upright pole's tip (row 172)
# to the cart's bottom edge (row 315); frames show a band centred on them, at least 150 rows high.
_SCENE_TOP = float(_pole_tip_row(CartPoleParams()))
_SCENE_BOTTOM = SCREEN_HEIGHT - (_CART_Y - _CART_HEIGHT / 2)
_MIN_WINDOW_ROWS = 150.0

# The axle: pygame's aacircle + filled_circle of radius 5 at an integer centre, as alpha x 255 (measured).
_AXLE_EDGE = (0, 0, 0, 152, 229, 255, 229, 152, 0, 0, 0)
_AXLE_HALF_WIDTHS = (None, 3, 4, 5, 5, 5, 5, 5, 4, 3, None)

# How far pygame's anti-aliased outline reaches beyond the polygon through the truncated vertex
# pixels' centres, in screen pixels (fitted to pygame's frames: about half a pixel, the outline's width).
_SIDE_DILATION, _END_DILATION = 0.6, 0.5


def _gray(rgb: tuple[int, int, int]) -> float:
    return float(np.dot(rgb, GRAY_WEIGHTS))


def _axle_mask() -> NDArray[np.float64]:
    mask = np.zeros((11, 11))
    for row, half in enumerate(_AXLE_HALF_WIDTHS):
        if half is None:
            mask[row] = _AXLE_EDGE
        else:
            mask[row, 5 - half : 6 + half] = 255
    return mask / 255.0


def check_frame_size(frame_size: Any) -> tuple[int, int]:
    """``frame_size`` as ``(height, width)``; ConfigError saying what is allowed otherwise."""
    allowed = (
        f"frame_size must be (height, width) in pixels with {MIN_HEIGHT} <= height <= {MAX_HEIGHT}, "
        f"width <= {SCREEN_WIDTH} and width/height between 1.5 (the whole {SCREEN_WIDTH}x"
        f"{SCREEN_HEIGHT} screen) and 4 (the {_MIN_WINDOW_ROWS:.0f} rows around the cart and pole), "
        f"e.g. {DEFAULT_FRAME_SIZE}; got {frame_size!r}"
    )
    if isinstance(frame_size, (str, bytes)) or not isinstance(frame_size, Sequence) or len(frame_size) != 2:
        raise ConfigError(allowed)
    height, width = frame_size
    for value in (height, width):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ConfigError(allowed)
    height, width = int(height), int(width)
    rows = height * SCREEN_WIDTH / width if width > 0 else math.inf
    if not (MIN_HEIGHT <= height <= MAX_HEIGHT and width <= SCREEN_WIDTH):
        raise ConfigError(allowed)
    if not (_MIN_WINDOW_ROWS <= rows <= SCREEN_HEIGHT):
        raise ConfigError(allowed)
    return height, width


def check_stack(stack: Any) -> int:
    """``stack`` as an int; ConfigError saying what is allowed otherwise."""
    if (
        isinstance(stack, bool)
        or not isinstance(stack, (int, np.integer))
        or not MIN_STACK <= stack <= MAX_STACK
    ):
        raise ConfigError(
            f"stack must be an integer from {MIN_STACK} to {MAX_STACK} (frames per observation), "
            f"got {stack!r}"
        )
    return int(stack)


def screen_window(frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE) -> tuple[float, float]:
    """The screen rows ``[top, bottom)`` that a frame of ``frame_size`` shows (all 600 columns).

    ``600 / width`` screen pixels per output pixel both ways; the band is centred on the scene's rows
    and moved inside the screen where it would leave it.
    """
    height, width = check_frame_size(frame_size)
    rows = height * SCREEN_WIDTH / width
    top = float(round(0.5 * (_SCENE_TOP + _SCENE_BOTTOM) - 0.5 * rows))
    top = min(max(top, 0.0), SCREEN_HEIGHT - rows)
    return top, top + rows


def _area_weights(start: float, pixel: float, n_out: int, n_in: int) -> NDArray[np.float64]:
    """``[n_out, n_in]``: the fraction of output pixel i (from ``start + i * pixel``, ``pixel`` wide)
    that input pixel k (``[k, k + 1)``) covers."""
    edges = start + pixel * np.arange(n_out + 1)
    k = np.arange(n_in)
    lo = np.maximum(edges[:-1, None], k[None, :])
    hi = np.minimum(edges[1:, None], k[None, :] + 1)
    return np.clip(hi - lo, 0.0, None) / pixel


def _row_fractions(y0: float, y1: float, top: float, pixel: float, n_rows: int) -> NDArray[np.float64]:
    """Per output row, the fraction of its height inside the screen rows ``[y0, y1)``."""
    edges = top + pixel * np.arange(n_rows + 1)
    return np.clip(np.minimum(edges[1:], y1) - np.maximum(edges[:-1], y0), 0.0, None) / pixel


# Halves round up, and a value within this of a half counts as one: gray levels of exact halves are
# common (a 1-pixel line in a 10-pixel-high box: 229.5), and two float computations of one would
# otherwise round apart.
_HALF = 0.5 + 1e-6


def _to_uint8(values: NDArray[np.floating[Any]]) -> NDArray[np.uint8]:
    return np.clip(np.floor(values + _HALF), 0, 255).astype(np.uint8)


def preprocess_frames(
    rgb: NDArray[np.uint8], frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE
) -> NDArray[np.uint8]:
    """Gymnasium's ``rgb_array`` pictures ``[N, 400, 600, 3]`` uint8 as frames ``[N, height, width]``.

    Gray (BT.601 luma), the band of rows of :func:`screen_window`, area-averaged to ``frame_size``,
    rounded once. What :class:`PixelRenderer` draws without the picture.
    """
    height, width = check_frame_size(frame_size)
    pictures = np.asarray(rgb)
    if (
        pictures.ndim != 4
        or pictures.shape[1:] != (SCREEN_HEIGHT, SCREEN_WIDTH, 3)
        or pictures.dtype != np.uint8
    ):
        raise ValueError(
            f"rgb must be uint8 pictures of shape (N, {SCREEN_HEIGHT}, {SCREEN_WIDTH}, 3), "
            f"got {pictures.dtype} {pictures.shape}"
        )
    top, _ = screen_window((height, width))
    pixel = SCREEN_WIDTH / width
    frames = np.empty((len(pictures), height, width), dtype=np.uint8)
    if pixel.is_integer() and top.is_integer():  # whole screen pixels per output pixel (30x100)
        blocks = _kernels().gray_blocks
        for frame, picture in zip(frames, pictures, strict=True):  # the kernel reads contiguous rows
            blocks(np.ascontiguousarray(picture), int(top), int(pixel), _GRAY_WEIGHTS_INT, frame)
        return frames
    first = math.floor(top)
    last = min(SCREEN_HEIGHT, math.ceil(top + height * pixel))
    # Gray levels times 1000 (299 R + 587 G + 114 B): whole numbers below 2**24, exact in float32.
    weights = np.round(1000 * np.asarray(GRAY_WEIGHTS, dtype=np.float32))
    for frame, picture in zip(frames, pictures, strict=True):  # one at a time: stays in cache
        gray = picture[first:last].astype(np.float32) @ weights
        columns = _box_average(gray, 0.0, pixel, width, axis=1)  # along rows first: contiguous
        frame[:] = _to_uint8(_box_average(columns, top - first, pixel, height, axis=0) / 1000.0)
    return frames


def _box_average(
    values: NDArray[Any], start: float, pixel: float, n_out: int, axis: int
) -> NDArray[np.float64]:
    """The means of ``values`` over ``n_out`` intervals ``pixel`` long along ``axis``, from ``start``
    (in elements: element k spans ``[k, k + 1)``; interval edges may fall inside an element).

    From cumulative sums, read at each edge (the part of a cut element counted pro rata): the exact
    area average, in time linear in the input, as ``cv2.INTER_AREA`` computes it.
    """
    n_in = values.shape[axis]
    edges = start + pixel * np.arange(n_out + 1)
    whole = np.minimum(np.floor(edges).astype(np.int64), n_in)
    part = edges - whole
    sums = np.cumsum(values, axis=axis, dtype=np.float64)  # float64: sums stay whole numbers
    shape = [1] * values.ndim
    shape[axis] = n_out + 1
    before = np.take(sums, np.maximum(whole - 1, 0), axis=axis) * (whole > 0).reshape(shape)
    cut = np.take(values, np.minimum(whole, n_in - 1), axis=axis) * part.reshape(shape)
    return np.diff(before + cut, axis=axis) / pixel


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernel, imported on first use so that importing this module stays cheap (asked for
    at each use, never kept on a renderer: envs can be pickled and copied, compiled functions not
    cheaply)."""
    from cartpole.envs import _pixel_kernels

    return _pixel_kernels


def _check_params(params: CartPoleParams | None) -> CartPoleParams:
    if params is None:
        return CartPoleParams()
    if not isinstance(params, CartPoleParams):
        raise TypeError(f"params must be a CartPoleParams, got {type(params).__name__}")
    return params


class PixelRenderer:
    """Draws cart-pole states as :func:`preprocess_frames` of Gymnasium's pictures of them.

    ```python
    >>> renderer = PixelRenderer((30, 100))
    >>> renderer.render(np.zeros((2, 4))).shape
    (2, 30, 100)

    ```

    ``params`` gives the pole's length and the track's width (the screen shows ``2 * x_threshold``
    metres, as Gymnasium's does); the pole must fit in the frame's band of rows.
    """

    def __init__(
        self, frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE, params: CartPoleParams | None = None
    ) -> None:
        height, width = self.frame_size = check_frame_size(frame_size)
        self.params = params = _check_params(params)
        k = _kernels()
        top, _ = screen_window(self.frame_size)
        pixel = SCREEN_WIDTH / width
        scale = SCREEN_WIDTH / (2 * params.x_threshold)
        pole_length = scale * 2 * params.length
        pivot_y = _CART_Y + _AXLE_OFFSET
        pole_tip = _pole_tip_row(params)
        if pole_tip < top:
            raise ConfigError(
                f"a pole of half-length {params.length} m on a {2 * params.x_threshold} m track reaches "
                f"screen row {pole_tip}, above the frame's band (from row {top:g}); use a frame_size "
                "with a smaller width/height ratio (taller band) or a shorter pole"
            )
        g = np.zeros(k.N_GEOMETRY)
        g[k.SCALE] = scale
        g[k.CENTER_X] = SCREEN_WIDTH / 2.0
        g[k.CART_HALF_WIDTH] = _CART_WIDTH / 2
        g[k.POLE_HALF_WIDTH] = _POLE_WIDTH / 2
        g[k.POLE_LENGTH] = pole_length
        g[k.PIVOT_Y] = pivot_y
        g[k.PIXEL] = pixel
        g[k.TOP] = top
        g[k.SIDE_DILATION] = _SIDE_DILATION
        g[k.END_DILATION] = _END_DILATION
        g[k.GRAY_POLE] = _gray(_RGB_POLE)
        g[k.GRAY_AXLE] = _gray(_RGB_AXLE)
        g[k.SCREEN_HEIGHT] = SCREEN_HEIGHT
        self._geometry = g

        # Screen rows (image rows, after Gymnasium's vertical flip) of the cart, the line and the axle.
        cart_y0 = SCREEN_HEIGHT - 1 - (_CART_Y + _CART_HEIGHT / 2)
        cart_y1 = SCREEN_HEIGHT - (_CART_Y - _CART_HEIGHT / 2)
        line_y = SCREEN_HEIGHT - 1 - _CART_Y
        self._cart_rows = _row_fractions(cart_y0, cart_y1, top, pixel, height)
        self._line_rows = _row_fractions(line_y, line_y + 1, top, pixel, height)
        self._cart_line_rows = _row_fractions(
            max(cart_y0, line_y), min(cart_y1, line_y + 1), top, pixel, height
        )
        self._axle_mask = mask = _axle_mask()
        self._axle_y0 = float(SCREEN_HEIGHT - 1 - (math.trunc(pivot_y) + mask.shape[0] // 2))
        per_row = _area_weights(top - self._axle_y0, pixel, height, mask.shape[0])  # [height, mask rows]
        touched = np.flatnonzero(per_row.any(axis=1))  # contiguous: the mask's rows lie in the band
        self._axle_row0 = int(touched[0])
        self._axle_rows = np.ascontiguousarray(per_row[touched[0] : touched[-1] + 1])
        self._background = _to_uint8(
            np.broadcast_to((255.0 * (1.0 - self._line_rows))[:, None], (height, width))
        )

    def render(self, states: ArrayLike, out: NDArray[np.uint8] | None = None) -> NDArray[np.uint8]:
        """Frames ``[N, height, width]`` uint8 of ``states`` ``[N, 4]`` (x, x_dot, theta, theta_dot).

        ``out``, when given, receives them and is returned (any strides; other than C-contiguous ones,
        as the envs pass, compile a second version of the kernel on first use).
        """
        s = np.ascontiguousarray(states, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != 4:
            raise ValueError(f"states must have shape (N, 4), got {s.shape}")
        if not np.isfinite(s).all():
            raise ValueError("states must be finite")
        shape = (s.shape[0], *self.frame_size)
        if out is None:
            out = np.empty(shape, dtype=np.uint8)
        elif out.shape != shape or out.dtype != np.uint8:
            raise ValueError(f"out must be uint8 of shape {shape}, got {out.dtype} {out.shape}")
        _kernels().render_frames(
            s,
            self._geometry,
            self._cart_rows,
            self._line_rows,
            self._cart_line_rows,
            self._axle_mask,
            self._axle_y0,
            self._axle_row0,
            self._axle_rows,
            self._background,
            out,
        )
        return out


@functools.lru_cache(maxsize=16)
def _cached_renderer(frame_size: tuple[int, int], params: CartPoleParams | None) -> PixelRenderer:
    return PixelRenderer(frame_size, params)


def render_frames(
    states: ArrayLike, frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE, params: CartPoleParams | None = None
) -> NDArray[np.uint8]:
    """:meth:`PixelRenderer.render` with a renderer kept per frame size and params."""
    return _cached_renderer(check_frame_size(frame_size), params).render(states)


class FrameStack:
    """The last ``stack`` frames of one env, oldest first: the observation ``[stack, height, width]``
    uint8. ``start(frame)`` fills the stack with an episode's first frame; ``push(frame)`` drops the
    oldest and appends the newest. Both return a new array."""

    def __init__(self, stack: int, frame_size: tuple[int, int]) -> None:
        self._frames = np.zeros((check_stack(stack), *frame_size), dtype=np.uint8)

    def start(self, frame: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """The first observation of an episode: its first frame, ``stack`` times."""
        self._frames[:] = frame
        return self._frames.copy()

    def push(self, frame: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """The observation after a step whose new frame is ``frame``."""
        self._frames[:-1] = self._frames[1:]
        self._frames[-1] = frame
        return self._frames.copy()


def _frame_space(frame_size: tuple[int, int], stack: int) -> spaces.Space[NDArray[np.uint8]]:
    """``Box(0, 255, (stack, height, width), uint8)``."""
    return cast("spaces.Space[NDArray[np.uint8]]", spaces.Box(0, 255, (stack, *frame_size), dtype=np.uint8))


class CartPolePixelsVectorEnv(VectorEnv[NDArray[np.uint8], NDArray[np.int64], NDArray[Any]]):
    """``num_envs`` cart-poles seen as stacks of gray frames ``[num_envs, stack, height, width]`` uint8.

    A :class:`~cartpole.envs.fast.CartPoleVectorEnv` steps them (same seeds, start states, rewards,
    flags and next-step autoreset; its ``params``, ``dtype`` and ``sutton_barto_reward``); each step
    draws one frame per env. An env's stack is filled with its first frame on reset and on its
    autoreset step.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012  (Gymnasium's convention: a class attribute)
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        sutton_barto_reward: bool = False,
        *,
        frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE,
        stack: int = DEFAULT_STACK,
        params: CartPoleParams | None = None,
        dtype: DTypeLike = np.float64,
    ) -> None:
        self.frame_size = check_frame_size(frame_size)
        self.stack = check_stack(stack)
        self._sim = CartPoleVectorEnv(
            num_envs, max_episode_steps, render_mode, sutton_barto_reward, params=params, dtype=dtype
        )
        self._renderer = PixelRenderer(self.frame_size, self._sim.params)
        self.num_envs = self._sim.num_envs
        self.max_episode_steps = self._sim.max_episode_steps
        self.render_mode = render_mode
        self.single_action_space = self._sim.single_action_space
        self.action_space = self._sim.action_space
        self.single_observation_space = _frame_space(self.frame_size, self.stack)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        # A ring of the last `stack` frames of every env, slot first (each slot is one contiguous
        # [num_envs, height, width] block for the renderer); slot `_head` holds the newest.
        self._frames = np.zeros((self.stack, self.num_envs, *self.frame_size), dtype=np.uint8)
        self._head = 0
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)

    @property
    def simulator(self) -> CartPoleVectorEnv:
        """The state simulator (its ``set_state`` shows in the frames from the next step on)."""
        return self._sim

    @property
    def states(self) -> NDArray[np.floating[Any]]:
        """A copy of the current states ``[num_envs, 4]`` (x, x_dot, theta, theta_dot)."""
        return self._sim.get_state()

    @property
    def state(self) -> NDArray[np.floating[Any]] | None:
        """The simulator's live states ``(4, num_envs)`` (:attr:`CartPoleVectorEnv.state`)."""
        return self._sim.state

    @property
    def prev_done(self) -> NDArray[np.bool_]:
        """Which envs autoreset on the next step (:attr:`CartPoleVectorEnv.prev_done`)."""
        return self._sim.prev_done

    @property
    def params(self) -> CartPoleParams:
        """The physics in use (they also set the pole's drawn length)."""
        return self._sim.params

    def set_params(self, params: CartPoleParams) -> None:
        """Use ``params`` from the next step on, for the physics and the drawing."""
        renderer = PixelRenderer(self.frame_size, params)
        self._sim.set_params(params)
        self._renderer = renderer

    @property
    def np_random(self) -> np.random.Generator:
        """The simulator's generator: the one that draws start states."""
        return self._sim.np_random

    @np_random.setter
    def np_random(self, value: np.random.Generator) -> None:
        self._sim.np_random = value

    @property
    def np_random_seed(self) -> int | None:
        """The simulator's seed (-1 when its generator was set directly)."""
        return self._sim.np_random_seed

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.uint8], dict[str, Any]]:
        """Reset every env (the simulator's ``reset``) and fill every stack with its first frame."""
        _, info = self._sim.reset(seed=seed, options=options)
        self._head = 0
        self._renderer.render(self._sim.get_state(), out=self._frames[0])
        self._frames[1:] = self._frames[:1]
        self._autoreset[:] = False
        return self._observation(), info

    def restart_at(self, states: ArrayLike) -> NDArray[np.uint8]:
        """Put every env at ``states`` ``[num_envs, 4]`` as fresh episodes (after ``reset``) and fill
        each stack with its frame; the observations. How evaluations start from the states that
        Gymnasium's ``reset(seed=...)`` draws."""
        self._sim.set_state(np.asarray(states))
        self._head = 0
        self._renderer.render(self._sim.get_state(), out=self._frames[0])
        self._frames[1:] = self._frames[:1]
        self._autoreset[:] = False
        return self._observation()

    def step(
        self, actions: ArrayLike
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Step the simulator, draw every env's new frame; an autoreset env's stack restarts from it."""
        _, reward, terminated, truncated, info = self._sim.step(actions)
        self._head = head = (self._head + 1) % self.stack
        self._renderer.render(self._sim.get_state(), out=self._frames[head])
        restarted = np.flatnonzero(self._autoreset)
        if restarted.size:
            self._frames[:, restarted] = self._frames[head, restarted]
        self._autoreset = terminated | truncated
        return self._observation(), reward, terminated, truncated, info

    def _observation(self) -> NDArray[np.uint8]:
        """A new array of the stacks, oldest frame first."""
        observations = np.empty((self.num_envs, self.stack, *self.frame_size), dtype=np.uint8)
        for slot in range(self.stack):
            observations[:, slot] = self._frames[(self._head + 1 + slot) % self.stack]
        return observations

    # A list, as Gymnasium's CartPoleVectorEnv returns and its vector HumanRendering asserts
    # (VectorEnv.render is typed as a tuple).
    def render(self) -> list[NDArray[np.uint8]] | None:  # type: ignore[override]
        """Gymnasium's picture of each env's state (``render_mode="rgb_array"``), through the simulator."""
        return self._sim.render()

    def close_extras(self, **kwargs: Any) -> None:
        """Close the simulator."""
        self._sim.close()

    def __repr__(self) -> str:
        spec_id = self.spec.id if self.spec is not None else "CartPolePixels"
        height, width = self.frame_size
        return (
            f"CartPolePixelsVectorEnv({spec_id}, num_envs={self.num_envs}, frame_size=({height}, {width}), "
            f"stack={self.stack})"
        )


class CartPolePixelsEnv(gym.Env[NDArray[np.uint8], int]):
    """One cart-pole seen as a stack of gray frames ``[stack, height, width]`` uint8.

    A :class:`~cartpole.envs.fast.CartPoleEnv` steps it; ``render_mode="rgb_array"`` (or ``"human"``)
    is its renderer: Gymnasium's 600x400 picture (needs pygame). ``state`` reads and sets the state;
    a state set by hand shows in the frames from the next step on.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        sutton_barto_reward: bool = False,
        render_mode: str | None = None,
        *,
        frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE,
        stack: int = DEFAULT_STACK,
        params: CartPoleParams | None = None,
        dtype: DTypeLike = np.float64,
    ) -> None:
        self.frame_size = check_frame_size(frame_size)
        self.stack = check_stack(stack)
        self._sim = CartPoleEnv(sutton_barto_reward, render_mode, params=params, dtype=dtype)
        self._renderer = PixelRenderer(self.frame_size, self._sim.params)
        self.render_mode = render_mode
        self.action_space = self._sim.action_space
        self.observation_space = _frame_space(self.frame_size, self.stack)
        self._frames = FrameStack(self.stack, self.frame_size)

    @property
    def simulator(self) -> CartPoleEnv:
        """The state simulator."""
        return self._sim

    @property
    def state(self) -> NDArray[np.floating[Any]] | None:
        """(x, x_dot, theta, theta_dot), None before reset; see :attr:`CartPoleEnv.state`."""
        return self._sim.state

    @state.setter
    def state(self, value: ArrayLike) -> None:
        self._sim.state = value

    @property
    def params(self) -> CartPoleParams:
        """The physics in use (they also set the pole's drawn length)."""
        return self._sim.params

    def set_params(self, params: CartPoleParams) -> None:
        """Use ``params`` from the next step on, for the physics and the drawing."""
        renderer = PixelRenderer(self.frame_size, params)
        self._sim.set_params(params)
        self._renderer = renderer

    def _frame(self) -> NDArray[np.uint8]:
        state = self._sim.state
        assert state is not None  # the simulator has been reset
        frame: NDArray[np.uint8] = self._renderer.render(state[None])[0]
        return frame

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.uint8], dict[str, Any]]:
        """Draw a start state (the simulator's draw, from this env's ``np_random``); fill the stack
        with its frame."""
        super().reset(seed=seed)
        self._sim.np_random = self.np_random  # one generator: check_env and seeding see this env's
        _, info = self._sim.reset(options=options)
        return self._frames.start(self._frame()), info

    def step(
        self, action: int | np.integer[Any] | NDArray[np.integer[Any]]
    ) -> tuple[NDArray[np.uint8], SupportsFloat, bool, bool, dict[str, Any]]:
        """Push the cart (0 left, 1 right); the new frame goes at the end of the stack."""
        _, reward, terminated, truncated, info = self._sim.step(action)
        return self._frames.push(self._frame()), reward, terminated, truncated, info

    def render(self) -> NDArray[np.uint8] | None:
        """Gymnasium's picture of the state (``render_mode="rgb_array"``), through the simulator."""
        return self._sim.render()

    def close(self) -> None:
        """Close the simulator's renderer, if one was opened."""
        self._sim.close()


class GymnasiumPixels(gym.Wrapper[NDArray[np.uint8], Any, Any, Any]):
    """Gymnasium's own env observed as stacks of its own pictures through :func:`preprocess_frames`.

    ``env`` must render ``rgb_array`` pictures, e.g. ``gym.make("CartPole-v1",
    render_mode="rgb_array")``; its state observations are dropped. The observation space is the one
    of :class:`CartPolePixelsEnv` with the same ``frame_size`` and ``stack``.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        *,
        frame_size: tuple[int, int] = DEFAULT_FRAME_SIZE,
        stack: int = DEFAULT_STACK,
    ) -> None:
        self.frame_size = check_frame_size(frame_size)
        self.stack = check_stack(stack)
        if env.render_mode != "rgb_array":
            raise ConfigError(
                f"GymnasiumPixels needs an env made with render_mode='rgb_array', got {env.render_mode!r}"
            )
        super().__init__(env)
        self.observation_space = _frame_space(self.frame_size, self.stack)
        self._frames = FrameStack(self.stack, self.frame_size)

    def _frame(self) -> NDArray[np.uint8]:
        picture = self.env.render()
        return preprocess_frames(np.asarray(picture)[None], self.frame_size)[0]

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.uint8], dict[str, Any]]:
        """Reset the env and fill the stack with its first picture."""
        _, info = self.env.reset(seed=seed, options=options)
        return self._frames.start(self._frame()), info

    def step(self, action: Any) -> tuple[NDArray[np.uint8], SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env; its new picture goes at the end of the stack."""
        _, reward, terminated, truncated, info = self.env.step(action)
        return self._frames.push(self._frame()), reward, terminated, truncated, info


__all__ = [
    "DEFAULT_FRAME_SIZE",
    "DEFAULT_STACK",
    "GRAY_WEIGHTS",
    "CartPolePixelsEnv",
    "CartPolePixelsVectorEnv",
    "FrameStack",
    "GymnasiumPixels",
    "PixelRenderer",
    "check_frame_size",
    "check_stack",
    "preprocess_frames",
    "render_frames",
    "screen_window",
]
