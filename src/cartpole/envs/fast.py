"""A fast, exact CartPole simulator: Gymnasium's CartPole, batched and compiled.

## Description

The cart-pole of Barto, Sutton and Anderson (1983), exactly as Gymnasium's
``gymnasium.envs.classic_control.cartpole`` defines it: a pole hinged on a cart that moves along a
frictionless track; each step pushes the cart left or right with a fixed force. Two forms share one
physics kernel (:func:`step_cartpole`, compiled with numba on first use and cached on disk):

- :class:`CartPoleVectorEnv`, a ``gymnasium.vector.VectorEnv`` of ``num_envs`` cart-poles with
  Gymnasium's next-step autoreset, for training;
- :class:`CartPoleEnv`, a ``gymnasium.Env``, for interactive use (playing by hand, rendering).

Both render as Gymnasium's do (``render_mode="rgb_array"``: its own 600x400 pictures, one per env).

A caller that keeps its own float64 state (the web app's simulator) can step it with
:class:`CartPoleStepper`: the single env's kernel call, without the env around it.

:func:`register_fast_envs` registers both under ``cartpole/CartPole-v1`` and ``cartpole/CartPole-v0``:

```python
>>> import gymnasium as gym
>>> import numpy as np
>>> from cartpole.envs.fast import register_fast_envs
>>> register_fast_envs()
>>> envs = gym.make_vec("cartpole/CartPole-v1", num_envs=4096, dtype=np.float32)  # fast, for training
>>> env = gym.make("cartpole/CartPole-v1", render_mode="rgb_array")  # rendering needs pygame

```

## Action space

``Discrete(2)`` (``MultiDiscrete([2] * num_envs)`` batched): 0 pushes the cart left, 1 right, with
``force_mag`` newtons. Any other value raises ``ValueError``.

## Observation space

``Box(-high, high, (4,), float32)`` with ``high = [2 * x_threshold, inf, 2 * theta_threshold_radians,
inf]``: cart position (m), cart velocity (m/s), pole angle (rad, 0 is upright), pole angular velocity
(rad/s). Observations are float32 whatever the simulation dtype, as in Gymnasium.

## Rewards

+1 for every step, the terminating one included. With ``sutton_barto_reward=True``: 0 for every step
and -1 for the terminating one. On the autoreset step of the vector env: 0.

## Starting state

Every component uniform in ``(-0.05, 0.05)``, or in ``(low, high)`` given by
``reset(options={"low": ..., "high": ...})`` (kept for the autoresets until the next ``reset``).
Draws come from ``self.np_random`` in Gymnasium's order, so the same seed gives the same start
states as Gymnasium: ``CartPoleEnv`` draws 4 numbers per reset; ``CartPoleVectorEnv`` draws a
``(4, num_envs)`` block on ``reset`` and a ``(4, k)`` block for the ``k`` envs it autoresets on a
step (env ``i`` of ``reset(seed=s)`` is *not* the single env of seed ``s + i``; that is Gymnasium's
own rule).

## Episode end

Terminated when the cart leaves ``[-x_threshold, x_threshold]`` (2.4 m) or the pole passes
``theta_threshold_radians`` (12 degrees). Truncated after ``max_episode_steps``: 500 for v1, 200 for
v0, read from Gymnasium's registry. ``terminated`` and ``truncated`` are separate arrays; both can be
True on the same step. The vector env autoresets on the *next* step (Gymnasium's
``AutoresetMode.NEXT_STEP``): that step ignores the action and returns the new start state, reward 0,
both flags False. The single env is truncated by the ``TimeLimit`` wrapper ``gymnasium.make`` adds.

## Physics parameters (:class:`CartPoleParams`)

| field | default | changing it |
| --- | --- | --- |
| ``gravity`` | 9.8 m/s² | larger: the pole falls faster; 0: it only moves when the cart pushes it |
| ``masscart`` | 1.0 kg | heavier cart: each push accelerates it less |
| ``masspole`` | 0.1 kg | heavier pole: pushes the cart back harder as it swings |
| ``length`` | 0.5 m | *half* the pole's length, as in Gymnasium; longer poles fall more slowly |
| ``force_mag`` | 10.0 N | the push of each action; 0 leaves the pole uncontrolled |
| ``tau`` | 0.02 s | seconds per step (smaller: finer, slower-looking motion) |
| ``theta_threshold_radians`` | 12° | angle that ends the episode (also sets the observation bounds) |
| ``x_threshold`` | 2.4 m | track half-width that ends the episode (also sets the bounds) |
| ``kinematics_integrator`` | "euler" | or "semi-implicit euler" (velocities first) |

``total_mass`` and ``polemass_length`` are derived properties. Pass ``params=CartPoleParams(...)`` to
either env, or the constants by name (``gym.make("cartpole/CartPole-v1", gravity=5.0)``, as
``--env-kwargs gravity=5.0`` does: Gymnasium's own CartPole takes no such keyword, so such an env
trains and is judged on our simulator, and its verdict says so), or change them on a live env with
``env.set_params(dataclasses.replace(env.params, gravity=20.0))``; the next step uses them. The
thresholds define the observation space, so they are fixed for an env's lifetime (make a new env to
change them).

## Setting the state

``CartPoleVectorEnv.set_state(states, indices=None)`` overwrites the states of some or all envs, and
``get_state()`` reads them (as ``(num_envs, 4)``); on the single env ``env.unwrapped.state`` is
readable and assignable, as in Gymnasium. Step counters are kept, so a nudge does not extend the time
limit, and an env that has just finished still autoresets on its next step. For checkpoints,
``snapshot()`` returns everything later steps depend on (states, step counters, pending autoresets,
reset bounds, the generator's state) as JSON-able data and ``restore(snapshot)`` continues from it
exactly.

## float32 or float64 (``dtype=``)

- ``np.float64``: bit-for-bit Gymnasium. Same start states, same trajectories, same flags, step for
  step (the lock-step tests check 10,000+ steps against both of Gymnasium's forms). Gymnasium calls
  numpy's sin/cos, which are the C library's except on Intel CPUs with AVX-512, where numpy uses SVML
  and itself differs from libm by an ulp now and then (numpy#23523); there we match libm, and
  Gymnasium only to ~1e-16 per step. Speed is bounded by libm's sin and cos, which cannot be
  vectorized without changing results.
- ``np.float32``: start states are Gymnasium's draws rounded to float32, and each step stays within
  1e-5 of Gymnasium's from the same state, using a vectorized polynomial sine/cosine (error < 1e-7
  for |angle| < 1e3 rad). Trajectories drift apart from Gymnasium's over long episodes, as any two
  implementations of a chaotic system do, but the dynamics, the flags and the seeds mean the same.

Both forms default to float64, so that ``gym.make`` and ``gym.make_vec`` of one id agree step for
step (as Gymnasium's own two forms do) and reproduce Gymnasium exactly; given the same ``dtype`` they
agree in float32 too. Training asks for float32 (``cartpole.envs.make_vec_env``): at large
``num_envs`` float64 runs several times slower, and the observations are float32 anyway.
``step_cartpole`` keeps the dtype of the state it is given.

## Copies

Both forms (and the pixel envs built on them) can be pickled and deep-copied, as Gymnasium's can; the
copy continues the same episode bit for bit (states, step counters, pending autoresets, the random
generator). A renderer is not copied: the copy opens its own when it first renders.

## Throughput and start-up

``python benchmarks/env_throughput.py`` measures env steps per CPU-second on one core (random
actions, autoreset included): the vector env in both dtypes against Gymnasium's
``CartPoleVectorEnv``, the single env through ``gymnasium.make`` against Gymnasium's, and the
start-up costs below.

Importing this module does not import numba. The first env of a process imports numba and loads the
compiled kernels from its on-disk cache, once per dtype; with an empty cache (first run after an
install or an edit of the kernels) it compiles them instead, which takes longer.
"""

