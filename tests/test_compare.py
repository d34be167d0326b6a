"""`cartpole compare` end to end on tiny budgets, resuming, Ctrl-C, bad input; statistics; preset files."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cartpole.cli.main import main
from cartpole.experiments.stats import censored_summary, iqm_summary


def run_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, timeout=timeout
    )


def run_folders(folder: Path) -> list[Path]:
    return sorted(p for p in (folder / "runs").iterdir() if (p / "config.json").is_file())


def test_compare_writes_its_report(tmp_path):
    runs_dir = tmp_path / "runs"
    done = run_cli(
        "compare", "cem", "--seeds", "2", "--jobs", "2", "--budget", "2gen", "--runs-dir", str(runs_dir)
    )
    assert done.returncode == 0, done.stderr
    folder = runs_dir / "experiments" / "cem"
    (entry,) = json.loads((folder / "report.json").read_text())["entries"]
    assert entry["entry"] == "cem" and entry["runs"] == 2 and entry["seeds"] == [0, 1]
    records = [json.loads((folder / "records" / f"cem__s{seed}.json").read_text()) for seed in (0, 1)]
    for key in ("env_steps_to_solve", "cpu_seconds_to_solve", "wall_seconds_to_solve"):
        assert entry[key]["median"] > 0 and entry[key]["censored"] == 2 - entry["solved"]
        # the per-seed values each statistic summarizes, in the order of "seeds" (for rliable and others)
        assert len(entry[key]["values"]) == 2
        assert entry[key]["censored_runs"] == [not r["solved_in_training"] for r in records]
    assert entry["env_steps_to_solve"]["values"] == [
        float(r["solve_steps"] if r["solved_in_training"] else r["env_steps"]) for r in records
    ]
    assert entry["final_mean_return"]["values"] == [r["final_mean"] for r in records]
    assert (folder / "curves.png").is_file() and "| cem | 2 |" in (folder / "report.md").read_text()


def test_compare_trains_a_population_agent_in_one_process(tmp_path):
    runs_dir = tmp_path / "runs"
    done = run_cli("compare", "ppo", "--seeds", "2", "--budget", "256", "--runs-dir", str(runs_dir))
    assert done.returncode == 0, done.stderr
    folder = runs_dir / "experiments" / "ppo"
    (entry,) = json.loads((folder / "report.json").read_text())["entries"]
    assert entry["runs"] == 2 and entry["seeds"] == [0, 1]
    runs = run_folders(folder)
    assert len(runs) == 2 and all((run / "eval.json").is_file() for run in runs)
    populations = {json.loads((run / "config.json").read_text())["population"]["id"] for run in runs}
    assert len(populations) == 1  # both seeds trained as one population
    records = [json.loads(p.read_text()) for p in sorted((folder / "records").iterdir())]
    assert [r["seed"] for r in records] == [0, 1] and all(r["population"] for r in records)
    assert all(r["cpu_seconds"] > 0 and Path(r["run"]) in runs for r in records)
    assert len(list((folder / "logs").iterdir())) == 1  # one worker process


def test_compare_on_another_env_trains_a_population_agent_one_seed_at_a_time(tmp_path):
    """Populations run CartPole only; on Acrobot a population agent's seeds are ordinary runs."""
    runs_dir = tmp_path / "runs"
    args = ["compare", "a2c", "--env", "Acrobot-v1", "--seeds", "2", "--budget", "400"]
    done = run_cli(*args, "--jobs", "2", "--runs-dir", str(runs_dir))
    assert done.returncode == 0, done.stderr
    folder = runs_dir / "experiments" / "a2c-acrobot"  # the entry takes a2c's preset for Acrobot-v1
    runs = run_folders(folder)
    assert len(runs) == 2 and all((run / "eval.json").is_file() for run in runs)
    assert not any(json.loads((run / "config.json").read_text()).get("population") for run in runs)


