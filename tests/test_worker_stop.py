"""Experiment workers stop cleanly the same way on every OS: the parent's stop request through the
worker's stdin, or the parent's end, has the worker save and exit as a Ctrl-C does. (Windows can send
no SIGINT to another process, and re-parents no orphan: this path is the one it takes.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import psutil
import pytest
from platforms import stop_signal_to_a_process
from polling import wait_for

from cartpole.experiments import processes, worker

SLOW_PRESET = "noise = 0.0001\nstop_when_solved = false\ncheckpoint_every = 1\n"
"""Hill climbing with a tiny step trains on to its budget, and writes latest.pt every generation."""


def worker_job(tmp_path: Path, budget: str = "30s") -> tuple[processes.Job, Path]:
    """A compare worker's job: one hill-climbing run that trains for ``budget``; its record's path."""
    preset = tmp_path / "slow.toml"
    preset.write_text(SLOW_PRESET)
    record = tmp_path / "record.json"
    task = worker.Task(
        "hill-climbing", str(preset), 0, "CartPole-v1", budget, str(tmp_path / "runs"), str(record), ["test"]
    )
    (tmp_path / "task.json").write_text(json.dumps(task.__dict__))
    args = processes.python_module("cartpole.experiments.worker", str(tmp_path / "task.json"))
    return processes.Job(args, tmp_path / "w.log"), record


def latest_saved(tmp_path: Path) -> bool:
    return bool(list(tmp_path.glob("runs/*/checkpoints/latest.pt")))


def assert_stopped_as_on_ctrl_c(tmp_path: Path, record: Path) -> None:
    """The record says interrupted, and the run's status says so, as a Ctrl-C leaves them."""
    assert json.loads(record.read_text())["state"] == worker.INTERRUPTED
    (status_file,) = tmp_path.glob("runs/*/status.json")
    status = json.loads(status_file.read_text())
    assert status["state"] == "interrupted" and status["stop_detail"] == "interrupted (SIGINT)", status
    assert "Traceback" not in (tmp_path / "w.log").read_text()


def test_a_worker_asked_to_stop_saves_its_run_and_exits_as_on_ctrl_c(tmp_path):
    job, record = worker_job(tmp_path)
    process = processes.start(job)
    try:
        wait_for(lambda: latest_saved(tmp_path), 120, "the worker's first checkpoint")
    finally:
        processes.stop_all({process: job}, grace=60)
    assert process.returncode == 130, (tmp_path / "w.log").read_text()
    assert_stopped_as_on_ctrl_c(tmp_path, record)


