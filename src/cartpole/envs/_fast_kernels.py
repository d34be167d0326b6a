"""Numba kernels behind :mod:`cartpole.envs.fast` (imported lazily, on first use).

This is the only place where the cart-pole equations are written. :func:`dynamics` advances a batch of
states held column-wise (``state[k, i]`` is component ``k`` of env ``i``), which lets LLVM vectorize
the loop; everything else here is bookkeeping around it (actions to forces, time limits, autoreset,
observations). Every kernel is compiled lazily on first call and cached on disk (``cache=True``), so
importing this module costs only the import of numba itself.

Exactness: without ``fastmath`` LLVM neither reassociates nor fuses (FMA) floating-point operations,
so float64 states follow Gymnasium's numpy expressions bit for bit, operation for operation; the
float64 sine and cosine are the C library's, the same functions numpy calls (except numpy on AVX-512
CPUs: see :mod:`cartpole.envs.fast`). The float32 path uses a polynomial sine/cosine instead (LLVM
vectorizes it; it cannot vectorize a libm call).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit, types
from numba.extending import overload
from numpy.typing import NDArray

if TYPE_CHECKING:
    from cartpole.envs.params import CartPoleParams

# Layout of the parameter vector the kernels read (see pack_params).
GRAVITY, MASSPOLE, TOTAL_MASS, LENGTH, POLEMASS_LENGTH = 0, 1, 2, 3, 4
FORCE_MAG, TAU, THETA_THRESHOLD, X_THRESHOLD, FOUR_THIRDS, SEMI_IMPLICIT = 5, 6, 7, 8, 9, 10
N_PARAMS = 11

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}


def pack_params(params: CartPoleParams, dtype: np.dtype[Any]) -> NDArray[np.floating[Any]]:
    """The parameter vector of ``params`` in the state's dtype.

    Derived values are computed in float64 exactly as Gymnasium computes them, then cast once, so the
    float64 kernel multiplies and divides by the very same numbers as Gymnasium.
    """
    p = np.empty(N_PARAMS, dtype=dtype)
    p[GRAVITY] = params.gravity
    p[MASSPOLE] = params.masspole
    p[TOTAL_MASS] = params.total_mass
    p[LENGTH] = params.length
    p[POLEMASS_LENGTH] = params.polemass_length
    p[FORCE_MAG] = params.force_mag
    p[TAU] = params.tau
    p[THETA_THRESHOLD] = params.theta_threshold_radians
    p[X_THRESHOLD] = params.x_threshold
    p[FOUR_THIRDS] = 4.0 / 3.0
    p[SEMI_IMPLICIT] = 0.0 if params.kinematics_integrator == "euler" else 1.0
    return p


# float32 sine/cosine: Cody-Waite reduction by pi/2 (pi/2 split in three parts so that j * part is
# exact), then Cephes' minimax polynomials on [-pi/4, pi/4]. Absolute error < 1e-7 for |theta| up to
# about 1e3 rad; CartPole terminates at 0.21 rad.
_F32 = np.float32
_TWO_OVER_PI = _F32(2.0 / math.pi)
_PIO2_1 = _F32(1.5703125)
_PIO2_2 = _F32(4.837512969970703125e-4)
_PIO2_3 = _F32(7.54978995489188216e-8)
_ROUNDER = _F32(12582912.0)  # 1.5 * 2**23: adding and subtracting it rounds to an integer
_S1, _S2, _S3 = _F32(-1.6666654611e-1), _F32(8.3321608736e-3), _F32(-1.9515295891e-4)
_C1, _C2, _C3 = _F32(4.166664568298827e-2), _F32(-1.388731625493765e-3), _F32(2.443315711809948e-5)
_ONE, _HALF = _F32(1.0), _F32(0.5)


def sin_cos(theta: float) -> tuple[float, float]:
    """(sin, cos) of theta; in kernels, libm for float64 and a vectorizable polynomial for float32."""
    return math.sin(theta), math.cos(theta)


# numba checks that the overload and its implementations have identical parameters, annotations
# included, so these three functions are left unannotated.
@overload(sin_cos, inline="always")
def _sin_cos_overload(theta):
    if isinstance(theta, types.Float) and theta.bitwidth == 32:

        def sin_cos_f32(theta):
            j = (theta * _TWO_OVER_PI + _ROUNDER) - _ROUNDER
            r = ((theta - j * _PIO2_1) - j * _PIO2_2) - j * _PIO2_3
            z = r * r
            s = r + r * z * (_S1 + z * (_S2 + z * _S3))
            c = _ONE - _HALF * z + z * z * (_C1 + z * (_C2 + z * _C3))
            quadrant = np.int32(j)
            swap = (quadrant & 1) != 0
            sin_t = c if swap else s
            cos_t = s if swap else c
            sin_t = -sin_t if (quadrant & 2) != 0 else sin_t
            cos_t = -cos_t if ((quadrant + 1) & 2) != 0 else cos_t
            return sin_t, cos_t

        return sin_cos_f32

    def sin_cos_libm(theta):
        return math.sin(theta), math.cos(theta)

    return sin_cos_libm


@njit(**_JIT, inline="always")
def physics_constants(p: NDArray[np.floating[Any]]) -> tuple[float, ...]:
    """What :func:`advance` reads of the parameter vector ``p``, as one tuple: read once before a loop,
    so that the loop's stores cannot alias it and LLVM vectorizes the loop."""
    return (
        p[GRAVITY],
        p[MASSPOLE],
        p[TOTAL_MASS],
        p[LENGTH],
        p[POLEMASS_LENGTH],
        p[TAU],
        p[THETA_THRESHOLD],
        p[X_THRESHOLD],
        p[FOUR_THIRDS],
        p[SEMI_IMPLICIT],
    )