from __future__ import annotations

import functools
from types import ModuleType
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import logger, spaces
from gymnasium.envs.classic_control.utils import maybe_parse_reset_bounds
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import ArrayLike, DTypeLike, NDArray

from cartpole.envs.params import CartPoleParams, KinematicsIntegrator, with_physics
from cartpole.envs.registration import REFERENCE_IDS, register_fast_envs

#: Gymnasium's bounds for the uniform start state (``reset`` without options).
DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH = -0.05, 0.05

#: The Gymnasium ids whose dynamics we reproduce; ours are registered as ``cartpole/<id>``.

_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernels, imported on first use so that importing this module stays cheap."""
    from cartpole.envs import _fast_kernels

    return _fast_kernels


def _check_dtype(dtype: DTypeLike) -> np.dtype[Any]:
    dt = np.dtype(dtype)
    if dt not in _DTYPES:
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dt}")
    return dt


_DEFAULT_PARAMS = CartPoleParams()
"""Gymnasium's cart-pole (frozen: shared by every step that names no parameters)."""


def _check_params(params: CartPoleParams | None) -> CartPoleParams:
    if params is None:
        return _DEFAULT_PARAMS
    if not isinstance(params, CartPoleParams):
        raise TypeError(f"params must be a CartPoleParams, got {type(params).__name__}")
    return params


