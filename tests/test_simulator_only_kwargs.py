"""CartPole kwargs that only our simulator takes (its physics constants): training and the verdict
run on our simulator, and the verdict says so.

Gymnasium's CartPole refuses ``gravity``, ``x_threshold`` and the rest; ours takes them. With
thresholds no pole or cart can reach, every episode lasts the time limit whatever the policy does, so
where these kwargs are ignored an episode ends within a few dozen steps instead: each test fails then.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cartpole.cli.main import main
from cartpole.envs import env_info, resolve_simulator
from cartpole.envs.seed_envs import make_seed_envs
from cartpole.evaluation import EvalReport, evaluate

UNREACHABLE = {"theta_threshold_radians": 1000.0, "x_threshold": 1000.0}
"""No episode terminates: each is cut by CartPole-v1's time limit of 500 steps."""


class _always_right:
    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.ones(len(observations), dtype=np.int64)


def test_physics_kwargs_are_ours_only_so_every_simulator_is_ours():
    info = env_info("CartPole-v1", UNREACHABLE)
    assert info.simulator_only == ("theta_threshold_radians", "x_threshold")
    assert resolve_simulator(info, "gymnasium") == resolve_simulator(info, "fast") == "fast"
    assert env_info("CartPole-v1", {"sutton_barto_reward": True}).simulator_only == ()  # Gymnasium's too
    assert resolve_simulator(env_info("CartPole-v1", {"sutton_barto_reward": True}), "fast") == "gymnasium"


def test_a_verdict_with_physics_kwargs_is_played_on_our_simulator_and_says_so():
    plain = evaluate(_always_right(), "CartPole-v1", 100, seed=0)
    assert plain.mean < 50 and plain.simulator == "gymnasium"
    report = evaluate(
        _always_right(), env_info("CartPole-v1", UNREACHABLE), 100, seed=0, simulator="gymnasium"
    )
    assert report.solved and report.mean == 500.0 and report.simulator == "fast"
    assert report.simulator_only == ["theta_threshold_radians", "x_threshold"]
    assert (
        "fast simulator: Gymnasium's CartPole-v1 does not take theta_threshold_radians, x_threshold"
        in report.verdict
    )
    assert EvalReport.from_dict(json.loads(json.dumps(report.to_dict()))) == report


@pytest.mark.parametrize("sutton_barto_reward", [False, True])
def test_training_envs_step_the_physics_kwargs(sutton_barto_reward: bool):
    kwargs = {**UNREACHABLE, "sutton_barto_reward": sutton_barto_reward}
    envs = make_seed_envs(env_info("CartPole-v1", kwargs), "gymnasium", [0, 1], 4)
    rng = np.random.default_rng(0)
    ends, total = [], 0.0
    for step in range(1, 502):
        _, rewards, terminated, truncated = envs.step(rng.integers(0, 2, 8))
        assert not terminated.any()
        ends += [step] * int(truncated.sum())
        total += float(rewards.sum())
    assert ends == [500] * 8  # every episode runs to the time limit
    assert total == (0.0 if sutton_barto_reward else 8 * 500.0)


def test_plain_training_envs_end_episodes_early():  # the contrast: the test above can fail
    envs = make_seed_envs(env_info("CartPole-v1"), "fast", [0, 1], 4)
    assert any(envs.step(np.ones(8, dtype=np.int64))[2].any() for _ in range(100))


def test_a_run_with_physics_kwargs_trains_and_is_judged_on_our_simulator(tmp_path: Path):
    runs = tmp_path / "runs"
    args = ["--env-kwargs", *(f"{k}={v}" for k, v in UNREACHABLE.items()), "--runs-dir", str(runs)]
    assert main(["train", "cem", "--budget", "2gen", "--quiet", *args]) == 0
    (run,) = runs.iterdir()
    report = json.loads((run / "eval.json").read_text())
    assert report["solved"] and report["simulator"] == "fast", report["verdict"]
    assert report["simulator_only"] == ["theta_threshold_radians", "x_threshold"]
    assert main(["eval", str(run), "--json", "--simulator", "gymnasium"]) == 0