@njit(**_JIT, inline="always")
def advance(
    x: float, x_dot: float, theta: float, theta_dot: float, force: float, constants: tuple[float, ...]
) -> tuple[float, float, float, float, bool]:
    """One cart-pole, one step of ``tau`` under ``force``: the next (x, x_dot, theta, theta_dot) and
    whether it terminated (left the track, or its pole passed the angle threshold).

    The equations and the order of every operation are Gymnasium's (Florian 2007, "Correct equations
    for the dynamics of the cart-pole system"), so float64 results are bit-identical to it. This is
    the only place they are written: :func:`dynamics` runs it over a batch, and a compiled policy
    that plays whole episodes (:mod:`cartpole.agents.nn.greedy_play`) runs it too.
    """
    (
        gravity,
        masspole,
        total_mass,
        length,
        polemass_length,
        tau,
        theta_threshold,
        x_threshold,
        four_thirds,
        semi_implicit,
    ) = constants
    sintheta, costheta = sin_cos(theta)
    temp = (force + polemass_length * (theta_dot * theta_dot) * sintheta) / total_mass
    thetaacc = (gravity * sintheta - costheta * temp) / (
        length * (four_thirds - masspole * (costheta * costheta) / total_mass)
    )
    xacc = temp - polemass_length * thetaacc * costheta / total_mass
    if semi_implicit != 0:
        x_dot = x_dot + tau * xacc
        x = x + tau * x_dot
        theta_dot = theta_dot + tau * thetaacc
        theta = theta + tau * theta_dot
    else:  # Euler, Gymnasium's default
        x = x + tau * x_dot
        x_dot = x_dot + tau * xacc
        theta = theta + tau * theta_dot
        theta_dot = theta_dot + tau * thetaacc
    terminated = (
        (x < -x_threshold) | (x > x_threshold) | (theta < -theta_threshold) | (theta > theta_threshold)
    )
    return x, x_dot, theta, theta_dot, terminated


@njit(**_JIT)
def dynamics(
    state: NDArray[np.floating[Any]],
    force: NDArray[np.floating[Any]],
    p: NDArray[np.floating[Any]],
    terminated: NDArray[np.bool_],
) -> None:
    """Advance ``state`` (4, N) by one step of ``tau`` under ``force`` (N,), in place (:func:`advance`
    for every env). ``terminated[i]`` is set when env ``i`` leaves the track or its pole passes the
    angle threshold."""
    constants = physics_constants(p)
    xs, x_dots, thetas, theta_dots = state[0], state[1], state[2], state[3]
    for i in range(xs.shape[0]):
        xs[i], x_dots[i], thetas[i], theta_dots[i], terminated[i] = advance(
            xs[i], x_dots[i], thetas[i], theta_dots[i], force[i], constants
        )


