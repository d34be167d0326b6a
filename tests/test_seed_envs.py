"""Every seed's own envs as one batch (what populations train on), in both forms."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from cartpole.envs import env_info
from cartpole.envs.seed_envs import FastSeedEnvs, GymnasiumSeedEnvs, make_seed_envs


def test_the_form_follows_the_simulator():
    cartpole = env_info("CartPole-v1")
    assert isinstance(make_seed_envs(cartpole, "fast", [1], 2), FastSeedEnvs)
    assert isinstance(make_seed_envs(cartpole, "gymnasium", [1], 2), GymnasiumSeedEnvs)
    assert isinstance(make_seed_envs(env_info("Acrobot-v1"), "fast", [1], 2), GymnasiumSeedEnvs)


@pytest.mark.parametrize("simulator", ["fast", "gymnasium"])
def test_each_seed_starts_where_its_own_vector_env_starts(simulator):
    envs = make_seed_envs(env_info("CartPole-v1"), simulator, [5, 9], 3)
    own = [gym.make_vec("CartPole-v1", num_envs=3).reset(seed=seed)[0] for seed in (5, 9)]
    np.testing.assert_array_equal(envs.observations(), np.concatenate(own).astype(np.float32))


@pytest.mark.parametrize("simulator", ["fast", "gymnasium"])
def test_observations_are_new_arrays_that_stepping_leaves_alone(simulator):
    """One env of one seed: the observations handed out are not views of the envs' own state."""
    envs = make_seed_envs(env_info("CartPole-v1"), simulator, [3], 1)
    first = envs.observations()
    kept = first.copy()
    after, rewards, _, _ = envs.step(np.array([1]))
    envs.step(np.array([0]))
    np.testing.assert_array_equal(first, kept)
    assert not np.array_equal(after, kept) and rewards.tolist() == [1.0]


@pytest.mark.parametrize(("env_id", "simulator"), [("CartPole-v1", "fast"), ("MountainCar-v0", "gymnasium")])
def test_a_seed_put_back_from_its_state_steps_on_exactly(env_id, simulator):
    """A seed's envs saved mid-episode (through JSON), put back beside another seed, step as before."""
    info = env_info(env_id)
    rng = np.random.default_rng(0)
    straight = make_seed_envs(info, simulator, [2, 4], 2)
    for _ in range(30):
        straight.step(rng.integers(0, info.n_actions, size=4))
    saved = json.loads(json.dumps(straight.seed_state(1)))
    observations = straight.observations()[2:]
    resumed = make_seed_envs(info, simulator, [7, 4], 2)
    resumed.load_seed_state(1, saved)
    np.testing.assert_array_equal(resumed.observations()[2:], observations)
    for _ in range(40):
        actions = rng.integers(0, info.n_actions, size=4)
        left, right = straight.step(actions), resumed.step(actions)
        for a, b in zip(left, right, strict=True):
            np.testing.assert_array_equal(a[2:], b[2:])


def test_keep_drops_the_other_seeds_rows():
    envs = make_seed_envs(env_info("CartPole-v1"), "fast", [1, 2, 3], 2)
    rows = envs.observations()
    envs.keep(np.array([2, 0]))
    np.testing.assert_array_equal(envs.observations(), np.concatenate([rows[4:6], rows[0:2]]))
    assert len(envs.step(np.zeros(4, dtype=np.int64))[1]) == 4
