"""A run folder tells the truth under faults: kill -9, Ctrl-C, a second process, a full disk.

The process tests start real ``cartpole train`` processes: random-search with stop-when-solved off
plays full-length episodes to its generation budget (a few seconds), which leaves time to act.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from platforms import kill_9, sigstop, stop_signal_to_a_process

from cartpole.cli.main import main
from cartpole.core.names import RunState
from cartpole.runs import (
    Checkpoint,
    LiveStatus,
    RunDir,
    displayed_state,
    load_checkpoint,
    save_checkpoint,
    summarize_run,
)
from cartpole.runs.run_dir import STALE_SECONDS
from cartpole.training import resume, train

GENERATIONS = 80
TRAIN = [
    "train",
    "random-search",
    "--budget",
    f"{GENERATIONS}gen",
    "--no-stop-when-solved",
    "--set",
    "population=4",
    "--set",
    "eval_every=0",  # evaluate after every generation: best.pt and best_eval.json appear early
    "--set",
    "eval_screen_episodes=2",
    "--set",
    "eval_simulator=fast",
    "--quiet",
]


def cartpole(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def wait_for(condition, what: str, timeout: float = 120):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def the_run(runs_dir: Path) -> RunDir | None:
    folders = list(runs_dir.glob("*/config.json"))
    return RunDir(folders[0].parent) if folders else None


def generations_logged(run: RunDir) -> int:
    return max((r["train/iteration"] for r in run.metrics() if "train/iteration" in r), default=0)


def start_training(runs_dir: Path) -> tuple[subprocess.Popen[str], RunDir]:
    """A training process, once it has logged a few generations and written ``latest.pt``."""
    process = cartpole(*TRAIN, "--runs-dir", str(runs_dir))
    run = wait_for(lambda: the_run(runs_dir), "the run folder")
    wait_for(lambda: run.checkpoint_path("latest").exists() and generations_logged(run) >= 12, "latest.pt")
    assert process.poll() is None, "training ended before the test could act"
    return process, run


@sigstop
@kill_9
def test_kill_9_shows_crashed_and_resume_finishes_with_a_verdict(tmp_path):
    process, run = start_training(tmp_path / "runs")
    # Frozen (it keeps its lock and its pid), so it cannot finish while the second trainer starts up.
    process.send_signal(signal.SIGSTOP)

    # One process per run folder: a second trainer of the same folder gets one line, exit 2.
    second = subprocess.run(
        [sys.executable, "-m", "cartpole", "train", "--resume", str(run.path), "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert second.returncode == 2, second.stderr
    assert second.stderr.count("\n") == 1 and "Traceback" not in second.stderr
    assert f"being trained by another process (pid {process.pid} on " in second.stderr
    assert summarize_run(run.path).state == RunState.RUNNING

    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=60)  # reaps it and closes its pipes
    logged = generations_logged(run)  # what the process had done, as far as the disk knows
    saved = load_checkpoint(run.checkpoint_path("latest")).meta["loop"]["iterations"]
    assert logged - saved <= GENERATIONS // 10 + 1  # at most one checkpoint interval lost
    assert summarize_run(run.path).state == RunState.CRASHED
    assert not (run.path / "eval.json").exists()

    assert main(["train", "--resume", str(run.path), "--quiet"]) == 0
    assert run.status()["state"] == RunState.FINISHED
    assert summarize_run(run.path).state == RunState.FINISHED
    assert json.loads((run.path / "eval.json").read_text())["episodes"] >= 100
    assert generations_logged(run) == GENERATIONS


@stop_signal_to_a_process
def test_ctrl_c_leaves_no_verdict_and_runs_does_not_say_solved(tmp_path):
    """In-training evaluations go to best_eval.json and metrics.jsonl, never to eval.json."""
    process, run = start_training(tmp_path / "runs")
    assert (run.path / "best_eval.json").exists()
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGINT
    assert not (run.path / "eval.json").exists()
    summary = summarize_run(run.path)
    assert summary.state == RunState.INTERRUPTED and summary.verdict is None and summary.solved is False


def stop_in_the_final_verdict(monkeypatch: pytest.MonkeyPatch, fault: BaseException | int) -> None:
    """Make the final verdict fail: a signal arrives while judging, or writing eval.json raises."""
    import cartpole.training.engine as engine

    if isinstance(fault, int):
        judge = engine.play_final_episodes

        def signalled(*args, **kwargs):
            os.kill(os.getpid(), fault)
            time.sleep(1)  # the handler interrupts this
            return judge(*args, **kwargs)

        monkeypatch.setattr(engine, "play_final_episodes", signalled)
    else:

        def fails(self, report):
            raise fault

        monkeypatch.setattr(RunDir, "write_eval", fails)


@pytest.mark.parametrize(
    "fault",
    [signal.SIGINT, signal.SIGTERM, OSError(errno.ENOSPC, "No space left on device")],
    ids=["ctrl-c", "sigterm", "full-disk"],
)
def test_a_stop_between_training_and_verdict_leaves_a_run_resume_finishes(tmp_path, monkeypatch, fault):
    settings = {"population": "8", "eval_every": "0"}
    with monkeypatch.context() as patch:
        stop_in_the_final_verdict(patch, fault)
        if isinstance(fault, int):
            outcome = train("cem", seed=1, overrides=settings, budget="4gen", runs_dir=tmp_path)
            assert outcome.report is None and outcome.signal == fault
            run = outcome.run
        else:
            with pytest.raises(OSError, match="No space"):
                train("cem", seed=1, overrides=settings, budget="4gen", runs_dir=tmp_path)
            run = the_run(tmp_path)
    assert run is not None and not (run.path / "eval.json").exists()
    assert summarize_run(run.path).state != RunState.FINISHED
    trained = load_checkpoint(run.checkpoint_path("latest")).meta["loop"]

    finished = resume(run.path)
    assert finished.report is not None and run.eval_report() == finished.report.to_dict()
    assert run.status()["state"] == RunState.FINISHED
    assert finished.state.iterations == trained["iterations"] > 0  # only the verdict was left to do


def test_a_run_killed_before_its_first_checkpoint_starts_over(tmp_path):
    outcome = train("cem", seed=2, overrides={"population": "8"}, budget="3gen", runs_dir=tmp_path)
    run = outcome.run
    for leftover in [*run.checkpoint_dir.iterdir(), run.path / "eval.json", run.metrics_path]:
        leftover.unlink()
    run.write_status({"state": "running", "pid": 2**22 + 1, "host": socket.gethostname()})
    assert summarize_run(run.path).state == RunState.CRASHED
    again = resume(run.path)
    assert again.report is not None and again.state.iterations == 3
    assert again.report.to_dict()["returns"] == outcome.report.to_dict()["returns"]  # the same run


# --- the displayed state ---------------------------------------------------------------------------


def dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_displayed_state_running_only_while_the_process_lives():
    now = time.time()
    here = socket.gethostname()
    alive = {"state": "running", "pid": os.getpid(), "host": here, "heartbeat": now}
    assert displayed_state(alive, now) == RunState.RUNNING
    assert displayed_state(alive | {"pid": dead_pid()}, now) == RunState.CRASHED
    assert displayed_state(alive, now + STALE_SECONDS + 1) == RunState.CRASHED  # hung or frozen
    elsewhere = alive | {"host": "another-machine", "pid": dead_pid()}
    assert displayed_state(elsewhere, now) == RunState.RUNNING  # another host: only the heartbeat tells
    assert displayed_state(elsewhere, now + STALE_SECONDS + 1) == RunState.CRASHED
    assert displayed_state({"state": "running"}, now) == RunState.CRASHED  # no sign of life at all
    for state in ("finished", "interrupted", "failed"):
        assert displayed_state({"state": state}, now) == state
    assert displayed_state({"state": "bogus"}, now) == RunState.UNKNOWN
    assert displayed_state({}, now) == RunState.UNKNOWN


def test_heartbeat_is_refreshed_while_training(tmp_path):
    run = RunDir.create(tmp_path, "CartPole-v1", "cem", 0)
    with LiveStatus(run, interval=0.05) as live:
        live.write(RunState.RUNNING, {"env_steps": 7})
        first = run.status()
        wait_for(lambda: run.status()["heartbeat"] > first["heartbeat"], "a fresh heartbeat", timeout=10)
    status = run.status()
    assert status["env_steps"] == 7 and status["pid"] == os.getpid() and status["state"] == "running"


def test_the_web_api_lists_a_crashed_run(tmp_path):
    pytest.importorskip("httpx")
    from conftest_web import local_client

    outcome = train("cem", seed=0, overrides={"population": "8"}, budget="2gen", runs_dir=tmp_path)
    outcome.run.write_status({**outcome.run.status(), "state": "running", "pid": dead_pid()})
    client = local_client(tmp_path)
    (row,) = client.get("/api/runs").json()["runs"]
    assert row["state"] == "crashed"
    detail = client.get(f"/api/runs/{outcome.run.name}").json()
    assert detail["state"] == detail["status"]["state"] == "crashed"
    with client.websocket_connect(f"/ws/runs/{outcome.run.name}/metrics") as socket_:
        messages = [socket_.receive_json() for _ in range(3)]
    assert messages[0]["status"]["state"] == "crashed" and messages[-1] == {"type": "end", "state": "crashed"}


# --- a real full disk: a small tmpfs (needs root; skipped elsewhere) -------------------------------


@pytest.fixture
def small_disk(tmpfs):
    """A 3 MiB tmpfs with about 250 KiB left: room for a run folder's first files, not for its run."""
    disk = tmpfs("disk", "size=3m")
    (disk / "filler").write_bytes(bytes(3 * 2**20 - 250 * 2**10))
    return disk


