"""Claims of a shared comparison (``cartpole compare --storage``), on a SQLite file: each run claimed by
one worker, stale claims taken over, only the first finish kept, and bad input as one line.

The same tables on a real PostgreSQL server, with two processes and a SIGKILL: test_compare_postgres.py.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from polling import wait_for

from cartpole.experiments.entries import Entry, ExperimentError
from cartpole.experiments.shared import RowState, SharedComparison

SETUP = {"env_id": "CartPole-v1", "budget": "3gen"}
CEM, RANDOM = Entry("cem"), Entry("random-search")
LABELS = [CEM.label, RANDOM.label]


@pytest.fixture
def url(tmp_path):
    return f"sqlite:///{tmp_path / 'shared.db'}"


def join(url: str, seeds: int = 4, timeout: float = 60.0) -> SharedComparison:
    return SharedComparison.join(url, "cmp", SETUP, [CEM, RANDOM], list(range(seeds)), timeout)


def claim(shared: SharedComparison, owner: str, chunk: int = 3, batches: bool = True, skip=frozenset()):  # type: ignore[no-untyped-def]
    every = {label: batches for label in LABELS}
    return shared.claim(owner, chunk, every, set(skip), LABELS, list(range(10)))


def test_joining_again_adds_nothing_twice_and_more_seeds_add_rows(url):
    join(url)
    join(url)
    shared = join(url, seeds=6)
    rows = shared.rows()
    assert len(rows) == 12 and len({(r.entry, r.seed) for r in rows}) == 12
    assert all(r.state == RowState.PENDING for r in rows)
    assert [e.label for e in shared.entries()] == LABELS


def test_a_claim_is_a_chunk_of_one_entry_and_no_other_worker_gets_it(url):
    shared = join(url)
    first = claim(shared, "a")
    assert first is not None and first.entry == CEM and first.seeds == [0, 1, 2]
    second = claim(shared, "b")
    assert second is not None and second.entry == RANDOM and second.seeds == [0, 1, 2]
    third = claim(shared, "c")
    assert third is not None and third.seeds == [3]
    owners = {(r.entry, r.seed): r.owner for r in shared.rows()}
    assert owners[(CEM.label, 0)] == "a" and owners[(RANDOM.label, 0)] == "b"
    assert sum(o is not None for o in owners.values()) == 7


def test_an_entry_that_does_not_batch_is_claimed_one_seed_at_a_time(url):
    shared = join(url)
    found = claim(shared, "a", batches=False)
    assert found is not None and found.seeds == [0]


def test_skipped_runs_are_not_claimed(url):
    shared = join(url, seeds=1)
    found = claim(shared, "a", skip={(CEM.label, 0)})
    assert found is not None and found.entry == RANDOM


def test_a_claim_without_heartbeat_is_taken_over_after_the_timeout(url):
    shared = join(url, seeds=1, timeout=2.0)
    assert claim(shared, "dead", chunk=1) is not None
    assert claim(shared, "alive", chunk=1) is not None  # the other entry
    assert claim(shared, "alive", chunk=1) is None  # nothing free: the dead one's claim is fresh
    for _ in range(3):
        time.sleep(0.8)
        assert shared.heartbeat("alive") == {(RANDOM.label, 0)}  # a live worker keeps its claim
    taken = claim(shared, "alive", chunk=1)
    assert taken is not None and taken.entry == CEM  # the dead worker's claim, now stale
    row = next(r for r in shared.rows() if r.entry == CEM.label)
    assert row.owner == "alive" and row.claims == 2
    assert shared.heartbeat("dead") == set()


def test_only_the_first_finish_is_kept_and_a_release_makes_a_run_pending(url):
    shared = join(url, seeds=1)
    claim(shared, "a", chunk=1)
    assert shared.finish("a", CEM, 0, {"solved_in_training": True}, {"steps": [1.0], "means": [2.0]})
    assert not shared.finish("b", CEM, 0, {"solved_in_training": False}, {})
    row = next(r for r in shared.rows() if r.entry == CEM.label)
    assert row.state == RowState.FINISHED and row.record == {"solved_in_training": True}
    claim(shared, "a", chunk=1)
    shared.release("a", RANDOM, 0)
    assert next(r for r in shared.rows() if r.entry == RANDOM.label).state == RowState.PENDING
    progress = shared.progress()
    assert (progress.total, progress.finished, progress.solved) == (2, 1, 1)
    records, curves = shared.finished()
    assert records == {CEM: [{"solved_in_training": True}], RANDOM: []}
    assert curves[CEM] == [{"steps": [1.0], "means": [2.0]}]


def test_joining_with_another_budget_is_refused(url):
    join(url)
    with pytest.raises(ExperimentError, match="was run with --budget 3gen, not 5gen"):
        SharedComparison.join(url, "cmp", {**SETUP, "budget": "5gen"}, [CEM], [0])


def test_a_sqlite_without_returning_is_refused_in_one_line(url, monkeypatch):
    from sqlite3 import dbapi2  # the module SQLAlchemy's SQLite dialect reads the version from

    monkeypatch.setattr(dbapi2, "sqlite_version_info", (3, 31, 1))
    with pytest.raises(ExperimentError, match=r"needs SQLite >= 3.35, and this Python's is 3.31.1"):
        join(url)


def test_a_comparison_that_is_not_there_cannot_be_opened(url):
    join(url)
    with pytest.raises(ExperimentError, match="no comparison named 'other'"):
        SharedComparison.open(url, "other")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["cem", "--storage", "postgresql://u@127.0.0.1:1/db"],
            "cannot reach the postgresql storage at 127.0.0.1:1",
        ),
        (["cem", "--storage", "nonsense"], "malformed --storage URL"),
        (["cem", "--storage", "sqlite:///x.db", "--claim-timeout", "0.5"], "--claim-timeout must be >= 2"),
        (["cem", "--chunk", "0"], "--chunk must be >= 1"),
        (["--report"], "--report needs --name NAME"),
        (["cem", "--report", "--name", "x"], "--report takes no ENTRY"),
        (["--report", "--name", "missing"], "no experiment named 'missing'"),
        ([], "name at least one ENTRY"),
    ],
)
def test_bad_shared_compare_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, args, message):
    from cartpole.cli.main import main

    monkeypatch.chdir(tmp_path)
    assert main(["compare", *args, "--runs-dir", str(tmp_path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / "experiments").exists() or args[:1] == ["--report"]


def test_a_shared_compare_on_sqlite_runs_every_seed_and_reports_from_the_database(tmp_path, url):
    command = [sys.executable, "-m", "cartpole", "compare", "cem", "--seeds", "2", "--budget", "2gen",
               "--storage", url, "--name", "cmp", "--chunk", "2"]  # fmt: skip
    first = subprocess.run(
        [*command, "--runs-dir", str(tmp_path / "m1")], capture_output=True, text=True, timeout=300
    )
    assert first.returncode == 0, first.stderr
    assert "| cem | 2 |" in first.stdout
    report = subprocess.run(
        [sys.executable, "-m", "cartpole", "compare", "--report", "--storage", url, "--name", "cmp",
         "--runs-dir", str(tmp_path / "m2")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert report.returncode == 0, report.stderr
    assert "| cem | 2 |" in report.stdout
    folder = tmp_path / "m2" / "experiments" / "cmp"
    assert (folder / "report.json").is_file() and (folder / "curves.png").is_file()
    assert not (tmp_path / "m2" / "experiments" / "cmp" / "runs").exists()  # nothing trained there
    local = subprocess.run(
        [sys.executable, "-m", "cartpole", "compare", "--report", "--name", "cmp",
         "--runs-dir", str(tmp_path / "m1")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert local.returncode == 0, local.stderr
    assert "| cem | 2 |" in local.stdout  # from the machine's own records, without the database


def test_a_worker_whose_claim_was_taken_over_stops_that_run_saving_nothing_and_goes_on(tmp_path, url):
    """A claim taken over while its run trains (as after a long pause or a network cut: here another owner
    writes itself into the row): at the next heartbeat the worker kills that run, writes nothing of it
    (no finish, no record, no file in its run folder, which the new owner may share), says so in one
    line, and runs the other entry."""
    from cartpole.experiments.shared import RUNS

    folder = tmp_path / "m1" / "experiments" / "cmp"
    command = [sys.executable, "-m", "cartpole", "compare", "cem", "random-search", "--seeds", "1",
               "--env", "MountainCar-v0", "--budget", "6s", "--jobs", "1", "--storage", url,
               "--name", "cmp", "--claim-timeout", "2", "--runs-dir", str(tmp_path / "m1")]  # fmt: skip
    worker = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        status = wait_for(lambda: next((folder / "runs").glob("*/status.json"), None), 300, "a run to start")
        shared = SharedComparison.open(url, "cmp")
        stolen = next(r for r in shared.rows() if r.state == RowState.CLAIMED)
        with shared.engine.begin() as db:  # the new owner's claim, fresh for ever
            db.execute(
                RUNS.update()
                .where(RUNS.c.entry == stolen.entry, RUNS.c.seed == stolen.seed)
                .values(owner="new-owner", heartbeat=time.time() + 1e6)
            )
        wait_for(lambda: _claimed_by_worker(shared, other_than=stolen.entry), 300, "the worker to go on")
        run_files = _files(status.parent)
        record = {**NEW_OWNERS_RECORD, "agent": stolen.agent, "preset": stolen.preset}
        assert shared.finish("new-owner", Entry(stolen.agent, stolen.preset), stolen.seed, record, {})
        _, stderr = worker.communicate(timeout=300)
    finally:
        if worker.poll() is None:
            worker.kill()
    assert worker.returncode == 0, stderr
    lost = [line for line in stderr.splitlines() if "took this claim over" in line]
    assert lost == [f"warning: {stolen.entry} seed 0: another worker took this claim over (this worker's "
                    "heartbeats were late); stopped its run here, saving nothing"], stderr  # fmt: skip
    rows = {r.entry: r for r in shared.rows()}
    assert rows[stolen.entry].owner == "new-owner" and rows[stolen.entry].record["run"] == "new-owner's"
    other = next(r for entry, r in rows.items() if entry != stolen.entry)
    assert other.state == RowState.FINISHED and other.record["seed"] == 0
    assert not (folder / "records" / f"{stolen.entry}__s0.json").exists()
    assert _files(status.parent) == run_files  # nothing written there after the kill
    assert not (status.parent / "eval.json").exists()


NEW_OWNERS_RECORD = {
    "seed": 0, "run": "new-owner's", "state": "finished", "solved_in_training": False, "solve_steps": None,
    "solve_wall_seconds": None, "solve_cpu_seconds": None, "env_steps": 1000, "wall_seconds": 6.0,
    "cpu_seconds": 6.0, "stop_reason": "budget", "final_mean": -200.0, "final_solved": False,
    "final_verdict": "not solved",
}  # fmt: skip


def _claimed_by_worker(shared: SharedComparison, other_than: str) -> bool:
    return any(r.entry != other_than and r.state != RowState.PENDING for r in shared.rows())


def _files(folder) -> dict[str, tuple[int, int]]:  # type: ignore[no-untyped-def]
    return {str(p): (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*") if p.is_file()}
