"""Faults of a shared comparison and a shared sweep, against a real PostgreSQL server of the test's own
(tests/postgres_cluster.py): a `cartpole compare --storage` process killed with SIGKILL while it claims,
while its runs train, and between a run's end and the write of its results; the server restarted
(`pg_ctl -m immediate`) in the middle of a comparison and of a sweep. Every (entry, seed) ends finished
exactly once, every sweep trial complete, none twice.

The points "while it claims" and "after a run, before its results are stored" are reached through the
test hook CARTPOLE_PAUSE_AT (cartpole/experiments/pause_points.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import optuna
import pytest
from platforms import kill_9, proc
from polling import wait_for
from postgres_cluster import Cluster

from cartpole.experiments.pause_points import PAUSE_AT
from cartpole.experiments.shared import RowState, SharedComparison

LOST = "lost the database connection"


def start(args: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
    """A `cartpole` process, its output (both streams) in ``log``."""
    with open(log, "ab") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "cartpole", *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, **(env or {})},
        )


def finish(process: subprocess.Popen[bytes], log: Path, timeout: float = 300) -> str:
    try:
        process.wait(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
    text = log.read_text(errors="replace")
    assert process.returncode == 0, text
    return text


def compare_args(url: str, machine: Path, entries: list[str], seeds: int, budget: str) -> list[str]:
    flags = ["--budget", budget, "--storage", url, "--name", "faults", "--chunk", "2", "--claim-timeout", "3"]
    return ["compare", *entries, "--seeds", str(seeds), *flags, "--runs-dir", str(machine)]


def check_finished_once(url: str, entries: list[str], seeds: int) -> list[Any]:
    """Every (entry, seed) finished, exactly once: one row each, and one run folder each in the
    folders the records name."""
    rows = SharedComparison.open(url, "faults").rows()
    assert sorted((r.entry, r.seed) for r in rows) == sorted((e, s) for e in entries for s in range(seeds))
    assert all(r.state == RowState.FINISHED for r in rows), [(r.entry, r.seed, r.state) for r in rows]
    folders = [Path(r.record["run"]) for r in rows]
    assert len(set(folders)) == len(rows) and all(f.is_dir() for f in folders)
    return rows


def run_folders(machine: Path) -> list[Path]:
    return sorted((machine / "experiments" / "faults" / "runs").glob("*__s*"))


@kill_9
@pytest.mark.slow
def test_sigkill_while_claiming_leaves_the_claim_to_go_stale(private_postgres: Cluster, tmp_path):
    url = private_postgres.new_database()
    entries, seeds = ["cem"], 2
    log = tmp_path / "doomed.log"
    doomed = start(
        compare_args(url, tmp_path / "m0", entries, seeds, "3gen"), log, {PAUSE_AT: f"claim:{tmp_path}"}
    )
    try:
        wait_for((tmp_path / "claim").is_file, 120, "the first process to be inside its claim")
        doomed.send_signal(signal.SIGKILL)  # its claim stored, no worker started for it
        doomed.wait(timeout=30)
    finally:
        doomed.kill()
    survivor = start(compare_args(url, tmp_path / "m1", entries, seeds, "3gen"), tmp_path / "survivor.log")
    finish(survivor, tmp_path / "survivor.log")
    rows = check_finished_once(url, entries, seeds)
    # the dead process's claim went stale (3 s) and the survivor took each row over and trained it
    assert all(r.claims == 2 and "/m1/" in r.record["run"] for r in rows)
    assert not (tmp_path / "m0" / "experiments" / "faults" / "runs").exists()


@kill_9
@pytest.mark.slow
def test_sigkill_while_training_then_the_same_machine_resumes_its_runs(private_postgres: Cluster, tmp_path):
    url = private_postgres.new_database()
    entries, seeds, machine = ["reinforce"], 2, tmp_path / "m0"
    args = compare_args(url, machine, entries, seeds, "40000")
    doomed = start(args, tmp_path / "doomed.log")
    try:
        wait_for(
            lambda: any((f / "checkpoints" / "latest.pt").is_file() for f in run_folders(machine)),
            240,
            "a run to save its first checkpoint",
        )
        doomed.send_signal(signal.SIGKILL)  # its workers stop on their own, saving their runs
        doomed.wait(timeout=30)
    finally:
        doomed.kill()
    trained = run_folders(machine)
    again = start(args, tmp_path / "again.log")  # the same command on the same machine, after the kill
    finish(again, tmp_path / "again.log", timeout=600)
    rows = check_finished_once(url, entries, seeds)
    # each killed run was taken over (its claim stale) and resumed from its folder, not trained anew
    assert run_folders(machine) == trained
    assert all(r.claims == 2 and Path(r.record["run"]) in trained for r in rows)


def worker_pids(marker: str) -> list[int]:
    """Live compare worker processes whose command line mentions ``marker`` (a machine's folder)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            line = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if "cartpole.experiments.worker" in line and marker in line:
            found.append(int(pid))
    return found


@kill_9
@proc
@pytest.mark.slow
def test_a_worker_process_killed_while_training_has_its_runs_claimed_again(
    private_postgres: Cluster, tmp_path
):
    url = private_postgres.new_database()
    entries, seeds, machine = ["reinforce"], 2, tmp_path / "m0"
    log = tmp_path / "compare.log"
    process = start(compare_args(url, machine, entries, seeds, "40000"), log)
    try:
        wait_for(
            lambda: any((f / "checkpoints" / "latest.pt").is_file() for f in run_folders(machine)),
            240,
            "a run to save its first checkpoint",
        )
        (worker,) = wait_for(lambda: worker_pids(str(machine)), 30, "the worker process")
        os.kill(worker, signal.SIGKILL)  # as the kernel's out-of-memory killer would
    except BaseException:
        process.kill()
        raise
    text = finish(process, log, timeout=600)
    assert "was killed (signal 9): claiming its unfinished runs again (1/2)" in text
    rows = check_finished_once(url, entries, seeds)
    assert all(r.claims == 2 for r in rows)


@kill_9
@pytest.mark.slow
def test_sigkill_between_a_runs_end_and_its_results_write(private_postgres: Cluster, tmp_path):
    url = private_postgres.new_database()
    entries, seeds, machine = ["cem"], 2, tmp_path / "m0"
    args = compare_args(url, machine, entries, seeds, "3gen")
    doomed = start(args, tmp_path / "doomed.log", {PAUSE_AT: f"finish:{tmp_path}"})
    try:
        wait_for((tmp_path / "finish").is_file, 240, "the first process to end a run")
        doomed.send_signal(signal.SIGKILL)
        doomed.wait(timeout=30)
    finally:
        doomed.kill()
    rows = SharedComparison.open(url, "faults").rows()
    assert all(r.state == RowState.CLAIMED for r in rows)  # trained, but not stored
    records = sorted((machine / "experiments" / "faults" / "records").glob("*.json"))
    assert [json.loads(p.read_text())["state"] for p in records] == ["finished"] * seeds
    trained = run_folders(machine)
    again = start(args, tmp_path / "again.log")
    finish(again, tmp_path / "again.log")
    rows = check_finished_once(url, entries, seeds)
    # the takeover stored what the killed process had trained: nothing trained twice
    assert run_folders(machine) == trained
    assert all(r.claims == 2 and Path(r.record["run"]) in trained for r in rows)


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_a_claim_whose_reply_is_lost_after_its_commit_runs_once_and_nothing_waits(
    backend: str, request: pytest.FixtureRequest, tmp_path
):
    """The server commits a claim and its reply is lost (the connection closed after the commit): the
    new try finds the claim (rows this worker holds but runs nothing for) and trains it, so the
    comparison finishes, well within its claim timeout, with every row claimed once."""
    if backend == "postgresql":
        url = request.getfixturevalue("private_postgres").new_database()
    else:
        url = f"sqlite:///{tmp_path / 'shared.db'}"
    entries, seeds, machine = ["cem"], 2, tmp_path / "m0"
    args = compare_args(url, machine, entries, seeds, "3gen")
    args[args.index("--claim-timeout") + 1] = "8"
    log = tmp_path / "compare.log"
    process = start(args, log, {PAUSE_AT: f"claim-reply:{tmp_path}"})
    text = finish(process, log, timeout=120)
    assert (tmp_path / "claim-reply").is_file()  # the reply was lost
    assert f"{LOST} (" in text and "while trying to give work: retrying in" in text
    assert "the claim of cem seeds 0, 1 was stored before the connection was lost: training it" in text
    rows = check_finished_once(url, entries, seeds)
    assert all(r.claims == 1 for r in rows)  # no row claimed again: the retry ran the stored claim


def outage(cluster: Cluster, logs: Callable[[], str], timeout: float = 120) -> None:
    """Stop the server at once (connections cut), wait until a process says it lost its connection
    and is retrying, then start the server again."""
    cluster.stop()
    try:
        wait_for(lambda: LOST in logs(), timeout, "a process to say it lost the database connection")
    finally:
        cluster.start()


@pytest.mark.slow
def test_a_comparison_rides_out_a_postgres_restart(private_postgres: Cluster, tmp_path):
    url = private_postgres.new_database()
    entries, seeds, machine = ["cem", "reinforce"], 2, tmp_path / "m0"
    args = compare_args(url, machine, entries, seeds, "20000")
    log = tmp_path / "compare.log"
    process = start(args, log)
    try:
        wait_for(lambda: run_folders(machine), 240, "the first run to start")
        private_postgres.restart()  # pg_ctl restart -m immediate, as an operator would
        outage(private_postgres, lambda: log.read_text(errors="replace"))  # and one that a call meets
    except BaseException:
        process.kill()
        raise
    text = finish(process, log, timeout=600)
    retried = [line for line in text.splitlines() if LOST in line]
    assert retried and all("retrying in" in line for line in retried)
    rows = check_finished_once(url, entries, seeds)
    assert all(r.claims == 1 for r in rows)  # no run claimed twice, none trained twice
    assert len(run_folders(machine)) == len(entries) * seeds


@pytest.mark.slow
def test_a_sweep_rides_out_a_postgres_restart(private_postgres: Cluster, tmp_path):
    url = private_postgres.new_database()
    trials, machine = 4, tmp_path / "m0"
    log = tmp_path / "sweep.log"
    process = start(
        ["sweep", "cem", "--trials", str(trials), "--seeds", "2", "--study", "faults", "--storage", url,
         "--budget", "8gen", "--runs-dir", str(machine)],
        log,
    )  # fmt: skip
    logs = machine / "sweeps" / "faults" / "logs"

    def everything() -> str:
        return "".join(p.read_text(errors="replace") for p in [log, *sorted(logs.glob("*.log"))])

    try:
        wait_for(lambda: list((machine / "sweeps" / "faults" / "runs").glob("*")), 240, "a trial to train")
        private_postgres.restart()  # pg_ctl restart -m immediate, as an operator would
        outage(private_postgres, everything)  # and an outage that some call surely meets
    except BaseException:
        process.kill()
        raise
    finish(process, log, timeout=600)
    assert all("retrying in" in line for line in everything().splitlines() if LOST in line)
    study = optuna.load_study(study_name="faults", storage=url)
    states = optuna.trial.TrialState
    done = study.get_trials(states=(states.COMPLETE, states.PRUNED))
    assert len(done) == trials, [(t.number, t.state) for t in study.get_trials()]
    assert not study.get_trials(states=(states.RUNNING, states.WAITING, states.FAIL))
    folders = [t.user_attrs["run_seed0"] for t in done]
    assert len(set(folders)) == trials  # each trial trained once


def connection_refused() -> Exception:
    from sqlalchemy.exc import OperationalError

    return OperationalError("SELECT 1", {}, ConnectionRefusedError("connection refused\nmore detail"))


def test_a_lost_connection_is_retried_with_a_line_each_time_then_given_up(capsys):
    from cartpole.experiments.storage import retry_lost_connection

    calls: list[int] = []

    def flaky() -> str:
        calls.append(1)
        if len(calls) < 3:
            raise connection_refused()
        return "done"

    assert retry_lost_connection("claim runs", flaky, waits=(0.0, 0.0, 0.0)) == "done"
    lines = capsys.readouterr().err.splitlines()
    said = "lost the database connection (connection refused) while trying to claim runs: retrying in 0 s"
    assert lines == [f"{said} (1/3)", f"{said} (2/3)"]

    def down() -> str:
        raise connection_refused()

    with pytest.raises(Exception, match="connection refused"):
        retry_lost_connection("claim runs", down, waits=(0.0, 0.0))
    assert len(capsys.readouterr().err.splitlines()) == 2  # bounded: two waits, three tries


def test_a_query_after_the_lost_one_in_the_same_session_is_retried_too(capsys):
    """Optuna's _get_trials catches the lost query's OperationalError and queries again in the same
    session: SQLAlchemy's PendingRollbackError, raised while handling the first, wrapped by Optuna
    in a StorageInternalError (as CI met while PostgreSQL restarted)."""
    from optuna.exceptions import StorageInternalError
    from sqlalchemy.exc import PendingRollbackError

    from cartpole.experiments.storage import retry_lost_connection

    calls: list[int] = []

    def session_after_a_restart() -> str:
        calls.append(1)
        if len(calls) > 1:
            return "trials"
        try:
            try:
                raise connection_refused()
            except Exception as lost:  # Optuna's fallback: a second query in the same session
                said = "Can't reconnect until invalid transaction is rolled back"
                raise PendingRollbackError(said) from lost
        except PendingRollbackError as err:
            raise StorageInternalError("An exception is raised during the commit.") from err

    assert retry_lost_connection("get trials", session_after_a_restart, waits=(0.0,)) == "trials"
    assert "(connection refused)" in capsys.readouterr().err


def test_other_database_errors_are_not_retried(capsys):
    from sqlalchemy.exc import IntegrityError

    from cartpole.experiments.storage import retry_lost_connection

    def broken() -> None:
        raise IntegrityError("INSERT", {}, ValueError("duplicate key"))

    with pytest.raises(IntegrityError):
        retry_lost_connection("store results", broken, waits=(0.0,))
    assert capsys.readouterr().err == ""


def test_a_comparison_gives_up_in_one_line_once_the_database_stays_away(tmp_path, monkeypatch, capsys):
    from cartpole.experiments import storage
    from cartpole.experiments.compare import Experiment, SharedRunner
    from cartpole.experiments.entries import Entry
    from cartpole.experiments.storage import StorageLost

    experiment = Experiment.open(tmp_path, "away", [Entry("cem")], [0], budget="2gen")
    url = f"sqlite:///{tmp_path / 'shared.db'}"
    runner = SharedRunner(
        experiment, SharedComparison.join(url, "away", experiment.setup, [Entry("cem")], [0]), 1, None
    )
    monkeypatch.setattr(storage, "RETRY_WAITS", (0.0, 0.0))

    def down() -> None:
        raise connection_refused()

    with pytest.raises(StorageLost) as caught:
        runner.database("claim runs", down, None)
    assert str(caught.value) == (
        "lost the database connection (connection refused) for good while trying to claim runs: what "
        "finished is stored; re-run the same command to resume"
    )
    assert len(capsys.readouterr().err.splitlines()) == 2  # a line for each new try
