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


def test_workers_joining_at_the_same_moment_add_every_row_once_and_every_entry(url):
    """Joins hold no lock across round trips: eight threads join one new comparison at once, half with
    one entry and fewer seeds, half with both entries; every row is there once, both entries listed."""
    import threading

    start = threading.Barrier(8)
    errors: list[BaseException] = []

    def join_once(index: int) -> None:
        start.wait()
        entries, seeds = ([CEM], range(6)) if index % 2 else ([CEM, RANDOM], range(10))
        try:
            SharedComparison.join(url, "cmp", SETUP, entries, list(seeds), 60.0)
        except BaseException as err:  # reported below, not lost in a thread
            errors.append(err)

    threads = [threading.Thread(target=join_once, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert not errors, errors
    shared = SharedComparison.open(url, "cmp")
    rows = shared.rows()
    assert sorted((r.entry, r.seed) for r in rows) == sorted((e, s) for e in LABELS for s in range(10))
    assert all(r.state == RowState.PENDING and r.claims == 0 for r in rows)
    assert sorted(e.label for e in shared.entries()) == sorted(LABELS)


def test_joining_with_another_entry_adds_it_to_the_list_once(url):
    join(url, seeds=2)
    SharedComparison.join(url, "cmp", SETUP, [Entry("hill-climbing")], [0, 1], 60.0)
    SharedComparison.join(url, "cmp", SETUP, [Entry("hill-climbing"), CEM], [0, 1, 2], 60.0)
    shared = SharedComparison.open(url, "cmp")
    assert [e.label for e in shared.entries()] == [*LABELS, "hill-climbing"]
    assert len(shared.rows()) == 2 * 2 + 3 + 1  # cem and random-search 0-1, hill-climbing 0-2, cem 2


def runner_on(tmp_path, url: str, seeds: int = 2, chunk: int = 1):  # type: ignore[no-untyped-def]
    """A SharedRunner of one machine on ``url`` (entries cem and random-search), that starts nothing."""
    from cartpole.experiments.compare import Experiment, SharedRunner

    experiment = Experiment.open(tmp_path, "cmp", [CEM, RANDOM], list(range(seeds)), budget="3gen")
    shared = SharedComparison.join(url, "cmp", experiment.setup, [CEM, RANDOM], list(range(seeds)), 60.0)
    return SharedRunner(experiment, shared, chunk, None)


def lost_reply(shared: SharedComparison, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The next claim of ``shared`` is committed, then its reply lost (a connection reset)."""
    from sqlalchemy.exc import OperationalError

    from cartpole.experiments import storage

    monkeypatch.setattr(storage, "RETRY_WAITS", (0.0, 0.0))
    claim = shared.claim

    def committed_then_lost(*args, **kwargs):  # type: ignore[no-untyped-def]
        monkeypatch.setattr(shared, "claim", claim)  # once
        claim(*args, **kwargs)
        raise OperationalError("UPDATE", {}, ConnectionResetError("connection reset by peer"))

    monkeypatch.setattr(shared, "claim", committed_then_lost)


def test_a_claim_whose_reply_was_lost_is_the_one_the_retry_runs(tmp_path, url, monkeypatch, capsys):
    """The database committed the claim and the reply was lost: the new try finds the rows this worker
    holds without a job and runs them, claiming nothing more: every row claimed once."""
    runner = runner_on(tmp_path, url)
    lost_reply(runner.shared, monkeypatch)
    job = runner.next_job()
    assert job is not None and job.key == (CEM, [0])
    err = capsys.readouterr().err
    assert "lost the database connection (connection reset by peer) while trying to give work" in err
    assert "the claim of cem seed 0 was stored before the connection was lost: training it" in err
    rows = {(r.entry, r.seed): r for r in runner.shared.rows()}
    assert rows[(CEM.label, 0)].owner == runner.owner and rows[(CEM.label, 0)].claims == 1
    assert sum(r.state == RowState.CLAIMED for r in rows.values()) == 1
    assert runner.next_job().key == (RANDOM, [0])  # the next claim is an ordinary one


def test_a_claim_held_without_a_job_is_given_back_at_the_next_heartbeat(tmp_path, url, capsys):
    """However a worker came to hold a claim it runs nothing for (a reply lost while the retry claimed
    other rows), its next heartbeat gives it back: no comparison waits for it."""
    runner = runner_on(tmp_path, url)
    job = runner.next_job()
    assert job is not None
    orphan = claim(runner.shared, runner.owner, chunk=1)  # committed, never handed to a job
    assert orphan is not None and orphan.entry == RANDOM
    runner.last_beat -= runner.period
    assert runner.tick() == []  # the job's claim is still its own
    line = ("warning: random-search seed 0: this worker held the claim but ran nothing for it (its reply "
            "lost with the connection); gave it back, pending again")  # fmt: skip
    assert line in capsys.readouterr().err.splitlines()
    rows = {(r.entry, r.seed): r for r in runner.shared.rows()}
    assert rows[(RANDOM.label, 0)].state == RowState.PENDING and rows[(RANDOM.label, 0)].owner is None
    assert rows[(CEM.label, 0)].state == RowState.CLAIMED and rows[(CEM.label, 0)].owner == runner.owner


def test_a_worker_whose_run_another_finished_first_is_told_so(tmp_path, url, capsys):
    runner = runner_on(tmp_path, url)
    job = runner.next_job()
    assert job is not None
    assert runner.shared.finish("other", CEM, 0, {"solved_in_training": True}, {})
    runner.last_beat -= runner.period
    assert runner.tick() == [job]
    assert capsys.readouterr().err.splitlines() == [
        "warning: cem seed 0: another worker finished this run first (its result is the one kept); stopped "
        "its run here, saving nothing"
    ]


def test_on_a_stop_every_claim_is_handed_back_at_once(tmp_path, url, capsys):
    runner = runner_on(tmp_path, url, chunk=2)
    assert runner.next_job() is not None and runner.next_job() is not None
    assert sum(r.state == RowState.CLAIMED for r in runner.shared.rows()) == 4
    runner.hand_back()
    assert all(r.state == RowState.PENDING and r.owner is None for r in runner.shared.rows())
    assert (
        "stopping: gave back the claims of 4 run(s) for other workers to take now" in capsys.readouterr().err
    )