@njit(**_JIT)
def actions_to_force(action: NDArray[np.int64], force_mag: float, force: NDArray[np.floating[Any]]) -> bool:
    """Write +force_mag for action 1 and -force_mag for 0; False (nothing written) if any is not 0/1."""
    bad = False
    for i in range(action.shape[0]):
        bad |= (action[i] & ~1) != 0
    if bad:
        return False
    # A float array of forces (not the int64 actions) keeps dynamics' loop 8 lanes wide in float32.
    for i in range(action.shape[0]):
        force[i] = force_mag if action[i] == 1 else -force_mag
    return True


@njit(**_JIT)
def step_states(
    state: NDArray[np.floating[Any]],
    action: NDArray[np.int64],
    p: NDArray[np.floating[Any]],
    terminated: NDArray[np.bool_],
) -> bool:
    """Actions to forces, then :func:`dynamics`; False (state untouched) if an action is not 0/1."""
    force = np.empty(action.shape[0], dtype=state.dtype)
    if not actions_to_force(action, p[FORCE_MAG], force):
        return False
    dynamics(state, force, p, terminated)
    return True


@njit(**_JIT)
def step_single(
    state: NDArray[np.floating[Any]],
    action: int,
    p: NDArray[np.floating[Any]],
    out: NDArray[np.floating[Any]],
) -> bool:
    """One env, one step through :func:`dynamics`: ``out`` (4,) gets the next state of ``state`` (4,).

    ``action`` must be 0 or 1 (the caller checks); ``out`` may be ``state`` itself. Returns
    ``terminated``. For callers that step a single state in a Python loop, where one dispatch with
    no buffers to pass is what a step costs.
    """
    column = np.empty((4, 1), dtype=out.dtype)
    for k in range(4):
        column[k, 0] = state[k]
    force = np.empty(1, dtype=out.dtype)
    force[0] = p[FORCE_MAG] if action == 1 else -p[FORCE_MAG]
    terminated = np.empty(1, dtype=np.bool_)
    dynamics(column, force, p, terminated)
    for k in range(4):
        out[k] = column[k, 0]
    return terminated[0]


@njit(**_JIT)
def vector_step(
    state: NDArray[np.floating[Any]],
    force: NDArray[np.floating[Any]],
    p: NDArray[np.floating[Any]],
    max_episode_steps: int,
    sutton_barto_reward: bool,
    steps: NDArray[np.int32],
    done_idx: NDArray[np.int64],
    n_done: int,
    reset_states: NDArray[np.float64],
    obs: NDArray[np.float32],
    reward: NDArray[np.float32],
    terminated: NDArray[np.bool_],
    truncated: NDArray[np.bool_],
) -> int:
    """One step of Gymnasium's CartPoleVectorEnv with next-step autoreset; returns the new n_done.

    ``done_idx[:n_done]`` lists the envs that finished on the previous step: they get
    ``reset_states[:, j]`` (drawn by the caller, in Gymnasium's order), reward 0 and both flags
    False, exactly as Gymnasium does after stepping them. On return ``done_idx`` lists the envs that
    finished on this step. ``force`` comes from :func:`actions_to_force`, called first so that a bad
    action is rejected before the caller draws any random numbers.
    """
    n = force.shape[0]
    dynamics(state, force, p, terminated)
    one = np.float32(1.0)
    for i in range(n):
        s = steps[i] + 1
        steps[i] = s
        truncated[i] = s >= max_episode_steps
        # -float32(terminated) gives -0.0 on ordinary steps, as Gymnasium's vector env does.
        reward[i] = -np.float32(terminated[i]) if sutton_barto_reward else one
    for j in range(n_done):
        i = done_idx[j]
        for k in range(4):
            state[k, i] = reset_states[k, j]
        steps[i] = 0
        reward[i] = 0.0
        terminated[i] = False
        truncated[i] = False
    # Flat indexing: LLVM vectorizes this transpose; obs[i, k] in a nested loop it does not.
    xs, x_dots, thetas, theta_dots = state[0], state[1], state[2], state[3]
    flat = obs.reshape(-1)
    for i in range(n):
        flat[4 * i] = np.float32(xs[i])
        flat[4 * i + 1] = np.float32(x_dots[i])
        flat[4 * i + 2] = np.float32(thetas[i])
        flat[4 * i + 3] = np.float32(theta_dots[i])
    # Branch-free compaction: the write is harmless when env i is not done (slot gets overwritten).
    m = 0
    for i in range(n):
        done_idx[m] = i
        m += terminated[i] | truncated[i]
    return m