def _reference_max_episode_steps() -> int:
    steps = gym.spec("CartPole-v1").max_episode_steps
    assert steps is not None  # Gymnasium registers CartPole-v1 with a time limit
    return steps


@functools.lru_cache(maxsize=64)
def packed_params(params: CartPoleParams, dtype: np.dtype[Any]) -> NDArray[np.floating[Any]]:
    """The kernels' parameter vector of ``params`` (read only), packed once per parameters and dtype."""
    packed = _kernels().pack_params(params, dtype)
    packed.flags.writeable = False
    return packed


def step_cartpole(
    state: ArrayLike, action: ArrayLike, params: CartPoleParams | None = None
) -> tuple[NDArray[np.floating[Any]], NDArray[np.bool_]]:
    """Advance a batch of cart-poles by one step: Gymnasium's equations, nothing else.

    ``state`` is ``(N, 4)`` (x, x_dot, theta, theta_dot per row; float32 stays float32, anything else
    is computed in float64), ``action`` is ``(N,)`` of 0/1. Returns the next states (same dtype,
    a new array) and ``terminated`` ``(N,)``. No time limit, no reset: the envs add those.
    """
    params = _check_params(params)
    s = np.asarray(state)
    dtype = np.dtype(np.float32) if s.dtype == np.float32 else np.dtype(np.float64)
    if s.ndim != 2 or s.shape[1] != 4:
        raise ValueError(f"state must have shape (N, 4), got {s.shape}")
    a = np.asarray(action)
    if a.shape != (s.shape[0],) or a.dtype.kind not in "iu":
        raise ValueError(f"action must be integers of shape ({s.shape[0]},), got {a.dtype} {a.shape}")
    k = _kernels()
    columns = np.ascontiguousarray(s.T, dtype=dtype)  # the kernel works on (4, N): a fresh copy
    terminated = np.empty(s.shape[0], dtype=np.bool_)
    if not k.step_states(columns, a.astype(np.int64, copy=False), packed_params(params, dtype), terminated):
        raise ValueError("actions must be 0 (push left) or 1 (push right)")
    return np.ascontiguousarray(columns.T), terminated


def step_cartpole_columns(
    columns: NDArray[np.floating[Any]], action: NDArray[np.int64], params: CartPoleParams | None = None
) -> NDArray[np.bool_]:
    """:func:`step_cartpole` in place, for callers that keep their states as the kernel's columns:
    ``columns`` ``(4, N)`` (C-contiguous float32 or float64) advance one step under ``params``
    (None: Gymnasium's); ``action`` ``(N,)`` int64 of 0/1. Returns ``terminated`` ``(N,)``."""
    terminated = np.empty(columns.shape[1], dtype=np.bool_)
    if not _kernels().step_states(
        columns, action, packed_params(_check_params(params), columns.dtype), terminated
    ):
        raise ValueError("actions must be 0 (push left) or 1 (push right)")
    return terminated


