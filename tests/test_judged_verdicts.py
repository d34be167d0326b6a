"""Verdicts nothing can fake (envs/judged.py, evaluation.py): on negative-reward envs (MountainCar-v0,
Acrobot-v1), where a shorter episode scores *higher*, no wrapper or env kwarg makes a failing policy
SOLVED, through the Python API, ``cartpole train`` and ``cartpole eval``.

The policies fail on purpose: always pushing left never reaches MountainCar's flag (-200 an episode),
doing nothing never swings Acrobot up (-500). The wrappers of a package the tests write,
``verdictwrappers``: ``ActionRepeat`` (each action stepped ``k`` times, the rewards summed, as frame
skip does), ``HideEnd`` (the env's end hidden: it starts the next episode itself and plays on) and
``ScaleReward``.
"""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cartpole.cli.main import main
from cartpole.envs import env_info
from cartpole.evaluation import EvalReport, evaluate

WRAPPERS = """
import gymnasium as gym


class ActionRepeat(gym.Wrapper):
    def __init__(self, env, k=4):
        super().__init__(env)
        self.k = k

    def step(self, action):
        total = 0.0
        for _ in range(self.k):
            observation, reward, terminated, truncated, info = self.env.step(action)
            total += reward
            if terminated or truncated:
                break
        return observation, total, terminated, truncated, info


class HideEnd(gym.Wrapper):
    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            observation, info = self.env.reset()
        return observation, reward, False, False, info


class ScaleReward(gym.RewardWrapper):
    def __init__(self, env, scale=0.001):
        super().__init__(env)
        self.scale = scale

    def reward(self, reward):
        return self.scale * reward
"""

CUT = {"name": "gymnasium.wrappers:TimeLimit", "kwargs": {"max_episode_steps": 5}}
CUT_LABEL = "gymnasium.wrappers:TimeLimit(max_episode_steps=5)"


@pytest.fixture(scope="module", autouse=True)
def verdictwrappers(tmp_path_factory: pytest.TempPathFactory):
    """The package, importable in this process."""
    root = tmp_path_factory.mktemp("wrappers")
    (root / "verdictwrappers.py").write_text(textwrap.dedent(WRAPPERS))
    sys.path.insert(0, str(root))
    yield root
    sys.path.remove(str(root))


class Always:
    def __init__(self, action: int):
        self.action = action

    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.full(len(observations), self.action, dtype=np.int64)


FAILING = {"MountainCar-v0": (Always(0), -200.0), "Acrobot-v1": (Always(1), -500.0)}


def judged(env_id: str, episodes: int = 100, **configuration) -> EvalReport:
    policy, _ = FAILING[env_id]
    return evaluate(policy, env_info(env_id, **configuration), episodes, seed=0)


@pytest.mark.parametrize("env_id", FAILING)
def test_a_wrapper_that_ends_episodes_early_leaves_no_verdict(env_id: str) -> None:
    report = judged(env_id, wrappers=[CUT])
    assert report.mean == -5.0  # above either threshold: counted, this would be SOLVED
    assert not report.solved and report.cut_by == {CUT_LABEL: 100}
    assert report.verdict.startswith("NO VERDICT") and f"{CUT_LABEL} ended 100 of them" in report.verdict


@pytest.mark.parametrize("env_id", FAILING)
def test_an_action_repeat_counts_every_reward_of_the_env(env_id: str) -> None:
    _, own = FAILING[env_id]
    report = judged(env_id, wrappers=[{"name": "verdictwrappers:ActionRepeat", "kwargs": {"k": 4}}])
    assert report.mean == own and report.returns == [own] * 100  # not own / 4: every inner step counts
    assert not report.solved and report.verdict.startswith("NOT SOLVED")


@pytest.mark.parametrize("env_id", FAILING)
def test_a_reward_wrapper_changes_no_judged_return(env_id: str) -> None:
    _, own = FAILING[env_id]
    report = judged(
        env_id, 20, wrappers=[{"name": "verdictwrappers:ScaleReward", "kwargs": {"scale": 0.001}}]
    )
    assert report.mean == own and not report.solved


