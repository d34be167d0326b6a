"""observation_mean and observation_std: the policy-gradient agents' networks see ``(x - mean) / std``,
in training and in every greedy policy made from them (a checkpoint's, the web app's, a verdict's)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from cartpole.agents.registry import get_agent
from cartpole.runs import load_checkpoint
from cartpole.training import train

MEAN, STD = (0.1, -0.2, 0.05, 0.3), (0.5, 2.0, 0.1, 4.0)
OBSERVATIONS = np.random.default_rng(7).normal(scale=0.5, size=(32, 4)).astype(np.float32)


@pytest.mark.parametrize("agent", ["ppo", "a2c", "reinforce"])
def test_a_checkpoint_policy_acts_on_standardized_observations(agent, tmp_path):
    """The same weights without the constants, given ``(x - mean) / std``, give the same scores."""
    settings = {"observation_mean": MEAN, "observation_std": STD, "hidden_sizes": (16, 16)}
    outcome = train(agent, seed=3, overrides=settings, budget="2k", runs_dir=tmp_path, stop_when_solved=False)
    checkpoint = load_checkpoint(outcome.run.path / "checkpoints" / "latest.pt")
    spec = get_agent(agent)
    plain = copy.deepcopy(checkpoint)
    plain.meta["config"] = {k: v for k, v in plain.meta["config"].items() if not k.startswith("observation_")}
    standardized = (OBSERVATIONS - np.float32(MEAN)) / np.float32(STD)

    scores = spec.policy_from_checkpoint(checkpoint).scores(OBSERVATIONS)
    np.testing.assert_allclose(scores, spec.policy_from_checkpoint(plain).scores(standardized), rtol=1e-6)
    assert not np.allclose(scores, spec.policy_from_checkpoint(plain).scores(OBSERVATIONS), rtol=1e-3)


def test_a_missing_mean_is_zero_and_a_missing_std_is_one(tmp_path):
    """Either constant may be left out: observation_std alone divides, observation_mean alone shifts."""
    std_only = {"observation_std": STD, "hidden_sizes": (16,)}
    outcome = train("ppo", seed=1, overrides=std_only, budget="1k", runs_dir=tmp_path, stop_when_solved=False)
    checkpoint = load_checkpoint(outcome.run.path / "checkpoints" / "latest.pt")
    spec = get_agent("ppo")
    both = copy.deepcopy(checkpoint)
    both.meta["config"]["observation_mean"] = [0.0, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(
        spec.policy_from_checkpoint(checkpoint).scores(OBSERVATIONS),
        spec.policy_from_checkpoint(both).scores(OBSERVATIONS),
    )
