"""A user's own env (``module:Id-vN``), its constructor's kwargs and wrappers, end to end.

The tests write a package of their own, ``lightsenv``: ``Lights-v0`` shows one constant number and
rewards pressing button ``lit`` (a constructor argument, 1 by default), 20 steps an episode, solved
at 19. A policy that always presses the lit button scores 20, any other 0: which env a run trained
on, and which env its verdict was played on, are plain in the verdict. Its wrappers: ``SwapButtons``
(the agent's button 0 presses 1 and the other way round) and ``TenfoldReward``.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from platforms import stop_signal_to_a_process

from cartpole.cli.main import main
from cartpole.envs import env_info
from cartpole.evaluation import evaluate
from cartpole.runs import RunDir

PACKAGE = """
import gymnasium as gym
import numpy as np


class Lights(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, lit=1, render_mode=None):
        self.lit, self.render_mode = lit, render_mode
        self.observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)
        self.action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pressed = 0
        return np.ones(1, np.float32), {}

    def step(self, action):
        self.pressed = int(action)
        return np.ones(1, np.float32), float(int(action) == self.lit), False, False, {}

    def render(self):
        frame = np.zeros((40, 60, 3), np.uint8)
        frame[:, 30 * self.pressed : 30 * self.pressed + 30] = 255
        return frame


gym.register("Lights-v0", entry_point="lightsenv:Lights", max_episode_steps=20, reward_threshold=19.0)
"""

WRAPPERS = """
import gymnasium as gym


class SwapButtons(gym.ActionWrapper):
    def action(self, action):
        return 1 - int(action)


class TenfoldReward(gym.RewardWrapper):
    def __init__(self, env, factor=10.0):
        super().__init__(env)
        self.factor = factor

    def reward(self, reward):
        return self.factor * reward
"""

ENV = "lightsenv:Lights-v0"


@pytest.fixture(scope="module", autouse=True)
def lightsenv(tmp_path_factory: pytest.TempPathFactory):
    """The package, importable in this process and in the processes it starts (PYTHONPATH)."""
    root = tmp_path_factory.mktemp("userenv")
    (root / "lightsenv").mkdir()
    (root / "lightsenv" / "__init__.py").write_text(textwrap.dedent(PACKAGE))
    (root / "lightsenv" / "wrappers.py").write_text(textwrap.dedent(WRAPPERS))
    sys.path.insert(0, str(root))
    monkeypatch = pytest.MonkeyPatch()
    monkeypatch.setenv("PYTHONPATH", str(root))
    yield root
    monkeypatch.undo()
    sys.path.remove(str(root))


def wait_for_rows(runs_dir: Path, rows: int, timeout: float = 120) -> RunDir:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for path in runs_dir.glob("*/metrics.jsonl"):
            if len(RunDir(path.parent).metrics()) >= rows:
                return RunDir(path.parent)
        time.sleep(0.05)
    raise AssertionError(f"no run under {runs_dir} logged {rows} rows in {timeout} s")


def verdict(run: Path) -> dict:
    return json.loads((run / "eval.json").read_text())


def cem(tmp_path: Path, *args: str) -> Path:
    """``cartpole train cem --env lightsenv:Lights-v0 ARGS``; its run folder."""
    runs = tmp_path / "runs"
    assert (
        main(["train", "cem", "--env", ENV, "--budget", "8gen", "--runs-dir", str(runs), "--quiet", *args])
        == 0
    )
    (run,) = runs.iterdir()
    return run


def preset(tmp_path: Path, text: str) -> str:
    path = tmp_path / "preset.toml"
    path.write_text(textwrap.dedent(text))
    return str(path)


def test_a_module_id_trains_and_is_judged_on_its_own_env(tmp_path: Path):
    run = cem(tmp_path)
    assert ":" not in run.name and run.name.startswith("lightsenv-Lights-v0__cem__")
    report = verdict(run)
    assert report["solved"] and report["env_id"] == ENV, report["verdict"]
    assert (
        report["threshold"] == 19.0 and report["max_episode_steps"] == 20
    )  # the registry's, read from the env


def test_env_kwargs_reach_training_and_the_verdict(tmp_path: Path):
    run = cem(tmp_path, "--env-kwargs", "lit=0")
    report = verdict(run)
    # trained on lit=0 and judged there: solved. Trained on the plain env (lit=1), or judged on it, is 0.
    assert report["solved"] and report["env_kwargs"] == {"lit": 0}, report["verdict"]
    assert "lit=0" in report["verdict"]
    assert RunDir(run).config()["settings"]["env_kwargs"] == {"lit": 0}
    plain = main(["eval", str(run), "--env", ENV, "--json"])  # the same policy on the plain env
    assert plain == 0


def test_eval_of_a_run_plays_its_recorded_env_kwargs(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    run = cem(tmp_path, "--env-kwargs", "lit=0")
    capsys.readouterr()
    assert main(["eval", str(run), "--json", "--seed", "5"]) == 0
    recorded = json.loads(capsys.readouterr().out)
    assert recorded["solved"] and recorded["env_kwargs"] == {"lit": 0}
    assert main(["eval", str(run), "--json", "--seed", "5", "--env-kwargs", "lit=1"]) == 0
    changed = json.loads(capsys.readouterr().out)
    assert changed["mean"] == 0.0 and changed["env_kwargs"] == {"lit": 1}


def test_a_keyword_the_env_does_not_take_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    runs = tmp_path / "runs"
    code = main(["train", "cem", "--env", ENV, "--env-kwargs", "brightness=3", "--runs-dir", str(runs)])
    err = capsys.readouterr().err
    assert code == 2 and "does not take env kwargs brightness=3" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not runs.exists() or not any(runs.iterdir())


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ("nosuchpackage:Lights-v0", "cannot import 'nosuchpackage'"),
        ("lightsenv:Darkness-v0", "importing lightsenv registers no 'Darkness-v0'"),
    ],
)
def test_a_module_id_that_does_not_resolve_is_one_line(
    env: str, message: str, capsys: pytest.CaptureFixture[str]
):
    assert main(["train", "cem", "--env", env]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_wrappers_of_a_preset_file_act_in_training_and_in_the_verdict(tmp_path: Path):
    file = preset(
        tmp_path,
        """
        wrappers = ["lightsenv.wrappers:SwapButtons"]
    """,
    )
    run = cem(tmp_path, "--preset", file)
    report = verdict(run)
    # The agent learns to press 0 (swapped to 1): played without the wrapper, that scores 0.
    assert report["solved"] and report["wrappers"] == ["lightsenv.wrappers:SwapButtons"], report["verdict"]
    assert RunDir(run).config()["settings"]["wrappers"] == ["lightsenv.wrappers:SwapButtons"]
    unwrapped = evaluate(_always(0), env_info(ENV), 100, seed=1)
    assert unwrapped.mean == 0.0


class _always:
    def __init__(self, action: int):
        self.action = action

    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.full(len(observations), self.action, dtype=np.int64)


class _alternating:
    """Presses 1, 0, 1, 0, ...: half of a lit=1 episode's steps score."""

    def __init__(self) -> None:
        self.calls = 0

    def act(self, observations: np.ndarray) -> np.ndarray:
        self.calls += 1
        return np.full(len(observations), self.calls % 2, dtype=np.int64)


