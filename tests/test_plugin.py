"""cartpole as a Gymnasium plugin: its envs are registered the way third-party envs are."""

from __future__ import annotations

import copy
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cartpole  # noqa: F401  (the import registers the envs)


def run_fresh(code: str) -> str:
    """Run ``code`` in a new interpreter (no cartpole import unless the code does it)."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_make_with_module_prefix_needs_no_import():
    out = run_fresh(
        "import sys, gymnasium as gym\n"
        "assert 'cartpole' not in sys.modules\n"
        "env = gym.make('cartpole:cartpole/CartPole-v1')\n"
        "print(type(env.unwrapped).__module__, env.spec.max_episode_steps)"
    )
    assert out == "cartpole.envs.fast 500"


def test_import_registers_both_versions_with_gymnasium_limits():
    for version, limit in (("v1", 500), ("v0", 200)):
        spec = gym.spec(f"cartpole/CartPole-{version}")
        assert spec.max_episode_steps == limit
        assert spec.reward_threshold == gym.spec(f"CartPole-{version}").reward_threshold


def test_make_vec_after_import_steps_our_vector_env():
    envs = gym.make_vec("cartpole/CartPole-v1", num_envs=8)
    observations, _ = envs.reset(seed=0)
    assert observations.shape == (8, 4)
    _, rewards, _, truncated, _ = envs.step(np.ones(8, dtype=np.int64))
    assert rewards.tolist() == [1.0] * 8 and not truncated.any()
    envs.close()


def test_import_compiles_nothing():
    """Registration is cheap: importing cartpole does not import numba or the kernels."""
    out = run_fresh(
        "import sys, cartpole\nprint('numba' in sys.modules, 'cartpole.envs.fast' in sys.modules)"
    )
    assert out == "False False"


# --- Gymnasium's own checks on every id we register (tests/envs: test_envs.py, test_env_implementation.py)

PLUGIN_IDS = sorted(env_id for env_id in gym.registry if env_id.startswith("cartpole/"))
DTYPES = {"default": {}, "float32": {"dtype": np.float32}, "float64": {"dtype": np.float64}}
EXPECTED_WARNINGS = (  # Gymnasium's test_all_env_api ignores these two; v0 ids are out of date by design
    "A Box observation space minimum value is -infinity",
    "A Box observation space maximum value is infinity",
    "is out of date",
)


def test_every_plugin_id_is_checked():
    assert PLUGIN_IDS == [
        "cartpole/CartPole-v0",
        "cartpole/CartPole-v1",
        "cartpole/CartPolePixels-v0",
        "cartpole/CartPolePixels-v1",
    ]


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("env_id", PLUGIN_IDS)
def test_gymnasiums_env_checker_passes_with_no_unexpected_warning(env_id):
    """``gymnasium.utils.env_checker.check_env``, its render check included, as Gymnasium's own
    test_all_env_api runs it on its envs."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id, render_mode="rgb_array").unwrapped
        check_env(env)
        env.close()
    unexpected = [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED_WARNINGS)]
    assert not unexpected


def pickled(env):
    return pickle.loads(pickle.dumps(env))


def play(env, actions, vector: bool) -> list[tuple]:
    """The bytes of what ``env`` returns for each action (observations, rewards, flags) and its state."""
    steps = []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(np.array([action]) if vector else action)
        state = env.unwrapped.state
        steps.append((np.asarray(obs).tobytes(), reward, terminated, truncated, np.asarray(state).tobytes()))
        if not vector and (terminated or truncated):
            env.reset()
    return steps


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("copy_env", [pickled, copy.deepcopy], ids=["pickle", "deepcopy"])
@pytest.mark.parametrize("dtype", sorted(DTYPES))
@pytest.mark.parametrize("vector", [False, True], ids=["make", "make_vec"])
@pytest.mark.parametrize("env_id", PLUGIN_IDS)
def test_a_copy_continues_the_same_episode_bit_for_bit(env_id, vector, dtype, copy_env):
    """``pickle.loads(pickle.dumps(env))`` and ``copy.deepcopy(env)`` mid-episode, then the same
    actions: the same observations, rewards, flags and states, through episode ends and autoresets
    (Gymnasium's test_pickle_env copies only after a reset)."""
    make = gym.make_vec if vector else gym.make
    env = make(env_id, **DTYPES[dtype])
    env.reset(seed=123)
    actions = np.random.default_rng(0).integers(0, 2, 400)
    play(env, actions[:20], vector)
    twin = copy_env(env)
    assert play(twin, actions[20:], vector) == play(env, actions[20:], vector)
    # Gymnasium's test_pickle_env: a copy reset with the same seed gives the same first step
    assert play(copy_env(env), [1], vector) == play(env, [1], vector)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.parametrize("dtype", sorted(DTYPES))
