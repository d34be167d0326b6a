"""Linear-policy agents: they learn, they are reproducible, and they reload exactly."""

from __future__ import annotations

import numpy as np
import pytest

from cartpole import evaluate, load_policy
from cartpole.agents.linear.search import LinearPolicy, ObservationScaling, policy_from_checkpoint
from cartpole.envs import env_info
from cartpole.runs import load_checkpoint
from cartpole.training import train

AGENTS = ["random-search", "hill-climbing", "cem"]


@pytest.mark.parametrize("agent", AGENTS)
def test_same_seed_same_result(agent, tmp_path):
    first = train(agent, seed=11, runs_dir=tmp_path / "a", budget="2gen", stop_when_solved=False)
    second = train(agent, seed=11, runs_dir=tmp_path / "b", budget="2gen", stop_when_solved=False)
    a = load_checkpoint(first.run.checkpoint_path("latest")).tensors["params"]
    b = load_checkpoint(second.run.checkpoint_path("latest")).tensors["params"]
    assert np.array_equal(a.numpy(), b.numpy())
    assert without_times(first.run.metrics()) == without_times(second.run.metrics())


def without_times(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in ("time", "time/sps")} for row in rows]


def test_save_load_gives_the_same_actions(cem_run):
    policy = load_policy(cem_run)
    observations = np.random.default_rng(0).normal(size=(256, 4))
    params = load_checkpoint(cem_run / "checkpoints" / "best.pt").tensors["params"].numpy()
    expected = (observations @ params > 0).astype(int)
    assert np.array_equal(policy.act(observations), expected)
    assert evaluate(policy, episodes=100, seed=99).solved


def test_tutorial_preset_is_the_tutorial(tmp_path):
    """100 candidates, one episode each, keep the best: it often picks a policy that is not solved."""
    outcome = train("random-search", seed=0, preset="tutorial", runs_dir=tmp_path)
    config = outcome.run.config()
    assert config["config"]["population"] == 100
    assert config["config"]["episodes_per_candidate"] == 1
    assert outcome.state.iterations == 1
    assert outcome.state.episodes == 100


def test_linear_scores_match_actions():
    policy = LinearPolicy(np.array([0.0, 0.0, 1.0, 0.5]), obs_dim=4, n_actions=2, bias=False)
    obs = np.array([[0, 0, 0.1, 0.0], [0, 0, -0.1, 0.0], [0, 0, 0.0, 0.0]])
    assert policy.act(obs).tolist() == [1, 0, 0]
    assert policy.scores(obs)[:, 1].tolist() == pytest.approx([0.1, -0.1, 0.0])


def test_linear_agents_handle_more_than_two_actions(tmp_path):
    outcome = train("cem", "Acrobot-v1", seed=0, runs_dir=tmp_path, budget="1gen",
                    overrides={"population": 4, "episodes_per_candidate": 1})  # fmt: skip
    policy = load_policy(outcome.run.path)
    assert policy.act(np.zeros((5, 6))).shape == (5,)


def test_observation_scaling_maps_finite_bounds_to_unit_range():
    scaling = ObservationScaling.from_bounds([-1.2, -0.07, -np.inf, 0.0], [0.6, 0.07, np.inf, 0.0])
    scaled = scaling.apply(np.array([[-1.2, -0.07, 5.0, 3.0], [0.6, 0.07, -5.0, 3.0], [-0.3, 0.0, 0.0, 3.0]]))
    assert scaled[:, :2] == pytest.approx(np.array([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0]]))
    assert scaled[:, 2:].tolist() == [[5.0, 3.0], [-5.0, 3.0], [0.0, 3.0]]  # infinite or empty: left alone


def test_a_two_action_policy_acts_on_scaled_observations():
    """The two-action hot path scales as the scores do: action 1 iff w . (s - center) / half_width > 0."""
    scaling = ObservationScaling.from_bounds([-2.0, -np.inf], [4.0, np.inf])  # center 1, half-width 3
    policy = LinearPolicy(np.array([1.0, 0.0]), obs_dim=2, n_actions=2, bias=False, scaling=scaling)
    obs = np.array(
        [[0.5, 0.0], [2.5, 0.0], [-1.0, 9.0]]
    )  # raw x > 0 for the first two; scaled x < 0, > 0, < 0
    assert policy.act(obs).tolist() == [0, 1, 0]
    assert policy.scores(obs)[:, 1] == pytest.approx([-1 / 6, 0.5, -2 / 3])


@pytest.fixture(scope="module")
def mountaincar_run(tmp_path_factory: pytest.TempPathFactory):
    """One generation of CEM on MountainCar-v0 with ``normalize_observations`` (and a bias)."""
    overrides = {"population": 4, "episodes_per_candidate": 1, "bias": True, "normalize_observations": True}
    outcome = train("cem", "MountainCar-v0", seed=0, runs_dir=tmp_path_factory.mktemp("runs"), budget="1gen",
                    overrides=overrides, quiet=True)  # fmt: skip
    return outcome.run.path


def mountaincar_probe() -> np.ndarray:
    """Observations over MountainCar's whole box: position in [-1.2, 0.6], velocity in [-0.07, 0.07]."""
    rng = np.random.default_rng(0)
    return np.column_stack([rng.uniform(-1.2, 0.6, 512), rng.uniform(-0.07, 0.07, 512)]).astype(np.float32)


def test_normalize_observations_is_what_the_saved_policy_acts_on(mountaincar_run):
    """The loaded policy scores ``(s - center) / half_width`` from MountainCar's bounds, not the raw
    observations: ignoring the setting (in training or in the checkpoint) changes its actions."""
    checkpoint = load_checkpoint(mountaincar_run / "checkpoints" / "best.pt")
    weights = checkpoint.tensors["params"].numpy().reshape(3, 3)  # (2 inputs + bias) x 3 actions
    info = env_info("MountainCar-v0")
    low, high = np.array(info.obs_low), np.array(info.obs_high)
    observations = mountaincar_probe()
    scaled = (observations - (high + low) / 2) / ((high - low) / 2)
    expected = (scaled @ weights[:2] + weights[2]).argmax(axis=1)
    raw = (observations @ weights[:2] + weights[2]).argmax(axis=1)
    assert not np.array_equal(expected, raw), "the probe must tell scaled from raw observations apart"
    assert np.array_equal(load_policy(mountaincar_run).act(observations), expected)
    assert checkpoint.meta["config"]["normalize_observations"] is True


def test_a_checkpoint_without_observation_scaling_acts_on_raw_observations(mountaincar_run):
    """Checkpoints from before ``normalize_observations`` (no scaling in their metadata) still load."""
    checkpoint = load_checkpoint(mountaincar_run / "checkpoints" / "best.pt")
    del checkpoint.meta["learner"]["observation_scaling"]
    weights = checkpoint.tensors["params"].numpy().reshape(3, 3)
    observations = mountaincar_probe()
    expected = (observations @ weights[:2] + weights[2]).argmax(axis=1)
    assert np.array_equal(policy_from_checkpoint(checkpoint).act(observations), expected)