def test_a_reward_wrapper_cannot_change_a_verdict():
    plain = evaluate(_alternating(), ENV, 100, seed=0)
    tenfold = evaluate(
        _alternating(),
        env_info(ENV, wrappers=[{"name": "lightsenv.wrappers:TenfoldReward", "kwargs": {"factor": 10.0}}]),
        100,
        seed=0,
    )
    assert plain.mean == tenfold.mean == 10.0  # the env's own reward: 10 of 20, below 19 either way
    assert not tenfold.solved and "TenfoldReward(factor=10.0)" in tenfold.verdict


def test_a_wrapper_that_ends_episodes_earlier_leaves_no_verdict():
    """Here the cut only lowers the return; on negative rewards it raises it
    (tests/test_judged_verdicts.py): either way the episodes are not the env's."""
    cut = env_info(
        ENV, wrappers=[{"name": "gymnasium.wrappers:TimeLimit", "kwargs": {"max_episode_steps": 5}}]
    )
    report = evaluate(_always(1), cut, 100, seed=0)
    assert report.mean == 5.0 and not report.solved and report.verdict.startswith("NO VERDICT")
    assert evaluate(_always(1), ENV, 100, seed=0).mean == 20.0


@pytest.mark.parametrize(
    ("wrappers", "message"),
    [
        ('["lightsenv.wrappers:Nothing"]', "cannot import wrapper 'lightsenv.wrappers:Nothing'"),
        ('["os:sep"]', "is not a gymnasium.Wrapper class"),
        ('[{name = "lightsenv.wrappers:TenfoldReward", kwargs = {scale = 2}}]', "cannot wrap"),
        ("[{kwargs = {}}]", "each wrapper is"),
        ("[1]", "a wrapper's name is an import path module:Class"),
    ],
)
def test_a_bad_wrapper_is_one_line_exit_2(
    tmp_path: Path, wrappers: str, message: str, capsys: pytest.CaptureFixture[str]
):
    file = preset(tmp_path, f"wrappers = {wrappers}\n")
    assert main(["train", "cem", "--env", ENV, "--preset", file, "--runs-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


@stop_signal_to_a_process
def test_a_user_env_with_kwargs_resumes_on_the_env_it_trained_on(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    runs = tmp_path / "runs"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "cartpole",
            "train",
            "dqn",
            "--env",
            ENV,
            "--env-kwargs",
            "lit=0",
            "--budget",
            "6000",
            "--no-stop-when-solved",
            "--set",
            "eval_every=500",
            "--set",
            "checkpoint_every=500",
            "--quiet",
            "--runs-dir",
            str(runs),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    run = wait_for_rows(runs, 2)
    process.send_signal(signal.SIGINT)
    out, _ = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGINT, out
    capsys.readouterr()
    assert main(["train", "--resume", str(run.path)]) == 0
    err = capsys.readouterr().err
    # Lights keeps no public state (as Box2D's envs): the resume says its episodes start afresh.
    assert "resuming" in err and "the episodes in progress start afresh" in err, err
    report = verdict(run.path)
    assert report["solved"] and report["env_kwargs"] == {"lit": 0}, report["verdict"]


def test_a_user_env_with_kwargs_is_compared(tmp_path: Path):
    """compare: an entry's preset file gives the env's kwargs; each entry trains and is judged on its env."""
    lit0 = tmp_path / "lit0.toml"
    lit0.write_text("env_kwargs = {lit = 0}\n")
    runs = tmp_path / "runs"
    args = [
        "compare",
        "cem",
        f"cem:{lit0}",
        "--env",
        ENV,
        "--seeds",
        "2",
        "--budget",
        "8gen",
        "--runs-dir",
        str(runs),
    ]
    assert main([*args, "--name", "lights"]) == 0
    report = json.loads((runs / "experiments" / "lights" / "report.json").read_text())
    solved = {entry["entry"]: entry["solved"] for entry in report["entries"]}
    assert list(solved.values()) == [2, 2], report["entries"]
    verdicts = [verdict(path) for path in (runs / "experiments" / "lights" / "runs").iterdir()]
    assert sorted(str(v["env_kwargs"]) for v in verdicts) == ["{'lit': 0}", "{'lit': 0}", "{}", "{}"]


def test_a_user_env_run_is_shown_in_the_web_app(tmp_path: Path):
    pytest.importorskip("fastapi")
    sys.path.insert(0, str(Path(__file__).parent))
    from conftest_web import local_client

    run = cem(tmp_path, "--env-kwargs", "lit=0")
    client = local_client(tmp_path / "runs")
    (row,) = client.get("/api/runs").json()["runs"]
    assert row["env_id"] == ENV and row["solved"]
    detail = client.get(f"/api/runs/{run.name}").json()
    assert detail["threshold"] == 19.0 and detail["max_episode_steps"] == 20
    assert "lit=0" in detail["eval"]["verdict"]
    assert client.get(f"/api/runs/{run.name}/metrics").status_code == 200


def test_compare_env_kwargs_reach_every_entry_and_fix_the_experiment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    runs = tmp_path / "runs"
    args = ["compare", "cem", "--env", ENV, "--seeds", "2", "--budget", "8gen", "--runs-dir", str(runs)]
    assert main([*args, "--env-kwargs", "lit=0", "--name", "dark"]) == 0
    folder = runs / "experiments" / "dark"
    assert json.loads((folder / "experiment.json").read_text())["env_kwargs"] == {"lit": 0}
    verdicts = [verdict(path) for path in (folder / "runs").iterdir()]
    assert [v["env_kwargs"] for v in verdicts] == [{"lit": 0}] * 2 and all(v["solved"] for v in verdicts)
    capsys.readouterr()
    assert main([*args, "--env-kwargs", "lit=1", "--name", "dark"]) == 2  # would mix two envs' results
    err = capsys.readouterr().err
    assert "was run with --env-kwargs" in err and len(err.strip().splitlines()) == 1


def test_sweep_env_kwargs_reach_its_trials_and_its_best_preset(tmp_path: Path):
    runs = tmp_path / "runs"
    args = ["sweep", "cem", "--env", ENV, "--env-kwargs", "lit=0", "--trials", "1", "--seeds", "1"]
    assert main([*args, "--study", "dark", "--budget", "8gen", "--runs-dir", str(runs)]) == 0
    best = runs / "sweeps" / "dark" / "best.toml"
    assert (
        "env_kwargs = {lit = 0}" in best.read_text().replace("\n", " ") or "[env_kwargs]" in best.read_text()
    )
    (run,) = (runs / "sweeps" / "dark" / "runs").iterdir()
    assert verdict(run)["env_kwargs"] == {"lit": 0}
    again = cem(tmp_path / "again", "--preset", str(best))  # the best preset trains on the sweep's env
    assert verdict(again)["env_kwargs"] == {"lit": 0}


def test_a_user_env_is_recorded_from_its_rgb_array_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    run = cem(tmp_path, "--env-kwargs", "lit=0")
    out = tmp_path / "lights.gif"
    assert main(["record", str(run), "--episodes", "1", "--seed", "0", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert out.stat().st_size > 0 and "returns 20" in printed and "lit=0" in printed


def test_the_web_app_replays_a_user_env_run_from_its_rgb_array_frames(tmp_path: Path):
    pytest.importorskip("fastapi")
    sys.path.insert(0, str(Path(__file__).parent))
    from conftest_web import local_client

    run = cem(tmp_path, "--env-kwargs", "lit=0")
    client = local_client(tmp_path / "runs")
    assert not client.get(f"/api/runs/{run.name}").json()["watchable"]  # Watch draws only its own envs
    gif = client.get(f"/api/runs/{run.name}/checkpoints/best/replay.gif", params={"seed": 3})
    assert gif.status_code == 200 and gif.headers["content-type"] == "image/gif"
    assert gif.content.startswith(b"GIF8")
    assert client.get(f"/api/runs/{run.name}/checkpoints/nope/replay.gif").status_code == 404