@pytest.mark.parametrize(
    ("argv", "seeds"),
    [
        (["dqn", "--seed", "0"], 1),
        # 64-wide layers (the preset's are 16): checkpoints large enough that a checkpoint, not a
        # metric row, is what meets the full disk
        (["ppo", "--seeds", "0-3", "--set", "hidden_sizes=[64,64]"], 4),
        (["dqn", "--seeds", "0-1"], 2),
    ],
    ids=["single-dqn", "ppo-population", "dqn-population"],
)
def test_a_full_disk_is_one_line_and_every_status_says_so(argv, seeds, small_disk):
    """torch.save reports a full disk as a RuntimeError; we still give one line naming the file, exit
    2, and a status.json per seed that says "failed: disk full" (rewritten in place: no room for a
    temp file), while what was saved before stays loadable."""
    command = ["train", *argv, "--budget", "100k", "--no-stop-when-solved", "--quiet"]
    done = subprocess.run(
        [sys.executable, "-m", "cartpole", *command, "--runs-dir", str(small_disk / "runs")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "No space left on device" in done.stderr and ".pt" in done.stderr
    runs = sorted((small_disk / "runs").iterdir())
    assert len(runs) == seeds
    for run in runs:
        status = json.loads((run / "status.json").read_text())
        assert status["state"] == "failed" and status["stop_detail"].startswith("failed: disk full")
        for checkpoint in (run / "checkpoints").glob("*.pt"):
            load_checkpoint(checkpoint)  # atomic writes: nothing half-written


@pytest.fixture
def full_disk(tmp_path: Path):
    """A 1 MiB tmpfs filled to its last 8 KiB: room for no figure and no video."""
    disk = tmp_path / "full"
    disk.mkdir()
    mount = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True, text=True
    )
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {mount.stderr.strip()}")
    try:
        (disk / "filler").write_bytes(bytes(2**20 - 8 * 2**10))
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


@pytest.mark.parametrize(
    ("command", "name"),
    [(["plot"], "curve.png"), (["record", "--episodes", "2", "--max-steps", "50"], "episodes.gif")],
    ids=["plot", "record"],
)
def test_a_figure_or_video_on_a_full_disk_is_one_line_naming_it_and_leaves_nothing(
    command, name, cem_run, full_disk, capsys
):
    out = full_disk / name
    assert main([command[0], str(cem_run), *command[1:], "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err and str(out) in err
    assert "--resume" not in err  # nothing of a run to resume: plot and record only read one
    assert [p.name for p in full_disk.iterdir()] == ["filler"]  # no half-written file, no temp file


def test_metric_rows_on_a_full_disk_name_their_file(full_disk):
    run = RunDir(full_disk)
    with pytest.raises(OSError) as raised:
        run.append_metrics([{"step": i, "train/episode_return": 500.0} for i in range(2000)])
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == str(run.metrics_path)


# --- a resume never starts a run that has trained again from 0 unasked -----------------------------


@kill_9
def test_a_kill_before_the_first_interval_still_finds_latest_from_the_start(tmp_path):
    """latest.pt is written as training starts: a kill -9 at any moment after that leaves one."""
    process = cartpole(*TRAIN, "--runs-dir", str(tmp_path / "runs"))
    run = wait_for(lambda: the_run(tmp_path / "runs"), "the run folder")
    latest = wait_for(lambda: run.checkpoint_path("latest").exists(), "latest.pt at start")
    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=60)
    assert latest and load_checkpoint(run.checkpoint_path("latest")).meta["resumable"]


@pytest.mark.parametrize("population", [False, True], ids=["single", "population"])
def test_a_resume_without_latest_is_refused_unless_from_scratch(population, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    seeds = ["--seeds", "0-1"] if population else ["--seed", "0"]
    argv = ["train", "cem", *seeds, "--budget", "4gen", "--no-stop-when-solved", "--quiet"]
    assert main([*argv, "--set", "population=8", "--runs-dir", str(runs_dir)]) == 0
    capsys.readouterr()
    run = RunDir(sorted(runs_dir.iterdir())[0])
    run.checkpoint_path("latest").unlink()
    (run.path / "eval.json").unlink()
    run.write_status(run.status() | {"state": "interrupted"})  # it had trained 4 generations

    assert main(["train", "--resume", str(run.path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has no checkpoints/latest.pt although its status records" in err
    assert "add --from-scratch" in err and not (run.path / "eval.json").exists()

    assert main(["train", "--resume", str(run.path), "--from-scratch"]) == 0
    assert "resuming" in (err := capsys.readouterr().err) and "step 0 " in err  # where it resumes from
    assert run.status()["state"] == RunState.FINISHED and (run.path / "eval.json").exists()


@pytest.mark.parametrize("agent", ["ppo", "dqn"])
def test_a_latest_without_training_state_is_refused_unless_from_scratch(agent, tmp_path, capsys):
    """A run whose latest.pt cannot continue (here its policy only, as a run an earlier version trained
    with a seed's own learner left it) is refused in one line naming the file and saying what to do;
    with --from-scratch it trains again from step 0, to a verdict."""
    runs_dir = tmp_path / "runs"
    argv = ["train", agent, "--seed", "0", "--budget", "1500", "--no-stop-when-solved", "--quiet"]
    assert main([*argv, "--set", "hidden_sizes=16,16", "--runs-dir", str(runs_dir)]) == 0
    capsys.readouterr()
    run = RunDir(sorted(runs_dir.iterdir())[0])
    latest = load_checkpoint(run.checkpoint_path("latest"))
    policy_only = {k: v for k, v in latest.tensors.items() if k.startswith(("model.", "q_net."))}
    data = {k: latest.meta["learner"][k] for k in ("obs_dim", "n_actions")}
    save_checkpoint(
        run.checkpoint_path("latest"), Checkpoint(meta=latest.meta | {"learner": data}, tensors=policy_only)
    )
    (run.path / "eval.json").unlink()
    run.write_status(run.status() | {"state": "interrupted"})

    assert main(["train", "--resume", str(run.path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "latest.pt: holds no training state" in err
    assert "add --from-scratch" in err and not (run.path / "eval.json").exists()

    assert main(["train", "--resume", str(run.path), "--from-scratch"]) == 0
    assert "step 0 " in capsys.readouterr().err
    assert run.status()["state"] == RunState.FINISHED and (run.path / "eval.json").exists()
    assert load_checkpoint(run.checkpoint_path("latest")).meta["learner"]["population"]


def test_from_scratch_goes_with_resume(tmp_path, capsys):
    assert main(["train", "cem", "--from-scratch", "--runs-dir", str(tmp_path)]) == 2
    assert "--from-scratch goes with --resume" in capsys.readouterr().err


def test_resuming_a_finished_population_is_nothing_to_do_as_for_a_single_run(tmp_path, capsys):
    argv = ["train", "cem", "--seeds", "0-1", "--budget", "2gen", "--quiet", "--runs-dir", str(tmp_path)]
    assert main(argv) == 0
    member = sorted(tmp_path.iterdir())[0]
    capsys.readouterr()
    assert main(["train", "--resume", str(member)]) == 0
    assert "has finished; nothing to resume" in capsys.readouterr().out


# --- the verdict judges the kept best policy; the last one is scored beside it ---------------------


def train_past_its_best(seed: int, runs_dir: Path):
    """Random search that trains on after its solves: 6 generations of 4 candidates, evaluated each."""
    overrides = {"population": 4, "eval_every": 0}
    return train("random-search", seed=seed, budget="6gen", stop_when_solved=False, overrides=overrides,
                 runs_dir=runs_dir)  # fmt: skip


def test_the_last_policy_is_scored_beside_the_verdict_when_training_went_on_past_its_best(tmp_path):
    scored = 0
    for seed in range(4):
        outcome = train_past_its_best(seed, tmp_path)
        best_step = load_checkpoint(outcome.run.checkpoint_path("best")).meta["step"]
        last = outcome.run.last_eval_report()
        if best_step == outcome.state.env_steps:  # the best is the last policy: nothing more to say
            assert last is None and outcome.last_report is None
            continue
        scored += 1
        assert last is not None and last["step"] == outcome.state.env_steps
        assert last["seeds"] == outcome.report.seeds  # the verdict's own episodes, side by side
        assert outcome.last_report is not None and outcome.last_report.mean == last["mean"]
    assert scored >= 2, "random search with 4 candidates rarely keeps its last generation as the best"


def test_a_run_that_stops_at_its_solve_has_no_separate_last_score(tmp_path):
    outcome = train("cem", seed=0, runs_dir=tmp_path)
    assert outcome.report is not None and outcome.report.solved
    assert outcome.run.last_eval_report() is None and outcome.last_report is None


def test_a_population_scores_each_seeds_last_policy_as_its_single_run_does(tmp_path):
    argv = ["train", "random-search", "--seeds", "0-3", "--budget", "6gen", "--no-stop-when-solved"]
    settings_ = ["--set", "population=4", "--set", "eval_every=0", "--quiet"]
    assert main([*argv, *settings_, "--runs-dir", str(tmp_path / "population")]) == 0
    members = {RunDir(p).config()["seed"]: RunDir(p) for p in (tmp_path / "population").iterdir()}
    for seed, member in members.items():
        single = train_past_its_best(seed, tmp_path / "single")
        last = member.last_eval_report()
        if single.last_report is None:
            assert last is None
        else:  # a linear search's seed is bit-identical to its single run, its last score too
            assert last is not None and last["returns"] == single.last_report.returns
    assert sum(m.last_eval_report() is not None for m in members.values()) >= 2


# --- the output names the run at start; status keeps up with latest.pt; a resume from step 0 --------


@kill_9
@pytest.mark.parametrize("seeds", [[], ["--seeds", "0-1"]], ids=["single", "population"])
def test_the_run_is_named_as_training_starts_so_a_kill_9_leaves_it_in_the_output(seeds, tmp_path):
    """`--resume RUN` needs the run folder: it is printed before training, not only at the end, which
    a kill -9 (or the out-of-memory killer) never reaches. With --quiet too."""
    runs_dir = tmp_path / "runs"
    process = cartpole(*TRAIN, *seeds, "--runs-dir", str(runs_dir))
    run = wait_for(lambda: the_run(runs_dir), "the run folder")
    wait_for(lambda: run.checkpoint_path("latest").exists() and generations_logged(run) >= 2, "training")
    process.send_signal(signal.SIGKILL)
    out, _ = process.communicate(timeout=60)
    first = sorted(runs_dir.iterdir())[0]
    assert (f"run: {first}" if not seeds else f"runs: 2 in {runs_dir}/ (seeds 0-1), the first {first}") in out


KILLED_AT_THE_SECOND_GENERATION = """
import os, signal, sys
from cartpole.training import Callback
from cartpole.training.session import train_population

class KillAfter(Callback):
    def on_step(self, loop, result):
        if loop.state.iterations >= 2:
            os.kill(os.getpid(), signal.SIGKILL)
        return True

settings = {"population": "4", "checkpoint_every": "1"}
train_population("random-search", [0, 1], runs_dir=sys.argv[1], budget="80gen", stop_when_solved=False,
                 overrides=settings, callbacks=[KillAfter()])
"""


@kill_9
def test_a_populations_status_keeps_up_with_its_latest_checkpoint_through_a_kill_9(tmp_path):
    """A population writes status.json every few seconds; latest.pt may be written more often (here
    every generation). After a kill -9 no status may lag behind its latest.pt (it said env_steps 0
    while latest.pt was at about 20k)."""
    done = subprocess.run(
        [sys.executable, "-c", KILLED_AT_THE_SECOND_GENERATION, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    runs = [RunDir(p) for p in sorted(tmp_path.iterdir())]
    assert len(runs) == 2
    for run in runs:
        saved = load_checkpoint(run.checkpoint_path("latest")).meta["step"]
        status = run.status()
        assert saved > 0 and status["env_steps"] >= saved, (status, saved)
        assert summarize_run(run.path).state == RunState.CRASHED


KILLED_AS_TRAINING_STARTS = """
import os, signal, sys
from cartpole.training import Callback, train

class KillAtStart(Callback):
    def on_start(self, loop):
        os.kill(os.getpid(), signal.SIGKILL)

train("random-search", seed=0, runs_dir=sys.argv[1], budget="2gen", overrides={"population": "4"},
      callbacks=[KillAtStart()])
"""


@kill_9
def test_a_resume_from_a_latest_written_at_step_0_says_so(tmp_path, capsys):
    """latest.pt is written as training starts (step 0): a resume goes on from it and says so,
    not that there was no latest.pt."""
    done = subprocess.run(
        [sys.executable, "-c", KILLED_AS_TRAINING_STARTS, str(tmp_path)], capture_output=True, timeout=300
    )
    assert done.returncode == -signal.SIGKILL
    run = the_run(tmp_path)
    assert run is not None and load_checkpoint(run.checkpoint_path("latest")).meta["step"] == 0
    assert main(["train", "--resume", str(run.path)]) == 0
    err = capsys.readouterr().err
    assert f"resuming {run.name} from env step 0 (checkpoints/latest.pt)" in err
    assert "no checkpoints/latest.pt" not in err


@pytest.fixture
def filled_disk(tmpfs):
    """A 1 MiB tmpfs with no byte left."""
    disk = tmpfs("filled", "size=1m")
    (disk / "runs").mkdir()
    with open(disk / "filler", "wb", buffering=0) as filler:
        try:
            while True:
                filler.write(bytes(4096))
        except OSError as err:
            assert err.errno == errno.ENOSPC
    return disk


def test_a_full_disk_while_the_run_folder_is_made_leaves_no_folder(filled_disk, capsys):
    """No space for config.json: one line, exit 2, and no empty folder that `cartpole runs` would list
    as incomplete for ever."""
    runs_dir = filled_disk / "runs"
    argv = ["train", "random-search", "--budget", "1gen", "--quiet", "--runs-dir", str(runs_dir)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err and "config.json" in err
    assert list(runs_dir.iterdir()) == []
    assert main(["runs", "--runs-dir", str(runs_dir), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == []
