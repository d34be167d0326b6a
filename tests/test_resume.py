"""Interruption and resume: SIGINT in a real training process, then ``--resume``; damaged checkpoints."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from platforms import stop_signal_to_a_process

from cartpole.cli.main import main
from cartpole.runs import CheckpointError, RunDir, load_checkpoint
from cartpole.training import resume, train

# random-search with stop-when-solved off keeps playing full-length episodes: a run that lasts its
# whole budget (60 generations, a few seconds), with an evaluation now and then. The budget counts
# generations, not seconds, so a slow start (a JIT compile, a loaded machine) cannot end the run
# before the signal arrives.
TRAIN = [
    "train",
    "random-search",
    "--budget",
    "60gen",
    "--no-stop-when-solved",
    "--set",
    "population=4",
    "--set",
    "eval_every=20000",
    "--set",
    "eval_simulator=fast",
    "--quiet",
]


def cartpole(*args: str, **kwargs) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        **kwargs,
    )


def wait_for_rows(runs_dir: Path, rows: int, timeout: float = 120) -> RunDir:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for path in runs_dir.glob("*/metrics.jsonl"):
            run = RunDir(path.parent)
            if len(run.metrics()) >= rows:
                return run
        time.sleep(0.05)
    raise AssertionError(f"no run under {runs_dir} logged {rows} rows in {timeout} s")


def check_continuous(rows: list[dict]) -> None:
    """One row per generation, numbered 1, 2, 3, ... with counters that never go back."""
    generations = [r["train/iteration"] for r in rows if "train/iteration" in r]
    assert generations == list(range(1, len(generations) + 1))
    for earlier, later in itertools.pairwise(rows):
        assert later["step"] >= earlier["step"] and later["episode"] >= earlier["episode"]
        assert later["time"] >= earlier["time"]


def interrupt(runs_dir: Path, signum: int) -> tuple[RunDir, str]:
    """Start a real training process, signal it once rows are logged; return its run and output."""
    process = cartpole(*TRAIN, "--runs-dir", str(runs_dir))
    run = wait_for_rows(runs_dir, 1)  # the first generation's row: the loop is running
    assert process.poll() is None, "training ended before it could be interrupted"
    process.send_signal(signum)
    output, _ = process.communicate(timeout=60)
    assert process.returncode == 128 + signum, output
    flat = output.replace("\n", "")  # rich wraps long paths at 80 columns when output is a pipe
    assert "cartpole train --resume" in flat and run.name in flat
    status = run.status()
    assert status["state"] == "interrupted" and status["stop_reason"].startswith("interrupted")
    latest = load_checkpoint(run.checkpoint_path("latest"))
    assert latest.meta["resumable"] and latest.meta["step"] == status["env_steps"]
    return run, output


@stop_signal_to_a_process
def test_sigterm_stops_cleanly_with_143(tmp_path):
    interrupt(tmp_path / "runs", signal.SIGTERM)


@stop_signal_to_a_process
def test_sigint_then_resume_continues_without_gap_or_duplicate(tmp_path, capsys):
    run, _ = interrupt(tmp_path / "runs", signal.SIGINT)
    before = run.metrics()
    assert before and before[-1]["step"] == run.status()["env_steps"]  # every row up to the stop
    check_continuous(before)

    assert main(["train", "--resume", str(run.path), "--quiet"]) == 0
    after = run.metrics()
    assert after[: len(before)] == before  # nothing rewritten
    assert len(after) > len(before)
    check_continuous(after)
    assert after[len(before)]["step"] > before[-1]["step"]
    assert run.status()["state"] == "finished"
    assert json.loads((run.path / "eval.json").read_text())["episodes"] >= 100

    # A finished run: say so, exit 0, change nothing.
    capsys.readouterr()
    files = {p: p.read_bytes() for p in run.path.rglob("*") if p.is_file()}
    assert main(["train", "--resume", str(run.path)]) == 0
    assert "already finished" in capsys.readouterr().out
    assert files == {p: p.read_bytes() for p in run.path.rglob("*") if p.is_file()}


def test_resume_in_process_matches_an_uninterrupted_run(tmp_path):
    """Stopping after k generations and resuming gives the very rows of a run never stopped."""
    settings = {"population": "8", "eval_every": "400"}
    whole = train("cem", seed=3, overrides=settings, budget="12gen", runs_dir=tmp_path / "a")

    interrupted = train("cem", seed=3, overrides=settings, budget="5gen", runs_dir=tmp_path / "b")
    run = interrupted.run
    # pretend the 5-generation run was interrupted: the budget in config.json is the full one
    config = run.config()
    config["budget"] = whole.run.config()["budget"]
    run.write_config(config)
    run.write_status(run.status() | {"state": "interrupted"})
    finished = resume(run.path)

    def strip(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k not in ("time", "time/sps")} for r in rows]

    train_rows = lambda rows: [r for r in strip(rows) if "train/iteration" in r]  # noqa: E731
    assert train_rows(run.metrics()) == train_rows(whole.run.metrics())
    assert finished.state.env_steps == whole.state.env_steps
    assert finished.state.episodes == whole.state.episodes


def test_truncated_checkpoint_is_detected_and_latest_still_works(tmp_path, cem_run, capsys):
    run = RunDir(tmp_path / cem_run.name)
    import shutil

    shutil.copytree(cem_run, run.path)
    best = run.checkpoint_path("best")
    data = best.read_bytes()
    best.write_bytes(data[: len(data) // 2])  # cut mid-file

    with pytest.raises(CheckpointError, match="truncated or damaged"):
        load_checkpoint(best)
    assert main(["eval", str(best), "--episodes", "5"]) == 2
    err = capsys.readouterr().err
    assert "truncated or damaged" in err and "another of the run's checkpoints" in err
    assert "Traceback" not in err
    assert load_checkpoint(run.checkpoint_path("latest")).meta["resumable"]
    assert main(["eval", str(run.checkpoint_path("latest")), "--episodes", "5"]) == 0


def test_resume_from_a_truncated_latest_says_so(tmp_path, cem_run, capsys):
    import shutil

    path = tmp_path / cem_run.name
    shutil.copytree(cem_run, path)
    run = RunDir(path)
    run.write_status(run.status() | {"state": "interrupted"})
    latest = run.checkpoint_path("latest")
    latest.write_bytes(latest.read_bytes()[:100])
    assert main(["train", "--resume", str(path)]) == 2
    err = capsys.readouterr().err
    assert "cannot resume" in err and "latest.pt is truncated or damaged" in err
    assert "resumes only from its latest.pt" in err  # not a hint to resume from best.pt


def test_a_crash_while_saving_leaves_the_previous_latest(tmp_path, cem_run, monkeypatch):
    """What a kill -9 during a save leaves behind: the old file, intact, and no temp file."""
    import shutil

    import torch

    from cartpole.runs import save_checkpoint

    path = tmp_path / "latest.pt"
    shutil.copy(cem_run / "checkpoints" / "latest.pt", path)
    before = path.read_bytes()
    checkpoint = load_checkpoint(path)

    def dies_half_way(obj, handle, *args, **kwargs):
        handle.write(before[: len(before) // 2])
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, checkpoint)
    assert path.read_bytes() == before and load_checkpoint(path).meta["resumable"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest.pt"]
