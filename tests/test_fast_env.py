"""The fast CartPole (cartpole.envs.fast) against Gymnasium's own, in lock-step.

float64 must reproduce Gymnasium bit for bit (observations, rewards, both flags, internal states),
float32 must stay within 1e-5 per step from the same state; plus autoreset, parameters, errors and
registration.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv as GymCartPoleEnv
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv as GymCartPoleVectorEnv
from gymnasium.utils.env_checker import check_env
from numpy.typing import NDArray

from cartpole.envs.fast import (
    CartPoleEnv,
    CartPoleParams,
    CartPoleVectorEnv,
    register_fast_envs,
    step_cartpole,
)

pytestmark = pytest.mark.filterwarnings("ignore:.*CartPole-v0 is out of date:DeprecationWarning")


def numpy_trig_is_libm() -> bool:
    """Whether numpy's float64 sin/cos (which Gymnasium calls) are the C library's (ours).

    True on AMD, ARM and Intel without AVX-512; with AVX-512, numpy uses Intel's SVML instead and
    differs from libm by an ulp now and then (numpy#23523), so Gymnasium itself does too.
    """
    angles = np.random.default_rng(0).uniform(-1.0, 1.0, 10_000)
    libm = np.array([(math.sin(a), math.cos(a)) for a in angles])
    return bool((np.sin(angles) == libm[:, 0]).all() and (np.cos(angles) == libm[:, 1]).all())


bit_exact = pytest.mark.skipif(
    not numpy_trig_is_libm(),
    reason="numpy's float64 sin/cos on this CPU are not libm's (AVX-512 SVML, numpy#23523); "
    "run with NPY_DISABLE_CPU_FEATURES=AVX512_SKX (or the CPU's AVX-512 groups) to compare bits",
)

N_STEPS = 10_000  # per lock-step run; vector runs step N_ENVS envs each time
N_ENVS = 8
F32_TOL = 1e-5

Policy = Callable[[NDArray[np.float32]], NDArray[np.int64]]


def make_policy(kind: str, seed: int) -> Policy:
    """Actions for a batch of observations: random (short episodes), balancing (truncations), mixed."""
    rng = np.random.default_rng(seed)

    def policy(obs: NDArray[np.float32]) -> NDArray[np.int64]:
        random_actions = rng.integers(0, 2, len(obs))
        balancing = (obs[:, 2] + 0.5 * obs[:, 3] > 0).astype(np.int64)
        if kind == "random":
            return random_actions
        if kind == "balancing":
            return balancing
        return np.where(rng.random(len(obs)) < 0.2, random_actions, balancing)  # "mixed"

    return policy


def assert_same_bits(ours: NDArray[Any], reference: NDArray[Any], what: str) -> None:
    """Equal dtype, shape and bytes: stricter than ==, which would let -0.0 pass for 0.0."""
    assert ours.dtype == reference.dtype, what
    assert ours.shape == reference.shape, what
    if ours.tobytes() != reference.tobytes():
        bits = ours.view(f"u{ours.itemsize}") != reference.view(f"u{reference.itemsize}")
        where = tuple(int(i[0]) for i in np.nonzero(bits))
        raise AssertionError(f"{what}: at {where}, {ours[where]!r} != {reference[where]!r}")


@pytest.fixture(scope="module", autouse=True)
def _registered() -> None:
    register_fast_envs()


# --------------------------------------------------------------------------- float64: bit for bit


@bit_exact
@pytest.mark.parametrize(
    ("env_id", "policy_kind", "kwargs", "options"),
    [
        ("CartPole-v1", "random", {}, None),
        ("CartPole-v1", "balancing", {}, None),
        ("CartPole-v0", "mixed", {"sutton_barto_reward": True}, None),
        ("CartPole-v1", "mixed", {}, {"low": -0.2, "high": 0.1}),
    ],
)
def test_vector_float64_matches_gymnasium_bit_for_bit(
    env_id: str, policy_kind: str, kwargs: dict[str, Any], options: dict[str, float] | None
) -> None:
    ref = gym.make_vec(env_id, num_envs=N_ENVS, vectorization_mode="vector_entry_point", **kwargs)
    ours = gym.make_vec(
        "cartpole/" + env_id,
        num_envs=N_ENVS,
        vectorization_mode="vector_entry_point",
        dtype=np.float64,
        **kwargs,
    )
    policy = make_policy(policy_kind, seed=1)
    obs_ref, _ = ref.reset(seed=123, options=options)
    obs, _ = ours.reset(seed=123, options=options)
    assert_same_bits(obs, obs_ref, "reset observation")
    n_terminated = n_truncated = 0
    for t in range(N_STEPS):
        actions = policy(obs_ref)
        got, want = ours.step(actions), ref.step(actions)
        for name, a, b in zip(("obs", "reward", "terminated", "truncated"), got, want, strict=False):
            assert_same_bits(a, b, f"step {t} {name}")
        assert_same_bits(ours.unwrapped.get_state(), ref.unwrapped.state.T, f"step {t} state")
        obs_ref = want[0]
        n_terminated += int(want[2].sum())
        n_truncated += int(want[3].sum())
    # The run must have exercised what it claims to: both kinds of episode end where expected.
    if policy_kind != "balancing":
        assert n_terminated > 0
    if policy_kind != "random":
        assert n_truncated > 0


@bit_exact
@pytest.mark.parametrize(
    ("env_id", "policy_kind", "kwargs"),
    [
        ("CartPole-v1", "random", {}),
        ("CartPole-v1", "mixed", {}),
        ("CartPole-v0", "balancing", {}),
        ("CartPole-v1", "mixed", {"sutton_barto_reward": True}),
    ],
)
def test_single_float64_matches_gymnasium_bit_for_bit(
    env_id: str, policy_kind: str, kwargs: dict[str, Any]
) -> None:
    ref = gym.make(env_id, **kwargs)
    ours = gym.make("cartpole/" + env_id, **kwargs)
    assert ours.unwrapped.dtype == np.float64  # the single env's default: exact
    policy = make_policy(policy_kind, seed=2)
    obs_ref, _ = ref.reset(seed=7)
    obs, _ = ours.reset(seed=7)
    assert_same_bits(obs, obs_ref, "reset observation")
    ends = {"terminated": 0, "truncated": 0}
    for t in range(N_STEPS):
        action = int(policy(obs_ref[None])[0])
        obs, reward, terminated, truncated, _ = ours.step(action)
        obs_ref, reward_ref, terminated_ref, truncated_ref, _ = ref.step(action)
        assert_same_bits(obs, obs_ref, f"step {t} obs")
        assert_same_bits(ours.unwrapped.state, ref.unwrapped.state, f"step {t} state")
        assert (reward, terminated, truncated) == (reward_ref, terminated_ref, truncated_ref), t
        assert type(reward) is type(reward_ref)
        if terminated or truncated:
            ends["terminated" if terminated else "truncated"] += 1
            obs_ref, _ = ref.reset()  # unseeded: both continue their own generator
            obs, _ = ours.reset()
            assert_same_bits(obs, obs_ref, f"step {t} reset observation")
    if policy_kind != "balancing":
        assert ends["terminated"] > 0
    if policy_kind != "random":
        assert ends["truncated"] > 0


def test_time_limits_are_gymnasiums() -> None:
    for env_id in ("CartPole-v0", "CartPole-v1"):
        limit = gym.spec(env_id).max_episode_steps
        assert limit is not None
        vec = gym.make_vec("cartpole/" + env_id, num_envs=2, vectorization_mode="vector_entry_point")
        vec.reset(seed=0)
        for _ in range(limit - 1):
            _, _, _, truncated, _ = vec.step(np.zeros(2, dtype=np.int64))
            assert not truncated.any()
            vec.unwrapped.set_state(np.zeros((2, 4)))  # keep both poles upright forever
        _, _, terminated, truncated, _ = vec.step(np.zeros(2, dtype=np.int64))
        assert truncated.all() and not terminated.any()


# --------------------------------------------------------------------------- float32: within 1e-5


def test_vector_float32_within_tolerance_from_the_same_state() -> None:
    ref = GymCartPoleVectorEnv(num_envs=N_ENVS)
    ours = CartPoleVectorEnv(num_envs=N_ENVS, dtype=np.float32)
    assert CartPoleVectorEnv(num_envs=N_ENVS).dtype == np.float64  # the default, as the single env's
    policy = make_policy("mixed", seed=3)
    obs_ref, _ = ref.reset(seed=5)
    obs, _ = ours.reset(seed=5)
    np.testing.assert_array_equal(obs, obs_ref)  # float64 draws cast to float32: identical
    worst = 0.0
    for t in range(N_STEPS):
        ours.set_state(ref.state.T)  # the same state, rounded to float32
        actions = policy(obs_ref)
        obs, reward, terminated, truncated, _ = ours.step(actions)
        obs_ref, reward_ref, terminated_ref, truncated_ref, _ = ref.step(actions)
        error = float(np.abs(obs.astype(np.float64) - obs_ref).max())
        worst = max(worst, error)
        assert error <= F32_TOL, f"step {t}: error {error}"
        # Plain asserts, not np.testing: 10,000 steps of np.testing cost seconds.
        assert (reward == reward_ref).all(), t
        assert (terminated == terminated_ref).all() and (truncated == truncated_ref).all(), t
    assert worst > 0  # float32 really is in use


def test_single_float32_within_tolerance_from_the_same_state() -> None:
    ref = GymCartPoleEnv()
    ours = CartPoleEnv(dtype=np.float32)
    policy = make_policy("mixed", seed=4)
    obs_ref, _ = ref.reset(seed=9)
    ours.reset(seed=9)
    for t in range(N_STEPS):
        assert ref.state is not None
        ours.state = ref.state
        action = int(policy(obs_ref[None])[0])
        obs, reward, terminated, _, _ = ours.step(action)
        obs_ref, reward_ref, terminated_ref, _, _ = ref.step(action)
        error = float(np.abs(obs.astype(np.float64) - obs_ref).max())
        assert error <= F32_TOL, f"step {t}: error {error}"
        assert (reward, terminated) == (reward_ref, terminated_ref), t
        if terminated:
            obs_ref, _ = ref.reset()


def test_step_cartpole_float32_over_the_observation_box() -> None:
    """Far from upright, fast and semi-implicit too: the polynomial sine/cosine holds everywhere."""
    rng = np.random.default_rng(11)
    n = 50_000
    high = np.array([2.4, 3.0, 0.4, 3.5])
    states = rng.uniform(-high, high, size=(n, 4))
    actions = rng.integers(0, 2, n)
    for integrator in ("euler", "semi-implicit euler"):
        params = CartPoleParams(kinematics_integrator=integrator)
        ref = GymCartPoleVectorEnv(num_envs=n)
        ref.kinematics_integrator = integrator
        ref.reset(seed=0)
        ref.state = states.T.copy()
        ref.step(actions)
        want = ref.state.T
        got, terminated = step_cartpole(states.astype(np.float32), actions, params)
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=0, atol=F32_TOL)
        limits = [params.x_threshold, params.theta_threshold_radians]
        near = np.abs(np.abs(want[:, [0, 2]]) - limits) < F32_TOL  # float32 may round across
        expected = (np.abs(want[:, [0, 2]]) > limits).any(1)
        np.testing.assert_array_equal(terminated[~near.any(1)], expected[~near.any(1)])


@bit_exact
@pytest.mark.parametrize("integrator", ["euler", "semi-implicit euler"])
def test_step_cartpole_float64_is_gymnasiums_bit_for_bit(integrator: str) -> None:
    rng = np.random.default_rng(12)
    n = 50_000
    states = rng.uniform(-1.0, 1.0, size=(n, 4)) * [2.4, 3.0, 0.4, 3.5]
    actions = rng.integers(0, 2, n)
    ref = GymCartPoleVectorEnv(num_envs=n)
    ref.kinematics_integrator = integrator
    ref.reset(seed=0)
    ref.state = states.T.copy()
    _, _, terminated_ref, _, _ = ref.step(actions)
    got, terminated = step_cartpole(states, actions, CartPoleParams(kinematics_integrator=integrator))
    assert_same_bits(got, np.ascontiguousarray(ref.state.T), integrator)
    np.testing.assert_array_equal(terminated, terminated_ref)


# --------------------------------------------------------------------------- semantics


def test_autoreset_on_the_step_after_done() -> None:
    env = CartPoleVectorEnv(num_envs=4, dtype=np.float64)
    env.reset(seed=0)
    ones = np.ones(4, dtype=np.int64)
    for _ in range(100):
        _, _, terminated, truncated, _ = env.step(ones)  # always push right: falls in ~10 steps
        done = terminated | truncated
        if done.any():
            break
    assert done.any()
    obs, reward, terminated, truncated, _ = env.step(ones)
    assert (reward[done] == 0).all()
    assert not terminated[done].any() and not truncated[done].any()
    state = env.get_state()
    np.testing.assert_array_equal(obs[done], state[done].astype(np.float32))
    assert (np.abs(state[done]) <= 0.05).all()  # a fresh start state, not a stepped one
    _, reward, _, _, _ = env.step(ones)  # the next step is an ordinary step again
    assert (reward[done] == 1).all()


def test_reset_options_bound_start_states_and_autoresets() -> None:
    low, high = 0.1, 0.2
    inside = lambda obs: ((obs >= np.float32(low)) & (obs <= np.float32(high))).all()  # noqa: E731
    env = CartPoleVectorEnv(num_envs=64)
    obs, _ = env.reset(seed=1, options={"low": low, "high": high})
    assert inside(obs)
    previous_done = np.zeros(64, dtype=bool)
    n_autoresets = 0
    for _ in range(60):
        obs, _, terminated, truncated, _ = env.step(np.zeros(64, dtype=np.int64))
        assert inside(obs[previous_done])  # the autoreset draws use the same bounds
        n_autoresets += int(previous_done.sum())
        previous_done = terminated | truncated
    assert n_autoresets > 0
    single = CartPoleEnv()
    obs1, _ = single.reset(seed=1, options={"low": low, "high": high})
    assert inside(obs1)
    with pytest.raises(ValueError, match="Lower bound"):
        env.reset(options={"low": 0.3, "high": 0.1})


def test_sutton_barto_reward() -> None:
    env = CartPoleVectorEnv(num_envs=2, sutton_barto_reward=True)
    env.reset(seed=0)
    seen_terminal = False
    for _ in range(100):
        _, reward, terminated, _, _ = env.step(np.ones(2, dtype=np.int64))
        np.testing.assert_array_equal(reward, np.where(terminated, -1.0, 0.0))
        seen_terminal |= bool(terminated.any())
    assert seen_terminal
    single = CartPoleEnv(sutton_barto_reward=True)
    single.reset(seed=0)
    rewards = []
    terminated = False
    while not terminated:
        _, r, terminated, _, _ = single.step(1)
        rewards.append(r)
    assert rewards[-1] == -1.0 and set(rewards[:-1]) == {0.0}


@pytest.mark.filterwarnings("ignore:.*Box observation space m:UserWarning")  # Gymnasium's own too
@pytest.mark.filterwarnings("ignore:.*alternative render modes:UserWarning")
def test_check_env_passes() -> None:
    check_env(CartPoleEnv())
    check_env(CartPoleEnv(dtype=np.float32))
    check_env(gym.make("cartpole/CartPole-v1").unwrapped)


def test_spaces_are_gymnasiums() -> None:
    ours, ref = CartPoleVectorEnv(num_envs=3), GymCartPoleVectorEnv(num_envs=3)
    assert ours.single_observation_space == ref.single_observation_space
    assert ours.observation_space == ref.observation_space
    assert ours.action_space == ref.action_space
    assert CartPoleEnv().observation_space == GymCartPoleEnv().observation_space


# --------------------------------------------------------------------------- physics parameters


def steps_until_fall(params: CartPoleParams) -> int:
    """Steps until an uncontrolled pole, released at 0.05 rad, terminates."""
    env = CartPoleEnv(params=params)
    env.reset(seed=0)
    env.state = [0.0, 0.0, 0.05, 0.0]
    for t in range(1, 1000):
        if env.step(0)[2]:
            return t
    raise AssertionError("the pole never fell")


def test_parameters_change_the_dynamics_as_the_equations_say() -> None:
    free = CartPoleParams(force_mag=0.0)  # no push: only gravity acts
    base = steps_until_fall(free)
    assert steps_until_fall(dataclasses.replace(free, gravity=20.0)) < base
    assert steps_until_fall(dataclasses.replace(free, length=2.0)) > base  # longer pole, slower fall

    # One Euler step from rest, by hand (Florian 2007, eq. 23 with no friction).
    p = CartPoleParams(gravity=11.0, masscart=2.0, masspole=0.3, length=0.8, force_mag=7.0)
    theta0 = 0.1
    (state,), _ = step_cartpole(np.array([[0.0, 0.0, theta0, 0.0]]), np.array([1]), p)
    total = p.masscart + p.masspole
    temp = p.force_mag / total
    thetaacc = (p.gravity * math.sin(theta0) - math.cos(theta0) * temp) / (
        p.length * (4 / 3 - p.masspole * math.cos(theta0) ** 2 / total)
    )
    xacc = temp - p.masspole * p.length * thetaacc * math.cos(theta0) / total
    np.testing.assert_allclose(state, [0.0, p.tau * xacc, theta0, p.tau * thetaacc], rtol=1e-12)

    semi = dataclasses.replace(p, kinematics_integrator="semi-implicit euler")
    (state,), _ = step_cartpole(np.array([[0.0, 0.0, theta0, 0.0]]), np.array([1]), semi)
    np.testing.assert_allclose(state[[0, 2]], [p.tau**2 * xacc, theta0 + p.tau**2 * thetaacc])


def test_set_params_on_a_live_env_applies_from_the_next_step() -> None:
    a, b = CartPoleVectorEnv(num_envs=16), CartPoleVectorEnv(num_envs=16)
    a.reset(seed=3)
    b.reset(seed=3)
    actions = np.zeros(16, dtype=np.int64)
    for env in (a, b):
        env.step(actions)
    heavy = dataclasses.replace(a.params, gravity=30.0)
    before = b.get_state()
    b.set_params(heavy)
    assert b.params == heavy
    obs_a = a.step(actions)[0]
    obs_b = b.step(actions)[0]
    assert not np.array_equal(obs_a, obs_b)
    expected, _ = step_cartpole(before, actions, heavy)
    np.testing.assert_array_equal(obs_b, expected.astype(np.float32))  # observations are float32

    single = CartPoleEnv()
    single.reset(seed=0)
    single.set_params(heavy)
    start = single.state.copy()  # type: ignore[union-attr]
    obs, *_ = single.step(1)
    np.testing.assert_array_equal(
        obs, step_cartpole(start[None], np.array([1]), heavy)[0][0].astype(np.float32)
    )


def test_set_state_and_get_state() -> None:
    env = CartPoleVectorEnv(num_envs=5, dtype=np.float64)
    env.reset(seed=0)
    nudged = np.array([[0.5, -0.1, 0.08, 0.3]])
    env.set_state(nudged, indices=[2])
    state = env.get_state()
    np.testing.assert_array_equal(state[2], nudged[0])
    actions = np.array([0, 1, 1, 0, 1])
    obs, *_ = env.step(actions)
    expected, _ = step_cartpole(state, actions)
    np.testing.assert_array_equal(obs, expected.astype(np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.set_state(np.zeros((2, 4)), indices=[1])
    with pytest.raises(ValueError, match="indices"):
        env.set_state(np.zeros((1, 4)), indices=[5])
    with pytest.raises(ValueError, match="finite"):
        env.set_state(np.full((5, 4), np.nan))

    single = CartPoleEnv()
    single.reset(seed=0)
    single.state = [0.0, 0.0, 0.1, 0.0]
    assert single.state is not None
    single.state[2] = 0.15  # in place, as with Gymnasium's env
    obs, *_ = single.step(0)
    np.testing.assert_array_equal(
        obs, step_cartpole(np.array([[0.0, 0.0, 0.15, 0.0]]), np.array([0]))[0][0].astype(np.float32)
    )


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_snapshot_and_restore_continue_exactly(dtype: type[np.floating[Any]]) -> None:
    env = CartPoleVectorEnv(num_envs=32, dtype=dtype)
    env.reset(seed=4, options={"low": -0.1, "high": 0.1})
    policy = make_policy("random", seed=5)
    obs = np.zeros((32, 4), dtype=np.float32)
    for _ in range(37):
        obs, _, terminated, truncated, _ = env.step(policy(obs))
    assert (terminated | truncated).any()  # some envs are awaiting their autoreset
    snapshot = json.loads(json.dumps(env.snapshot()))  # plain data, as in a checkpoint
    twin = CartPoleVectorEnv(num_envs=32, dtype=dtype)
    twin.restore(snapshot)
    for t in range(300):
        actions = policy(obs)
        got, want = twin.step(actions), env.step(actions)
        for a, b in zip(got[:4], want[:4], strict=True):
            assert_same_bits(a, b, f"step {t}")
        obs = want[0]
    with pytest.raises(ValueError, match="cannot restore"):
        CartPoleVectorEnv(num_envs=31, dtype=dtype).restore(snapshot)


def test_step_cartpole_is_pure_and_keeps_dtype() -> None:
    states = np.random.default_rng(0).uniform(-0.05, 0.05, (10, 4))
    copy = states.copy()
    for dtype in (np.float32, np.float64):
        out, terminated = step_cartpole(states.astype(dtype), np.zeros(10, dtype=np.int64))
        assert out.dtype == dtype and out.shape == (10, 4) and terminated.shape == (10,)
    np.testing.assert_array_equal(states, copy)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"masscart": -1.0}, "masscart must be > 0"),
        ({"masspole": 0.0}, "masspole must be > 0"),
        ({"length": 0.0}, "length must be > 0"),
        ({"length": -0.5}, "length must be > 0"),
        ({"tau": 0.0}, "tau must be > 0"),
        ({"gravity": -9.8}, "gravity must be >= 0"),
        ({"gravity": math.nan}, "gravity must be finite"),
        ({"force_mag": math.inf}, "force_mag must be finite"),
        ({"x_threshold": 0.0}, "x_threshold must be > 0"),
        ({"gravity": "9.8"}, "gravity must be a number"),
        ({"kinematics_integrator": "rk4"}, "kinematics_integrator must be"),
    ],
)
def test_bad_parameters_are_rejected(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        CartPoleParams(**changes)


def test_bad_construction_and_actions_are_rejected() -> None:
    for n in (0, -3, 1.5, True):
        with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
            CartPoleVectorEnv(num_envs=n)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_episode_steps"):
        CartPoleVectorEnv(num_envs=2, max_episode_steps=0)
    with pytest.raises(ValueError, match="dtype must be"):
        CartPoleVectorEnv(num_envs=2, dtype=np.int32)
    with pytest.raises(TypeError, match="params must be a CartPoleParams"):
        CartPoleEnv(params={"gravity": 1.0})  # type: ignore[arg-type]
    env = CartPoleVectorEnv(num_envs=3)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(3, dtype=np.int64))
    env.reset(seed=0)
    before = env.get_state()
    with pytest.raises(ValueError, match="0 \\(push left\\) or 1"):
        env.step(np.array([0, 2, 1]))
    with pytest.raises(ValueError, match="shape \\(3,\\)"):
        env.step(np.zeros(4, dtype=np.int64))
    np.testing.assert_array_equal(env.get_state(), before)  # a rejected step changes nothing
    with pytest.raises(ValueError, match="cannot change on a live env"):
        env.set_params(CartPoleParams(x_threshold=3.0))
    single = CartPoleEnv()
    single.reset(seed=0)
    for bad in (2, -1, 0.5, "1"):
        with pytest.raises(ValueError, match="action must be 0"):
            single.step(bad)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- registration


def test_registration_is_idempotent_and_copies_gymnasiums_limits() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # re-registering would warn "Overriding environment"
        register_fast_envs()
        register_fast_envs()
    for env_id in ("CartPole-v0", "CartPole-v1"):
        ours, ref = gym.spec("cartpole/" + env_id), gym.spec(env_id)
        assert ours.max_episode_steps == ref.max_episode_steps
        assert ours.reward_threshold == ref.reward_threshold


def test_make_and_make_vec() -> None:
    vec = gym.make_vec("cartpole/CartPole-v1", num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(vec.unwrapped, CartPoleVectorEnv)
    assert vec.unwrapped.max_episode_steps == gym.spec("CartPole-v1").max_episode_steps
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (3, 4) and obs.dtype == np.float32
    v0 = gym.make_vec("cartpole/CartPole-v0", num_envs=2)
    assert v0.unwrapped.max_episode_steps == gym.spec("CartPole-v0").max_episode_steps
    sync = gym.make_vec("cartpole/CartPole-v1", num_envs=2, vectorization_mode="sync")
    sync.reset(seed=0)
    sync.step(np.zeros(2, dtype=np.int64))
    single = gym.make("cartpole/CartPole-v1", dtype=np.float32)
    assert isinstance(single.unwrapped, CartPoleEnv) and single.unwrapped.dtype == np.float32
    assert single.spec is not None
    assert single.spec.max_episode_steps == gym.spec("CartPole-v1").max_episode_steps


def test_render_rgb_array() -> None:
    pytest.importorskip("pygame")
    env, ref = CartPoleEnv(render_mode="rgb_array"), GymCartPoleEnv(render_mode="rgb_array")
    env.reset(seed=0)
    ref.reset(seed=0)
    for _ in range(5):
        env.step(1)
        ref.step(1)
    frame = env.render()
    assert frame is not None and frame.shape == (400, 600, 3)
    np.testing.assert_array_equal(frame, ref.render())  # Gymnasium's own picture
    env.close()
    ref.close()