class _KernelsAtHand:
    """Keeps the numba kernels module at hand (``self._kernels``: one attribute lookup a step), and
    out of copies: a module cannot be pickled, nor can a pygame renderer. ``pickle`` and
    ``copy.deepcopy`` leave both out; the copy takes the kernels again, and opens its own renderer
    when it first renders, so it continues exactly where the original stands."""

    _kernels: ModuleType

    def __getstate__(self) -> dict[str, Any]:
        state = {k: v for k, v in self.__dict__.items() if k != "_kernels"}
        if "_renderer" in state:
            state["_renderer"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._kernels = _kernels()


class CartPoleStepper(_KernelsAtHand):
    """Steps one float64 state at a time: Gymnasium's equations, through the same kernel, and nothing else.

    No spaces, time limit, rewards or copies: the caller keeps the state (and any step counter), e.g.
    the web app's simulator, which plays whole episodes in a Python loop. A step costs one compiled
    call, several times less than :meth:`CartPoleEnv.step`, and gives the same bits as that step.

    ```python
    >>> stepper = CartPoleStepper()
    >>> state = np.array([0.0, 0.0, 0.01, 0.0])
    >>> stepper.step(state, 1)  # in place; returns terminated
    False

    ```
    """

    def __init__(self, params: CartPoleParams | None = None) -> None:
        self._kernels = _kernels()
        self.set_params(params)

    @property
    def params(self) -> CartPoleParams:
        """The physics in use; change it with :meth:`set_params`."""
        return self._params

    def set_params(self, params: CartPoleParams | None) -> None:
        """Use ``params`` (None: the defaults) from the next step on (any params: there are no spaces to
        keep)."""
        self._params = _check_params(params)
        self._packed = self._kernels.pack_params(self._params, np.dtype(np.float64))

    def step(
        self,
        state: NDArray[np.float64],
        action: int | np.integer[Any],
        out: NDArray[np.float64] | None = None,
    ) -> bool:
        """Advance ``state`` (4,) by one push (0 left, 1 right) into ``out`` (default: ``state``, in
        place); returns ``terminated`` (off the track, or the pole past the angle threshold)."""
        if out is None:
            out = state
        if not (_is_single_state(state) and _is_single_state(out)):
            raise ValueError(f"states must be float64 arrays of shape (4,), got {state!r} and {out!r}")
        if not isinstance(action, (int, np.integer)) or action not in (0, 1):
            raise ValueError(f"action must be 0 (push left) or 1 (push right), got {action!r}")
        # int(): a numpy integer of another width would compile a second specialization.
        return self._kernels.step_single(state, int(action), self._packed, out)


_FLOAT64 = np.dtype(np.float64)


def _is_single_state(array: Any) -> bool:
    return isinstance(array, np.ndarray) and array.dtype == _FLOAT64 and array.shape == (4,)


class _Physics(_KernelsAtHand):
    """What both env forms share: the float type and the physics parameters, changeable live."""

    _dtype: np.dtype[Any]
    _params: CartPoleParams
    _packed: Any

    def _init_physics(self, params: CartPoleParams | None, dtype: DTypeLike) -> None:
        self._dtype = _check_dtype(dtype)
        self._params = _check_params(params)
        self._kernels = _kernels()
        self._packed = self._kernels.pack_params(self._params, self._dtype)

    @property
    def dtype(self) -> np.dtype[Any]:
        """The simulation's float type (observations are float32 regardless)."""
        return self._dtype

    @property
    def params(self) -> CartPoleParams:
        """The physics in use; change it with :meth:`set_params`."""
        return self._params

    def set_params(self, params: CartPoleParams) -> None:
        """Use ``params`` from the next step on (thresholds must stay: they define the spaces)."""
        params = _check_params(params)
        _check_same_thresholds(self._params, params)
        self._params = params
        self._packed = self._kernels.pack_params(params, self._dtype)


class CartPoleVectorEnv(_Physics, VectorEnv[NDArray[np.float32], NDArray[np.int64], NDArray[Any]]):
    """``num_envs`` cart-poles stepped together; a drop-in for Gymnasium's CartPoleVectorEnv.

    Next-step autoreset, ``terminated`` and ``truncated`` kept apart, float32 observations; see the
    module docstring for spaces, rewards, parameters and the choice of ``dtype``. As Gymnasium's:
    ``state`` is the live ``(4, num_envs)`` array (None before ``reset``), ``prev_done`` says which
    envs autoreset on the next step, and ``render_mode="rgb_array"`` makes ``render()`` return one
    600x400 picture per env (Gymnasium's own drawing; needs pygame).
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
        params: CartPoleParams | None = None,
        dtype: DTypeLike = np.float64,
        **physics: Any,
    ) -> None:
        """``max_episode_steps`` defaults to CartPole-v1's (``gymnasium.make_vec`` passes the id's);
        ``physics``: constants of :class:`CartPoleParams` by name (``gravity=5.0``), over ``params``."""
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is None:
            max_episode_steps = _reference_max_episode_steps()
        if (
            isinstance(max_episode_steps, bool)
            or not isinstance(max_episode_steps, (int, np.integer))
            or max_episode_steps < 1
        ):
            raise ValueError(f"max_episode_steps must be an integer >= 1, got {max_episode_steps!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.num_envs = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        self._renderer: Any = None
        self._sutton_barto_reward = bool(sutton_barto_reward)
        self._init_physics(with_physics(params, physics), dtype)

        self.single_action_space = spaces.Discrete(2)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        high = self._params.observation_high()
        self.single_observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        n = self.num_envs
        self._state: NDArray[np.floating[Any]] | None = None  # (4, N), set by reset
        self._steps = np.zeros(n, dtype=np.int32)
        self._done_idx = np.zeros(n, dtype=np.int64)  # envs to autoreset on the next step
        self._n_done = 0
        self._force = np.empty(n, dtype=self._dtype)  # per-env push, rewritten every step
        self._no_reset_states = np.empty((4, 0), dtype=np.float64)
        self._low, self._high = DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH

    @property
    def sutton_barto_reward(self) -> bool:
        """True for the 0 / -1 reward of Sutton and Barto, False for Gymnasium's +1 per step."""
        return self._sutton_barto_reward

    @property
    def state(self) -> NDArray[np.floating[Any]] | None:
        """The live states ``(4, num_envs)`` in the simulation dtype (None before ``reset``), as
        Gymnasium's vector env holds them: ``state[:, i]`` is env ``i``'s (x, x_dot, theta,
        theta_dot). Edits in place apply to the next step; :meth:`set_state` checks what it gets."""
        return self._state

    @property
    def prev_done(self) -> NDArray[np.bool_]:
        """Which envs ended on the last step and so autoreset on the next (a new array)."""
        done = np.zeros(self.num_envs, dtype=np.bool_)
        done[self._done_idx[: self._n_done]] = True
        return done

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Draw all start states (Gymnasium's order); ``options`` may set ``low``/``high`` bounds."""
        super().reset(seed=seed)
        self._low, self._high = maybe_parse_reset_bounds(options, DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH)
        draws = self.np_random.uniform(low=self._low, high=self._high, size=(4, self.num_envs))
        self._state = draws.astype(self._dtype)
        self._steps[:] = 0
        self._n_done = 0
        return np.ascontiguousarray(self._state.T, dtype=np.float32), {}

    def step(
        self, actions: ArrayLike
    ) -> tuple[
        NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]
    ]:
        """Push every cart (0 left, 1 right); envs that finished on the last step autoreset instead."""
        if self._state is None:
            raise ResetNeeded("call reset() before step()")
        a = np.asarray(actions)
        n = self.num_envs
        if a.shape != (n,) or a.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers of shape ({n},), got {a.dtype} {a.shape}")
        if a.dtype != np.int64:
            a = a.astype(np.int64)  # one compiled signature, whatever integer type comes in
        kernels = self._kernels
        # Validate before drawing reset states: a rejected step must leave the generator untouched.
        if not kernels.actions_to_force(a, self._packed[kernels.FORCE_MAG], self._force):
            raise ValueError("actions must be 0 (push left) or 1 (push right)")
        k = self._n_done
        reset_states = (
            self.np_random.uniform(low=self._low, high=self._high, size=(4, k))
            if k
            else self._no_reset_states
        )
        obs = np.empty((n, 4), dtype=np.float32)
        reward = np.empty(n, dtype=np.float32)
        terminated = np.empty(n, dtype=np.bool_)
        truncated = np.empty(n, dtype=np.bool_)
        self._n_done = kernels.vector_step(
            self._state,
            self._force,
            self._packed,
            self.max_episode_steps,
            self._sutton_barto_reward,
            self._steps,
            self._done_idx,
            k,
            reset_states,
            obs,
            reward,
            terminated,
            truncated,
        )
        return obs, reward, terminated, truncated, {}

    def get_state(self) -> NDArray[np.floating[Any]]:
        """A copy of the current states, ``(num_envs, 4)`` in the simulation dtype."""
        if self._state is None:
            raise ResetNeeded("call reset() before get_state()")
        return np.ascontiguousarray(self._state.T)

    def set_state(self, states: ArrayLike, indices: ArrayLike | None = None) -> None:
        """Overwrite the states of envs ``indices`` (all if None) with ``states`` (``(len, 4)``).

        Step counters are kept (a nudge does not extend the time limit) and an env that finished on
        the last step still autoresets on the next one.
        """
        if self._state is None:
            raise ResetNeeded("call reset() before set_state()")
        idx = np.arange(self.num_envs) if indices is None else np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1 or (idx.size and (idx.min() < -self.num_envs or idx.max() >= self.num_envs)):
            raise ValueError(f"indices must be a 1-D array of env indices < {self.num_envs}")
        values = np.asarray(states, dtype=np.float64)
        if values.shape != (idx.size, 4):
            raise ValueError(f"states must have shape ({idx.size}, 4), got {values.shape}")
        if not np.isfinite(values).all():
            raise ValueError("states must be finite")
        self._state[:, idx] = values.T

    def snapshot(self) -> dict[str, Any]:
        """Everything later steps depend on, as JSON-able plain data (for checkpoints and resume).

        States, step counters, the envs awaiting their autoreset, the reset bounds and the random
        generator's state; :meth:`restore` on an env of the same ``num_envs`` and dtype continues
        exactly where this one stands. Physics parameters are not included (they are configuration).
        """
        if self._state is None:
            raise ResetNeeded("call reset() before snapshot()")
        return {
            "num_envs": self.num_envs,
            "dtype": self._dtype.name,
            "state": self.get_state().tolist(),  # float32 and float64 both survive JSON exactly
            "steps": self._steps.tolist(),
            "awaiting_reset": self._done_idx[: self._n_done].tolist(),
            "reset_bounds": [self._low, self._high],
            "np_random": self.np_random.bit_generator.state,
        }

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from a :meth:`snapshot` of an env with the same ``num_envs`` and dtype."""
        if (snapshot.get("num_envs"), snapshot.get("dtype")) != (self.num_envs, self._dtype.name):
            raise ValueError(
                f"snapshot of {snapshot.get('num_envs')} {snapshot.get('dtype')} envs cannot restore "
                f"{self.num_envs} {self._dtype.name} envs"
            )
        state = np.asarray(snapshot["state"], dtype=self._dtype)
        awaiting = np.asarray(snapshot["awaiting_reset"], dtype=np.int64)
        self._state = np.ascontiguousarray(state.T)
        self._steps[:] = snapshot["steps"]
        self._n_done = len(awaiting)
        self._done_idx[: self._n_done] = awaiting
        self._low, self._high = (float(b) for b in snapshot["reset_bounds"])
        self.np_random.bit_generator.state = snapshot["np_random"]

    # A list, as Gymnasium's CartPoleVectorEnv returns and its vector HumanRendering asserts
    # (VectorEnv.render is typed as a tuple).
    def render(self) -> list[NDArray[np.uint8]] | None:  # type: ignore[override]
        """One picture per env (``render_mode="rgb_array"``), drawn by Gymnasium's own vector
        renderer (pygame), fed our states, pole length and track width."""
        if self.render_mode is None:
            logger.warn("render() needs render_mode='rgb_array' at construction")
            return None
        if self._state is None:
            raise ResetNeeded("call reset() before render()")
        if self._renderer is None:
            from gymnasium.envs.classic_control.cartpole import (
                CartPoleVectorEnv as GymnasiumCartPoleVector,
            )

            self._renderer = GymnasiumCartPoleVector(self.num_envs, render_mode=self.render_mode)
        renderer = self._renderer
        renderer.length = self._params.length
        renderer.x_threshold = self._params.x_threshold
        renderer.state = self._state.astype(np.float64)
        pictures: list[NDArray[np.uint8]] = renderer.render()
        return pictures

    def close_extras(self, **kwargs: Any) -> None:
        """Close the renderer, if one was opened."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __repr__(self) -> str:
        spec_id = self.spec.id if self.spec is not None else "CartPole"
        return f"CartPoleVectorEnv({spec_id}, num_envs={self.num_envs}, dtype={self._dtype.name})"