@contextmanager
def sigint_ignored() -> Iterator[None]:
    """SIGINT ignored here, and so in the processes started meanwhile (a background job's lot)."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_worker_asked_to_stop_before_it_trains_exits_130_without_a_traceback(tmp_path):
    """Even with SIGINT ignored from its start: the stop reaches it before its training does."""
    job, record = worker_job(tmp_path, budget="10min")
    with sigint_ignored():
        process = processes.start(job)
    try:
        processes.request_stop(process)
        assert process.wait(timeout=60) == 130, (tmp_path / "w.log").read_text()
    finally:
        process.kill()
        process.wait()
    assert "Traceback" not in (tmp_path / "w.log").read_text()
    assert not latest_saved(tmp_path) and not record.exists()


def test_a_worker_run_by_hand_does_not_read_its_stdin(tmp_path):
    """Only a worker that processes.start started takes the end of its stdin for a stop request."""
    job, record = worker_job(tmp_path, budget="2gen")
    done = subprocess.run(job.args, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads(record.read_text())["state"] == worker.FINISHED


@pytest.mark.slow
def test_the_workers_of_a_killed_compare_save_their_runs_and_stop(tmp_path):
    """SIGKILL of ``cartpole compare`` (nothing of it runs any more) still stops its workers cleanly:
    the end of their stdin is their stop request."""
    preset = tmp_path / "slow.toml"
    preset.write_text(SLOW_PRESET)
    runs_dir = tmp_path / "runs"
    args = ["compare", f"hill-climbing:{preset}", "--seeds", "2", "--jobs", "2", "--budget", "60s",
            "--name", "c", "--runs-dir", str(runs_dir)]  # fmt: skip
    parent = subprocess.Popen([sys.executable, "-m", "cartpole", *args], stderr=subprocess.DEVNULL)
    folder = runs_dir / "experiments" / "c"
    try:
        wait_for(lambda: len(list(folder.glob("runs/*/checkpoints/latest.pt"))) == 2, 120, "both workers")
        statuses = [json.loads(p.read_text()) for p in folder.glob("runs/*/status.json")]
    finally:
        parent.kill()
        parent.wait()
    workers = [psutil.Process(status["pid"]) for status in statuses]
    _, alive = psutil.wait_procs(workers, timeout=60)
    assert not alive, "a worker trains on for nobody"
    records = [json.loads(p.read_text()) for p in sorted((folder / "records").glob("*.json"))]
    assert len(records) == 2 and all(r["state"] == worker.INTERRUPTED for r in records), records
    for status_file in folder.glob("runs/*/status.json"):
        status = json.loads(status_file.read_text())
        assert status["state"] == "interrupted" and status["stop_detail"] == "interrupted (SIGINT)"


SLOW_SAVES = '''\
"""A test's hook (tests/test_worker_stop.py): every save of a latest.pt after the first hangs for
SECONDS, before its temp file is moved into place, where CARTPOLE_TEST_SLOW_SAVE=FOLDER:SECONDS;
FOLDER/saving is created as one starts."""
import os

_spec = os.environ.get("CARTPOLE_TEST_SLOW_SAVE")
if _spec:
    import time

    _folder, _, _seconds = _spec.rpartition(":")
    _replace, _saves = os.replace, []

    def _slow_replace(source, target, *args, **kwargs):
        if str(target).endswith("latest.pt"):
            _saves.append(target)
            if len(_saves) > 1:
                open(os.path.join(_folder, "saving"), "w").close()
                time.sleep(float(_seconds))
        return _replace(source, target, *args, **kwargs)

    os.replace = _slow_replace
'''


def compare_workers(parent: psutil.Process) -> list[psutil.Process]:
    return [
        p for p in parent.children(recursive=True) if "cartpole.experiments.worker" in " ".join(p.cmdline())
    ]


@stop_signal_to_a_process
@pytest.mark.slow
@pytest.mark.parametrize("while_it", ["trains", "saves"])
def test_sigterm_hands_the_claims_back_at_once_and_exits_within_slurms_grace(tmp_path, while_it):
    """As Slurm stops a task (scancel, preemption, its time limit): SIGTERM to `cartpole compare` and
    its worker, while the run trains or while it writes a checkpoint (here a save that hangs). The
    claim is pending again at once, the command exits 130 within 20 s (a worker that cannot finish
    its save is killed after the grace, its previous latest.pt kept), and the same command started
    again finishes at once: it does not wait out the claim timeout (10 minutes here)."""
    from cartpole.experiments.shared import RowState, SharedComparison

    preset = tmp_path / "slow.toml"
    preset.write_text(SLOW_PRESET)
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(SLOW_SAVES)
    url = f"sqlite:///{tmp_path / 'shared.db'}"
    command = [sys.executable, "-m", "cartpole", "compare", f"hill-climbing:{preset}", "--seeds", "1",
               "--budget", "15s", "--storage", url, "--name", "stop", "--claim-timeout", "600",
               "--runs-dir", str(tmp_path / "m")]  # fmt: skip
    env = dict(os.environ)
    if while_it == "saves":
        path = os.pathsep.join(p for p in (str(hook), env.get("PYTHONPATH", "")) if p)
        env |= {"PYTHONPATH": path, "CARTPOLE_TEST_SLOW_SAVE": f"{tmp_path}:600"}
    log = tmp_path / "first.log"
    with open(log, "wb") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env)
    try:
        if while_it == "saves":
            wait_for((tmp_path / "saving").is_file, 180, "a run to hang in a save of its latest.pt")
        else:
            wait_for(lambda: latest_saved(tmp_path / "m" / "experiments" / "stop"), 180, "a first checkpoint")
        workers = compare_workers(psutil.Process(process.pid))
        assert len(workers) == 1, workers
        sent = time.monotonic()
        for target in [process, *workers]:  # Slurm signals every process of the task
            target.send_signal(signal.SIGTERM)
        shared = SharedComparison.open(url, "stop")
        wait_for(lambda: all(r.state == RowState.PENDING for r in shared.rows()), 5, "the claim handed back")
        process.wait(timeout=60)
        took = time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
    text = log.read_text(errors="replace")
    assert process.returncode == 130, text
    assert took < 20, f"exited {took:.1f} s after SIGTERM\n{text}"
    assert "stopping: gave back the claims of 1 run(s) for other workers to take now" in text
    assert not [w for w in workers if w.is_running() and w.status() != psutil.STATUS_ZOMBIE]
    again = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    (row,) = shared.rows()
    assert row.state == RowState.FINISHED and row.claims == 2
    runs = sorted((tmp_path / "m" / "experiments" / "stop" / "runs").glob("*__s0__*"))
    if while_it == "trains":  # stopped cleanly: resumed from its folder, not trained again
        assert [Path(row.record["run"])] == runs
