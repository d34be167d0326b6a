"""`cartpole sweep` end to end on a tiny CEM budget (journal storage, two workers), best.toml, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import optuna
import pytest

from cartpole.cli.main import main
from cartpole.experiments.space import parse_space
from cartpole.experiments.sweep import PruneReporter


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, timeout=600
    )


def load(folder: Path, name: str) -> optuna.Study:
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(folder / "journal.log")))
    return optuna.load_study(study_name=name, storage=storage)


def finished(study: optuna.Study) -> list[optuna.trial.FrozenTrial]:
    states = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    return study.get_trials(states=states)


def test_sweep_two_workers_then_more_trials_and_best_toml_trains(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    args = ["sweep", "cem", "--seeds-per-trial", "2", "--workers", "2", "--study", "s", "--budget", "3gen",
            "--runs-dir", str(runs_dir)]  # fmt: skip
    done = run_cli(*args, "--trials", "3")
    assert done.returncode == 0, done.stderr
    folder = runs_dir / "sweeps" / "s"
    study = load(folder, "s")
    trials = finished(study)
    assert len(trials) == 3 and len({t.number for t in trials}) == 3
    complete = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
    for trial in complete:  # the objective is the median of the seeds' costs
        costs = sorted(trial.user_attrs[f"cost_seed{i}"] for i in range(2))
        assert trial.value == pytest.approx(sum(costs) / 2)
        record = json.loads((Path(trial.user_attrs["run_seed1"]) / "config.json").read_text())
        assert record["population"]["seeds"] == [0, 1]  # a trial's seeds train as one population
        assert set(trial.params) == set(
            parse_space(
                "cem",
                (Path(__file__).parents[1] / "src/cartpole/agents/search_spaces/cem.toml").read_text(),
                "x",
            )
        )
    first = study.get_trials()[0]  # a new study starts from the preset's own values
    assert first.params == {"population": 32, "episodes_per_candidate": 2, "elite_fraction": 0.2,
                            "init_std": 0.5, "extra_std": 0.02}  # fmt: skip
    best = tomllib.loads((folder / "best.toml").read_text())
    winner = min(complete, key=lambda t: t.value)
    assert best["population"] == winner.params["population"] and best["budget"] == "3gen"

    more = run_cli(*args, "--trials", "4")  # re-running adds trials to the same study
    assert more.returncode == 0, more.stderr
    assert len(finished(load(folder, "s"))) == 4

    trained = runs_dir / "trained"
    assert (
        main(["train", "cem", "--preset", str(folder / "best.toml"), "--runs-dir", str(trained), "--quiet"])
        == 0
    )
    assert main(["presets", "cem", "--runs-dir", str(runs_dir)]) == 0
    out = capsys.readouterr().out
    assert "agents/presets/cem.toml" in out and str(folder / "best.toml") in out


class PruningTrial:
    """What the reporter needs of an Optuna trial: it records the reports, and prunes from the
    ``prune_from``-th report on."""

    def __init__(self, prune_from: int):
        self.reports: list[tuple[int, float]] = []
        self.prune_from = prune_from

    def report(self, value: float, step: int) -> None:
        self.reports.append((step, value))

    def should_prune(self) -> bool:
        return len(self.reports) >= self.prune_from


def seed_loop(env_steps: int, solved_at: int | None = None) -> SimpleNamespace:
    state = SimpleNamespace(env_steps=env_steps, solved=solved_at is not None, solved_at_step=solved_at)
    return SimpleNamespace(state=state)


def test_the_reporter_bounds_the_median_and_stops_every_unsolved_seed_once_pruned():
    """Three seeds train together: each report is the median of the seeds' costs so far (unevaluated
    seeds 0); after the pruner says so, unsolved seeds stop and solved ones are not stopped."""
    trial = PruningTrial(prune_from=3)
    reporter = PruneReporter(trial, seeds=3)
    a, b, c = seed_loop(1000), seed_loop(2000), seed_loop(500, solved_at=500)
    assert reporter.on_eval(a, None) is True  # costs 1000, 0, 0
    assert reporter.on_eval(b, None) is True  # 1000, 2000, 0
    assert not reporter.pruned
    assert reporter.on_eval(c, None) is True  # a solved seed is never stopped
    a.state.env_steps = 3000
    assert reporter.on_eval(a, None) is False  # 3000, 2000, 500: pruned, and a is unsolved
    assert reporter.pruned
    assert reporter.on_eval(b, None) is False  # every unsolved seed stops at its next evaluation
    assert trial.reports == [(1, 0.0), (2, 1000.0), (3, 1000.0), (4, 2000.0), (5, 2000.0)]


def test_the_reporter_never_stops_a_trial_the_pruner_keeps():
    reporter = PruneReporter(PruningTrial(prune_from=10**6), seeds=2)
    assert all(reporter.on_eval(seed_loop(steps), None) for steps in (100, 200, 300, 400))
    assert not reporter.pruned


def write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--trials", "0"], "--trials must be >= 1"),
        (["--trials", "2", "--seeds-per-trial", "0"], "--seeds-per-trial must be >= 1"),
        (["--trials", "2", "--workers", "0"], "--workers must be >= 1"),
        (["--trials", "2", "--preset", "nope"], "unknown preset 'nope'"),
        (["--trials", "2", "--budget", "lots"], "bad budget"),
        (["--trials", "2", "--study", "a/b"], "study name 'a/b'"),
        (["--trials", "2", "--space", "SPACE:[speed]\nlow = 1\nhigh = 2\n"], "unknown setting for cem"),
        (["--trials", "2", "--space", "SPACE:[population]\nlow = 8\nhigh = 8\n"], "the range is empty"),
        (["--trials", "2", "--space", "SPACE:[population]\nchoices = []\n"], "choices is empty"),
        (["--trials", "2", "--space", "SPACE:[population]\nlow = 0\nhigh = 8\n"], "population must be >= 1"),
        (
            ["--trials", "2", "--space", "SPACE:[population]\nlow = 4\nhigh = 8\nlog = 'x'\nstep = 0\n"],
            "step",
        ),
        (["--trials", "2", "--space", "/no/such/space.toml"], "cannot read the search space"),
        (["--trials", "2", "--storage", "not a url"], "malformed --storage URL"),
        (["--trials", "2", "--storage", "http://example.com/db"], "not supported"),
        (["--trials", "2", "--storage", "postgresql://postgres@127.0.0.1:1/db"], "at 127.0.0.1:1:"),
        (["--trials", "2", "--storage", "postgresql://u@127.0.0.1:port/db"], "malformed --storage URL"),
        (["--trials", "2", "--storage", "postgresql:///db"], "names no host"),
        (["--trials", "2", "--storage", "mysql://u@127.0.0.1:1/db"], "needs its driver"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(extra, message, tmp_path, capsys):
    extra = [
        write(tmp_path / "space.toml", e.removeprefix("SPACE:")) if e.startswith("SPACE:") else e
        for e in extra
    ]
    runs_dir = tmp_path / "runs"
    args = ["sweep", "cem", "--study", "s", "--runs-dir", str(runs_dir), *extra]
    if "--study" in extra:
        args[3:5] = []
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and not runs_dir.exists(), "bad input must not write anything"


def test_unknown_agent_is_one_line(capsys):
    assert main(["sweep", "nope", "--trials", "1", "--study", "s"]) == 2
    assert "unknown agent 'nope'" in capsys.readouterr().err


def test_a_study_cannot_change_its_agent_or_space(tmp_path, capsys):
    from cartpole.experiments.sweep import make_spec, open_storage, open_study

    runs_dir = tmp_path / "runs"
    spec = make_spec(runs_dir, "s", "cem", "default", 2, [0, 1], budget="3gen")
    open_study(spec, open_storage(spec))
    journal = runs_dir / "sweeps" / "s" / "journal.log"
    before = journal.read_bytes()
    base = ["--study", "s", "--trials", "2", "--budget", "3gen", "--runs-dir", str(runs_dir)]
    assert main(["sweep", "hill-climbing", *base]) == 2
    assert "exists for agent 'cem'" in capsys.readouterr().err
    space = write(tmp_path / "space.toml", "[population]\nchoices = [8, 16]\n")
    assert main(["sweep", "cem", *base, "--space", space]) == 2
    assert "another search space" in capsys.readouterr().err
    assert journal.read_bytes() == before, "the study is untouched"


@pytest.mark.slow
def test_ctrl_c_leaves_the_study_consistent_and_a_rerun_finishes_it(tmp_path):
    import signal
    import time

    # 30 s of training each: time for a loaded machine to start both workers before either trial ends.
    preset = write(tmp_path / "slow.toml", "stop_when_solved = false\ncheckpoint_every = 1\n")
    space = write(tmp_path / "space.toml", "[noise]\nlow = 0.0001\nhigh = 0.0002\n")
    runs_dir = tmp_path / "runs"
    args = ["sweep", "hill-climbing", "--preset", preset, "--space", space, "--trials", "2",
            "--workers", "2", "--seeds-per-trial", "1", "--study", "c", "--budget", "30s",
            "--runs-dir", str(runs_dir)]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    folder = runs_dir / "sweeps" / "c"
    deadline = time.monotonic() + 120
    while len(list(folder.glob("runs/*/checkpoints/latest.pt"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    study = load(folder, "c")
    states = [t.state for t in study.get_trials()]
    assert optuna.trial.TrialState.RUNNING not in states and optuna.trial.TrialState.FAIL in states
    assert all(
        t.user_attrs.get("interrupted") for t in study.get_trials(states=(optuna.trial.TrialState.FAIL,))
    )

    again = run_cli(*args)
    assert again.returncode == 0, again.stderr
    assert len(finished(load(folder, "c"))) == 2


def test_a_worker_trains_on_the_clis_torch_thread_count(tmp_path, monkeypatch):
    """A sweep worker is a process of its own: it trains on `cartpole train`'s default thread count
    (one on state observations), not on torch's one per core."""
    import torch

    from cartpole.experiments import sweep

    seen: list[int] = []

    def spy(spec: sweep.SweepSpec, device: str = "cpu") -> int:
        seen.append(torch.get_num_threads())
        return 0

    monkeypatch.setattr(sweep, "run_worker", spy)
    spec = sweep.SweepSpec("s", "cem", "default", "CartPole-v1", "2gen", 1, 1, "", None, str(tmp_path))
    (tmp_path / "spec.json").write_text(json.dumps(spec.__dict__))
    torch.set_num_threads(3)
    assert sweep.main([str(tmp_path / "spec.json")]) == 0
    assert seen == [1] and torch.get_num_threads() == 3