def test_a_wrapper_that_hides_the_env_s_end_does_not_lengthen_a_judged_episode() -> None:
    """One step aside, on +1 rewards: hiding CartPole's end would make a falling policy SOLVED."""
    plain = evaluate(Always(0), env_info("CartPole-v1"), 20, seed=0)
    hidden = evaluate(Always(0), env_info("CartPole-v1", wrappers=["verdictwrappers:HideEnd"]), 20, seed=0)
    assert hidden.returns == plain.returns and hidden.lengths == plain.lengths
    assert max(hidden.lengths) < 20 and not hidden.solved and not hidden.cut_by


@pytest.mark.parametrize("env_id", FAILING)
def test_max_episode_steps_in_env_kwargs_is_for_training_only(env_id: str) -> None:
    report = judged(env_id, 10, kwargs={"max_episode_steps": 50})
    registry = env_info(env_id).max_episode_steps
    assert report.max_episode_steps == registry and set(report.lengths) == {registry}
    assert report.mean == FAILING[env_id][1] and not report.solved
    assert report.training_only == ["max_episode_steps"]
    assert f"max_episode_steps for training only: judged with the registry's {registry}-step limit" in (
        report.verdict
    )


def test_a_longer_time_limit_in_env_kwargs_does_not_lengthen_a_cartpole_verdict() -> None:
    report = evaluate(Always(0), env_info("CartPole-v0", {"max_episode_steps": 1000}), 10, seed=0)
    assert report.max_episode_steps == 200 and report.threshold == 195.0


def test_a_report_with_cut_episodes_reads_back_as_no_verdict() -> None:
    report = judged("MountainCar-v0", 100, wrappers=[CUT])
    again = EvalReport.from_dict(json.loads(json.dumps(report.to_dict())))
    assert again.cut_by == report.cut_by and not again.solved and again.verdict == report.verdict


def cut_preset(tmp_path: Path) -> str:
    path = tmp_path / "cut.toml"
    path.write_text(
        'wrappers = [{ name = "gymnasium.wrappers:TimeLimit", kwargs = { max_episode_steps = 5 } }]\n'
    )
    return str(path)


@pytest.mark.parametrize("env_id", FAILING)
def test_train_and_eval_give_no_verdict_through_a_cutting_wrapper(
    env_id: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    args = ["train", "cem", "--env", env_id, "--preset", cut_preset(tmp_path), "--budget", "2gen"]
    main([*args, "--runs-dir", str(runs), "--quiet"])
    out = capsys.readouterr().out
    assert "NO VERDICT" in out and CUT_LABEL in out and "SOLVED:" not in out.replace("NOT SOLVED:", "")
    (run,) = runs.iterdir()
    report = json.loads((run / "eval.json").read_text())
    assert not report["solved"] and report["cut_by"] == {CUT_LABEL: 100}
    status = json.loads((run / "status.json").read_text())
    assert (
        "solved" not in json.dumps(status.get("stop_reason", "")).lower()
    )  # no in-training solve stopped it
    main(["eval", str(run)])
    again = capsys.readouterr().out
    assert "NO VERDICT" in again and CUT_LABEL in again


def test_the_notebook_api_gives_no_verdict_through_a_cutting_wrapper(tmp_path: Path) -> None:
    import cartpole

    run = cartpole.train(
        "cem", "MountainCar-v0", budget="2gen", runs_dir=tmp_path, progress=False, wrappers=[CUT]
    )
    assert run.report is not None and run.report.cut_by == {CUT_LABEL: 100} and not run.solved
    again = run.evaluate(100, seed=0)  # the run's own env: through its wrappers
    assert again.cut_by == {CUT_LABEL: 100} and again.verdict.startswith("NO VERDICT")


def test_presets_say_how_a_solve_stops_their_training(capsys: pytest.CaptureFixture[str]) -> None:
    """The README's solve sentence points here: each preset says whether a solve is confirmed."""
    assert main(["presets", "ppo"]) == 0
    out = capsys.readouterr().out
    shown = out.split("presets by env")[0]
    presets = [line for line in shown.splitlines() if line.startswith("  ") and not line.startswith("    ")]
    rules = [line.strip() for line in shown.splitlines() if line.strip().startswith("solves:")]
    assert len(rules) == len(presets) - 1  # every preset but the "from FILE" line
    assert any("once the next 100 episodes pass too" in rule for rule in rules)  # default
    assert any("confirm_solves=false" in rule for rule in rules)  # rl-zoo, cleanrl, ...
