"""CartPoleStepper (one float64 state, stepped in place) against the single env, bit for bit.

The single env is checked against Gymnasium in tests/test_fast_env.py; the stepper must give the very
same states and ``terminated`` flags, under any physics, so that the web app's episodes stay exact.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from cartpole.envs.fast import CartPoleEnv, CartPoleParams, CartPoleStepper, step_cartpole

PHYSICS = [
    CartPoleParams(),
    CartPoleParams(gravity=25.0, length=1.7, masspole=0.6, masscart=0.3, force_mag=35.0),
    CartPoleParams(gravity=0.0, force_mag=0.0),
    CartPoleParams(kinematics_integrator="semi-implicit euler", masspole=2.0, tau=0.01),
]


def random_states(n: int, seed: int) -> np.ndarray:
    """States across and beyond the thresholds, so that about half of the steps terminate."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, size=(n, 4)) * [3.0, 3.0, 0.3, 3.5]


def env_step(env: CartPoleEnv, state: np.ndarray, action: int) -> tuple[np.ndarray, bool]:
    env.state = state
    _, _, terminated, _, _ = env.step(action)
    assert env.state is not None
    return env.state, terminated


@pytest.mark.parametrize("params", PHYSICS, ids=["default", "heavy", "no-force", "semi-implicit"])
def test_stepper_matches_the_single_env_bit_for_bit(params: CartPoleParams) -> None:
    env, stepper = CartPoleEnv(params=params), CartPoleStepper(params)
    states = random_states(2_000, seed=3)
    actions = np.random.default_rng(4).integers(0, 2, len(states))
    flags = []
    for state, action in zip(states, actions, strict=True):
        expected, terminated = env_step(env, state, int(action))
        before = state.copy()
        out = np.empty(4)
        assert stepper.step(state, action, out=out) is terminated
        assert out.tobytes() == expected.tobytes()
        assert state.tobytes() == before.tobytes()  # out= leaves the input alone
        assert stepper.step(state, int(action)) is terminated  # in place
        assert state.tobytes() == expected.tobytes()
        flags.append(terminated)
    assert 0.2 < np.mean(flags) < 0.8  # both outcomes were exercised


def test_stepper_follows_the_env_along_episodes() -> None:
    """Lock-step trajectories (long ones too), with the env's own start states."""
    env, stepper = CartPoleEnv(), CartPoleStepper()
    rng = np.random.default_rng(5)
    for seed in range(20):
        env.reset(seed=seed)
        assert env.state is not None
        state = env.state.copy()
        for _ in range(500):
            action = int(state[2] + 0.5 * state[3] > 0) if rng.random() < 0.9 else int(rng.integers(2))
            _, _, terminated, _, _ = env.step(action)
            assert stepper.step(state, action) is terminated
            assert state.tobytes() == env.state.tobytes()
            if terminated:
                break


def test_stepper_matches_the_batched_step() -> None:
    params = PHYSICS[1]
    states = random_states(500, seed=6)
    actions = np.random.default_rng(7).integers(0, 2, len(states))
    expected, terminated = step_cartpole(states, actions, params)
    stepper = CartPoleStepper(params)
    for i in range(len(states)):
        assert stepper.step(states[i], actions[i]) is bool(terminated[i])
    assert states.tobytes() == expected.tobytes()


def test_set_params_applies_from_the_next_step() -> None:
    stepper = CartPoleStepper()
    heavy = replace(CartPoleParams(), gravity=30.0, x_threshold=1.0)  # thresholds may change too
    state = np.array([0.995, 1.0, 0.05, 0.2])  # 1.015 m after the step: only off the new track
    stepper.set_params(heavy)
    assert stepper.params == heavy
    expected, terminated = step_cartpole(state[None], np.array([1]), heavy)
    assert stepper.step(state, 1) is bool(terminated[0]) is True  # past the new 1.0 m track edge
    assert state.tobytes() == expected[0].tobytes()


@pytest.mark.parametrize(
    ("state", "action", "out"),
    [
        (np.zeros(4), 2, None),
        (np.zeros(4), -1, None),
        (np.zeros(4), 1.0, None),
        (np.zeros(4), "1", None),
        (np.zeros(4, dtype=np.float32), 1, None),
        (np.zeros(5), 1, None),
        (np.zeros((1, 4)), 1, None),
        ([0.0, 0.0, 0.0, 0.0], 1, None),
        (np.zeros(4), 1, np.zeros(4, dtype=np.float32)),
    ],
)
def test_bad_actions_and_states_are_rejected_untouched(state: Any, action: Any, out: Any) -> None:
    before = np.array(state, copy=True)
    with pytest.raises(ValueError, match="must be"):
        CartPoleStepper().step(state, action, out=out)
    np.testing.assert_array_equal(state, before)


def test_numpy_integer_actions_are_accepted() -> None:
    a, b = np.zeros(4), np.zeros(4)
    CartPoleStepper().step(a, np.int32(1))
    CartPoleStepper().step(b, 1)
    assert a.tobytes() == b.tobytes()