class CartPoleEnv(_Physics, gym.Env[NDArray[np.float32], int]):
    """One cart-pole: Gymnasium's CartPoleEnv on the same kernel as :class:`CartPoleVectorEnv`.

    Passes ``gymnasium.utils.env_checker.check_env``; ``self.state`` can be read and assigned, and
    ``render_mode="rgb_array"``/``"human"`` delegate to Gymnasium's renderer (needs pygame).
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        sutton_barto_reward: bool = False,
        render_mode: str | None = None,
        *,
        params: CartPoleParams | None = None,
        dtype: DTypeLike = np.float64,
        **physics: Any,
    ) -> None:
        """``physics``: constants of :class:`CartPoleParams` by name (``gravity=5.0``), over ``params``."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self._sutton_barto_reward = bool(sutton_barto_reward)
        self._init_physics(with_physics(params, physics), dtype)
        # Gymnasium types Env.action_space as Space[int]; Discrete samples np.int64 (as in its own CartPole).
        self.action_space = spaces.Discrete(2)  # type: ignore[assignment]
        high = self._params.observation_high()
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self._state: NDArray[np.floating[Any]] | None = None
        self._steps_beyond_terminated: int | None = None
        self._renderer: Any = None

    @property
    def state(self) -> NDArray[np.floating[Any]] | None:
        """(x, x_dot, theta, theta_dot), None before reset; edits in place apply to the next step."""
        return self._state

    @state.setter
    def state(self, value: ArrayLike) -> None:
        s = np.array(value, dtype=np.float64)  # always a copy, never the caller's array
        if s.shape != (4,) or not np.isfinite(s).all():
            raise ValueError(f"state must be 4 finite numbers, got {value!r}")
        self._state = s.astype(self._dtype, copy=False)
        self._steps_beyond_terminated = None  # a new state starts afresh, even after termination

    def step(
        self, action: int | np.integer[Any] | NDArray[np.integer[Any]]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Push the cart (0 left, 1 right) for ``tau`` seconds; ``truncated`` is always False here."""
        if isinstance(action, (int, np.integer)) or (
            isinstance(action, np.ndarray) and action.shape == () and action.dtype.kind in "iu"
        ):
            a = int(action)
        else:
            a = -1
        if a not in (0, 1):
            raise ValueError(f"action must be 0 (push left) or 1 (push right), got {action!r}")
        if self._state is None:
            raise ResetNeeded("call reset() before step()")
        # A new array each step, as in Gymnasium: a reference to the old state stays put.
        next_state = np.empty_like(self._state)
        terminated = bool(self._kernels.step_single(self._state, a, self._packed, next_state))
        self._state = next_state
        obs = next_state.astype(np.float32)

        sutton = self._sutton_barto_reward
        if not terminated:
            reward = 0.0 if sutton else 1.0
        elif self._steps_beyond_terminated is None:
            self._steps_beyond_terminated = 0  # the pole just fell
            reward = -1.0 if sutton else 1.0
        else:
            if self._steps_beyond_terminated == 0:
                logger.warn(
                    "You are calling 'step()' even though this environment has already returned "
                    "terminated = True. You should always call 'reset()' once you receive "
                    "'terminated = True' -- any further steps are undefined behavior."
                )
            self._steps_beyond_terminated += 1
            reward = -1.0 if sutton else 0.0

        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, False, {}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Draw a start state (4 numbers from ``self.np_random``, in Gymnasium's order)."""
        super().reset(seed=seed)
        low, high = maybe_parse_reset_bounds(options, DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH)
        self._state = self.np_random.uniform(low=low, high=high, size=(4,)).astype(self._dtype, copy=False)
        self._steps_beyond_terminated = None
        if self.render_mode == "human":
            self.render()
        return self._state.astype(np.float32), {}

    def render(self) -> NDArray[np.uint8] | None:
        """Draw with Gymnasium's own renderer (pygame), fed our state, length and track width."""
        if self.render_mode is None:
            logger.warn("render() needs render_mode='rgb_array' or 'human' at construction")
            return None
        if self._renderer is None:
            from gymnasium.envs.classic_control.cartpole import CartPoleEnv as GymnasiumCartPole

            self._renderer = GymnasiumCartPole(render_mode=self.render_mode)
        renderer = self._renderer
        renderer.length = self._params.length
        renderer.x_threshold = self._params.x_threshold
        renderer.state = None if self._state is None else self._state.astype(np.float64)
        return renderer.render()

    def close(self) -> None:
        """Close the renderer, if one was opened."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _check_same_thresholds(old: CartPoleParams, new: CartPoleParams) -> None:
    if (old.x_threshold, old.theta_threshold_radians) != (
        new.x_threshold,
        new.theta_threshold_radians,
    ):
        raise ValueError(
            "x_threshold and theta_threshold_radians define the observation space and cannot change "
            "on a live env; make a new env with these params instead"
        )


__all__ = [
    "DEFAULT_RESET_HIGH",
    "DEFAULT_RESET_LOW",
    "REFERENCE_IDS",
    "CartPoleEnv",
    "CartPoleParams",
    "CartPoleStepper",
    "CartPoleVectorEnv",
    "KinematicsIntegrator",
    "register_fast_envs",
    "step_cartpole",
    "step_cartpole_columns",
]