@pytest.mark.slow
def test_compare_reports_resumes_and_adds_seeds(tmp_path):
    runs_dir = tmp_path / "runs"
    args = ["compare", "cem", "random-search:tutorial", "--jobs", "2", "--runs-dir", str(runs_dir)]
    done = run_cli(*args, "--seeds", "2", "--name", "x")
    assert done.returncode == 0, done.stderr
    folder = runs_dir / "experiments" / "x"
    report = json.loads((folder / "report.json").read_text())
    assert [e["entry"] for e in report["entries"]] == ["cem", "random-search:tutorial"]
    for entry in report["entries"]:
        assert entry["runs"] == 2 and 0 <= entry["solved"] <= 2
        assert len(entry["run_folders"]) == 2 and all(Path(p).is_dir() for p in entry["run_folders"])
        steps = entry["env_steps_to_solve"]
        assert steps["median"] > 0 and steps["iqr"][0] <= steps["median"] <= steps["iqr"][1]
        assert entry["final_mean_return"]["iqm"] > 0
    assert "| cem | 2 |" in (folder / "report.md").read_text()
    for png in ("curves.png", "solve_steps.png"):
        assert (folder / png).read_bytes()[:4] == b"\x89PNG"
    assert len(run_folders(folder)) == 4

    again = run_cli(*args, "--seeds", "2", "--name", "x")  # everything finished: nothing is trained again
    assert again.returncode == 0, again.stderr
    assert len(run_folders(folder)) == 4
    more = run_cli(*args, "--seeds", "3", "--name", "x")  # one more seed per entry
    assert more.returncode == 0, more.stderr
    assert len(run_folders(folder)) == 6
    assert all(e["runs"] == 3 for e in json.loads((folder / "report.json").read_text())["entries"])


@pytest.mark.slow
def test_ctrl_c_stops_every_worker_and_a_rerun_resumes(tmp_path):
    # Hill climbing with a tiny step keeps training to its 30-second budget; latest.pt every generation.
    # (The budget leaves a loaded machine time to start both workers before either run ends.)
    preset = tmp_path / "slow.toml"
    preset.write_text("noise = 0.0001\nstop_when_solved = false\ncheckpoint_every = 1\n")
    runs_dir = tmp_path / "runs"
    args = ["compare", f"hill-climbing:{preset}", "--seeds", "2", "--jobs", "2", "--budget", "30s",
            "--name", "c", "--runs-dir", str(runs_dir)]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    folder = runs_dir / "experiments" / "c"
    deadline = time.monotonic() + 120
    while len(list(folder.glob("runs/*/checkpoints/latest.pt"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert "re-run the same command to resume" in stderr
    records = [json.loads(p.read_text()) for p in sorted((folder / "records").glob("*.json"))]
    assert len(records) == 2 and all(r["state"] == "interrupted" for r in records), records

    resumed = run_cli(*args)
    assert resumed.returncode == 0, resumed.stderr
    after = [json.loads(p.read_text()) for p in sorted((folder / "records").glob("*.json"))]
    assert [r["run"] for r in after] == [r["run"] for r in records], "the same runs go on"
    assert all(r["state"] == "finished" for r in after)
    assert all(a["env_steps"] > r["env_steps"] for a, r in zip(after, records, strict=True))
    assert len(run_folders(folder)) == 2


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["compare", "nope"], "unknown agent 'nope'"),
        (["compare", "cem:nope"], "unknown preset 'nope'"),
        (["compare", "cem:/no/such/preset.toml"], "does not exist"),
        (["compare", "cem", "cem"], "given twice"),
        (["compare", "cem:PRESET:speed = 3\n"], "unknown setting 'speed'"),
        (["compare", "cem", "--seeds", "0"], "--seeds 0 is a count of no seeds"),
        (["compare", "cem", "--first-seed", "-1"], "--first-seed must be >= 0"),
        (["compare", "cem", "--name", "../x"], "experiment name '../x'"),
        (["compare", "cem", "--jobs", "0"], "--jobs must be >= 1"),
        (["compare", "cem", "--budget", "lots"], "bad budget"),
        (["compare", "cem", "--env", "NoSuchEnv-v9"], "unknown environment"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    for i, arg in enumerate(args):  # "agent:PRESET:text": a preset file holding text
        if ":PRESET:" in arg:
            agent, _, text = arg.partition(":PRESET:")
            (tmp_path / "preset.toml").write_text(text)
            args = [*args[:i], f"{agent}:{tmp_path / 'preset.toml'}", *args[i + 1 :]]
    assert main([*args, "--runs-dir", str(runs_dir)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and not runs_dir.exists(), "bad input must not write anything"


def test_an_experiment_cannot_change_its_env_or_budget(tmp_path, capsys):
    folder = tmp_path / "experiments" / "e"
    folder.mkdir(parents=True)
    (folder / "experiment.json").write_text(json.dumps({"env_id": "CartPole-v1", "budget": "5gen"}))
    assert main(["compare", "cem", "--name", "e", "--budget", "6gen", "--runs-dir", str(tmp_path)]) == 2
    assert "was run with --budget 5gen" in capsys.readouterr().err
    assert json.loads((folder / "experiment.json").read_text())["budget"] == "5gen"


def test_censored_runs_count_at_their_budget_and_hold_the_median_up():
    solved = censored_summary([100.0, 200.0, 300.0], [False, False, False])
    assert (
        solved["median"] == 200.0 and solved["iqr"] == [150.0, 250.0] and not solved["median_is_lower_bound"]
    )
    low, high = solved["ci95"]
    assert 100.0 <= low <= 200.0 <= high <= 300.0
    # Two of three never solved within 1000 steps: they count at 1000, and the median is a lower bound.
    censored = censored_summary([100.0, 1000.0, 1000.0], [False, True, True])
    assert censored["median"] == 1000.0 and censored["censored"] == 2 and censored["median_is_lower_bound"]
    assert censored_summary([5.0], [False])["ci95"] is None


def test_iqm_ignores_the_outer_quarters():
    values = np.array([0.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 500.0])
    summary = iqm_summary(values)
    assert summary["iqm"] == pytest.approx(100.0) and summary["mean"] == pytest.approx(137.5)
    assert summary["ci95"][0] <= 100.0 <= summary["ci95"][1]


def test_train_accepts_a_preset_file_from_any_path(tmp_path, capsys):
    flat = tmp_path / "mine.toml"
    flat.write_text('description = "mine"\nbudget = "3gen"\npopulation = 8\n')
    assert main(["train", "cem", "--preset", str(flat), "--runs-dir", str(tmp_path / "runs"), "--quiet"]) == 0
    (run,) = (tmp_path / "runs").iterdir()
    config = json.loads((run / "config.json").read_text())
    assert config["config"]["population"] == 8 and config["budget"] == {"iterations": 3}
    one_table = tmp_path / "one.toml"
    one_table.write_text('[fast]\nbudget = "2gen"\npopulation = 4\n')
    assert (
        main(["train", "cem", "--preset", str(one_table), "--runs-dir", str(tmp_path / "r2"), "--quiet"]) == 0
    )
    capsys.readouterr()
    unknown = tmp_path / "unknown.toml"
    unknown.write_text("speed = 3\n")
    assert main(["train", "cem", "--preset", str(unknown), "--runs-dir", str(tmp_path / "r3")]) == 2
    assert "unknown setting 'speed'" in capsys.readouterr().err
    two = tmp_path / "two.toml"
    two.write_text("[a]\npopulation = 4\n[b]\npopulation = 8\n")
    assert main(["train", "cem", "--preset", str(two), "--runs-dir", str(tmp_path / "r3")]) == 2
    assert "holds 2 presets" in capsys.readouterr().err
    assert not (tmp_path / "r3").exists()


@pytest.mark.parametrize("command", ["compare", "sweep"])
def test_help_is_complete(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert f"usage: cartpole {command}" in capsys.readouterr().out


def test_a_worker_trains_on_the_clis_torch_thread_count(tmp_path, monkeypatch):
    """A compare worker is a process of its own: it trains on `cartpole train`'s default thread count
    (one on state observations), not on torch's one per core, which with --jobs 2 would oversubscribe."""
    import torch

    from cartpole.experiments import worker

    seen: list[int] = []

    def spy(task: worker.Task) -> dict:
        seen.append(torch.get_num_threads())
        return {"state": worker.FINISHED}

    monkeypatch.setattr(worker, "run_task", spy)
    record = str(tmp_path / "record.json")
    task = worker.Task("cem", "default", 0, "CartPole-v1", "2gen", str(tmp_path), record, [])
    (tmp_path / "task.json").write_text(json.dumps(task.__dict__))
    torch.set_num_threads(3)
    assert worker.main([str(tmp_path / "task.json")]) == 0
    assert seen == [1] and torch.get_num_threads() == 3


@pytest.mark.parametrize("command", ["compare", "sweep"])
def test_storage_help_names_sqlite_too(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert (
        "--storage URL" in text and "postgresql://USER@HOST:PORT/DB" in text and "sqlite:///FILE.db" in text
    )


def test_compare_refuses_generations_for_a_gradient_agent_in_one_line(tmp_path, capsys):
    assert main(["compare", "cem", "ppo", "--budget", "2gen", "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert "a budget of 2 generations means nothing to ppo" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()