@pytest.mark.parametrize("env_id", PLUGIN_IDS)
def test_make_and_make_vec_agree_step_for_step(env_id, dtype):
    """Gymnasium's test_cartpole_vector_equiv on our ids, for several seeds, in each dtype (the two
    forms' defaults included): one env of ``make_vec`` is the env of ``make``, observations, rewards,
    flags and ``state`` alike, to the episode's end and through the vector env's autoreset step."""
    for seed in range(10):
        env = gym.make(env_id, **DTYPES[dtype])
        envs = gym.make_vec(env_id, num_envs=1, **DTYPES[dtype])
        assert env.action_space == envs.single_action_space
        assert env.observation_space == envs.single_observation_space
        obs, info = env.reset(seed=seed)
        vec_obs, vec_info = envs.reset(seed=seed)
        env.action_space.seed(seed)
        assert np.array_equal(obs, vec_obs[0]) and info == vec_info
        assert np.array_equal(env.unwrapped.state, envs.unwrapped.state[:, 0])
        for _ in range(600):
            action = env.action_space.sample()
            obs, reward, term, trunc, info = env.step(action)
            vec_obs, vec_reward, vec_term, vec_trunc, vec_info = envs.step(np.array([action]))
            assert np.array_equal(obs, vec_obs[0]) and reward == vec_reward[0]
            assert (term, trunc, info) == (vec_term[0], vec_trunc[0], vec_info)
            assert np.array_equal(env.unwrapped.state, envs.unwrapped.state[:, 0])
            if term or trunc:
                break
        assert envs.unwrapped.prev_done.tolist() == [True]
        obs, info = env.reset()
        vec_obs, vec_reward, vec_term, vec_trunc, vec_info = envs.step(envs.action_space.sample())
        assert np.array_equal(obs, vec_obs[0])
        assert (vec_reward[0], vec_term[0], vec_trunc[0]) == (0, False, False)
        assert np.array_equal(env.unwrapped.state, envs.unwrapped.state[:, 0])


def test_the_vector_env_renders_each_env_as_gymnasiums_does():
    """``make_vec(..., render_mode="rgb_array").render()``: one 600x400 picture per env, the very
    pictures of Gymnasium's CartPoleVectorEnv at the same states (float64: the same states)."""
    pytest.importorskip("pygame")
    ours = gym.make_vec("cartpole/CartPole-v1", num_envs=3, render_mode="rgb_array")
    reference = gym.make_vec("CartPole-v1", num_envs=3, render_mode="rgb_array")
    ours.reset(seed=4)
    reference.reset(seed=4)
    for step in range(30):
        actions = np.array([step % 2, 1, 0])
        ours.step(actions)
        reference.step(actions)
        if step % 10 == 9:
            pictures = ours.render()
            expected = reference.render()
            assert len(pictures) == 3
            for picture, want in zip(pictures, expected, strict=True):
                assert picture.shape == (400, 600, 3) and np.array_equal(picture, want)
    pixels = gym.make_vec("cartpole/CartPolePixels-v1", num_envs=2, render_mode="rgb_array")
    pixels.reset(seed=0)
    assert [p.shape for p in pixels.render()] == [(400, 600, 3)] * 2
    ours.close()
    reference.close()
    pixels.close()
