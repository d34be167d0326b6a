"""Trainings started through the web app's API: the token, the origin, the checks `cartpole train`
makes, the same run as the CLI's, the queue, stop and resume, a restart, a failure.

Every training here is a real `cartpole train` process started by the app (its lifespan runs: the
test client is used as a context manager), on a runs folder of the test's own.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from platforms import kill_9
from starlette.websockets import WebSocketDisconnect

from cartpole.cli.main import main as cartpole_main
from cartpole.runs import RunDir
from cartpole.training.request import TrainRequest, train_command
from cartpole.web.app import create_app
from cartpole.web.trainings import (
    CTRL_BREAK_EVENT,
    SIGBREAK,
    Trainings,
    ended_well,
    last_problem,
    stop_training_process,
)

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import LOCAL, LocalClient

TOKEN = "test-token-1234"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
LONG_DQN = {"agent": "dqn", "budget": "2000k", "settings": {"stop_when_solved": False}}
"""A training that goes on until it is stopped (far longer than any test)."""


@contextmanager
def served(runs_dir: Path, **options: Any) -> Iterator[TestClient]:
    """A client of an app on ``runs_dir`` whose lifespan runs (its trainings start and stop with it)."""
    app = create_app(runs_dir, token=TOKEN, **options)
    with LocalClient(app, base_url=LOCAL) as client:
        yield client


def wait_for(condition: Callable[[], Any], seconds: float = 120, what: str = "condition") -> Any:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def training(client: TestClient, name: str) -> dict[str, Any]:
    return next(row for row in client.get("/api/trainings").json() if row["name"] == name)


def state_becomes(client: TestClient, name: str, *states: str, seconds: float = 120) -> dict[str, Any]:
    return wait_for(
        lambda: (row := training(client, name))["state"] in states and row,
        seconds,
        f"training {name} to be {' or '.join(states)}",
    )


def trains(runs_dir: Path, run: str) -> bool:
    """Whether ``run`` is training: it has logged metrics and says it runs."""
    folder = RunDir(runs_dir / run)
    return folder.status().get("state") == "running" and bool(folder.read_metrics(0)[0])


# --- the token and the origin ---------------------------------------------------------------


@pytest.mark.parametrize(
    "headers",
    [{}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}, {"Cookie": "cartpole_token=wrong"}],
    ids=["none", "wrong-bearer", "no-scheme", "wrong-cookie"],
)
def test_a_start_without_the_right_token_is_401_and_starts_nothing(tmp_path: Path, headers: dict[str, str]):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    for path in ("/api/trainings", "/api/trainings/x/stop", "/api/trainings/x/resume"):
        answer = client.post(path, json={"agent": "cem"}, headers=headers)
        assert answer.status_code == 401, (path, answer.text)
        assert "token" in answer.text
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "headers",
    [
        {"Origin": "http://evil.example"},
        {"Origin": "http://127.0.0.1:9999"},
        {"Origin": "null"},
        {"Sec-Fetch-Site": "cross-site"},
        {"Sec-Fetch-Site": "same-site"},
    ],
)
def test_a_start_from_another_origin_is_403_even_with_the_token(tmp_path: Path, headers: dict[str, str]):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    answer = client.post("/api/trainings", json={"agent": "cem"}, headers={**BEARER, **headers})
    assert answer.status_code == 403, answer.text
    assert not (tmp_path / "runs").exists()


def test_the_pages_own_origin_with_the_cookie_may_check_a_training(tmp_path: Path):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    headers = {"Origin": LOCAL, "Sec-Fetch-Site": "same-origin", "Cookie": f"cartpole_token={TOKEN}"}
    answer = client.post("/api/trainings", json={"agent": "cem", "dry_run": True}, headers=headers)
    assert answer.status_code == 200, answer.text
    # The runs folder as the pages show it (its name): no path of this machine in an answer.
    assert answer.json()["command"] == ["cartpole", "train", "cem", "--runs-dir", "runs"]


def test_the_address_with_the_token_sets_a_strict_httponly_cookie_and_drops_the_token(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN), base_url=LOCAL)
    answer = client.get(f"/run?name=x&token={TOKEN}", follow_redirects=False)
    assert answer.status_code == 303
    assert answer.headers["location"] == "/run?name=x"
    cookie = answer.headers["set-cookie"]
    assert cookie.startswith(f"cartpole_token={TOKEN};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert client.get("/?token=wrong", follow_redirects=False).status_code == 401


def test_a_read_only_server_refuses_every_change_but_shows_everything(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN, read_only=True), base_url=LOCAL)
    for path in ("/api/trainings", "/api/trainings/x/stop", "/api/trainings/x/resume"):
        answer = client.post(path, json={"agent": "cem"}, headers=BEARER)
        assert answer.status_code == 403 and "read-only" in answer.text
    assert client.get("/api/runs").status_code == 200
    assert client.get("/api/trainings").json() == []
    assert client.get("/api/training-options").json()["read_only"] is True


def test_bound_beyond_this_machine_every_request_needs_the_token(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN, reads_need_token=True), base_url=LOCAL)
    assert client.get("/api/runs").status_code == 401
    assert client.get("/").status_code == 401
    assert client.get("/api/runs", headers=BEARER).status_code == 200
    with pytest.raises(WebSocketDisconnect), client.websocket_connect("/ws/play?env=CartPole-v1") as socket:
        socket.receive_json()
    client.get(f"/?token={TOKEN}")  # the cookie: the pages and their WebSockets work
    assert client.get("/api/runs").status_code == 200
    with client.websocket_connect("/ws/play?env=CartPole-v1") as socket:
        socket.send_json({"type": "reset", "seed": 1})
        assert socket.receive_json()["type"] == "state"


def test_a_server_on_this_machine_answers_reads_without_the_token(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN), base_url=LOCAL)
    assert client.get("/api/runs").status_code == 200
    assert client.get("/train").status_code == 200


# --- the checks: cartpole train's, word for word -------------------------------------------------

BAD_CHOICES = [
    ({"settings": {"lr": "abc"}}, ["--set", "lr=abc"], "lr"),
    ({"settings": {"lr": -1}}, ["--set", "lr=-1"], "lr"),
    ({"settings": {"batch_size": 2.5}}, ["--set", "batch_size=2.5"], "batch_size"),
    ({"settings": {"no_such_setting": 1}}, ["--set", "no_such_setting=1"], "settings"),
    ({"budget": "5x"}, ["--budget", "5x"], "budget"),
    ({"budget": "3gen"}, ["--budget", "3gen"], "budget"),
    ({"preset": "pixels"}, ["--preset", "pixels"], "preset"),
    ({"settings": {"eval_simulator": "mujoco"}}, ["--set", "eval_simulator=mujoco"], "eval_simulator"),
]


@pytest.mark.parametrize(("body", "flags", "field"), BAD_CHOICES, ids=[c[2] for c in BAD_CHOICES])
def test_a_bad_choice_gets_the_clis_message_for_its_field_and_nothing_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], body: dict[str, Any], flags: list[str], field: str
):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    answer = client.post("/api/trainings", json={"agent": "dqn", **body}, headers=BEARER)
    assert answer.status_code == 422, answer.text
    assert answer.json()["field"] == field
    assert cartpole_main(["train", "dqn", "--runs-dir", str(tmp_path / "cli"), *flags]) == 2
    cli_line = capsys.readouterr().err.strip().removeprefix("cartpole train: error: ")
    assert answer.json()["detail"] == cli_line
    assert not (tmp_path / "runs").exists() and not (tmp_path / "cli").exists()


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"agent": "dqn", "env_id": "Pendulum-v1"}, "env_id"),
        ({"agent": "dqn", "env_id": "mypkg:MyEnv-v0"}, "env_id"),
        ({"agent": "cem", "env_id": "cartpole/CartPolePixels-v1"}, "env_id"),
        ({"agent": "dqn", "preset": "best.toml"}, "preset"),
        ({"agent": "dqn", "preset": "/etc/passwd"}, "preset"),
        ({"agent": "nope"}, "agent"),
        ({"agent": "dqn", "seeds": [1, 1]}, "seeds"),
        ({"agent": "dqn", "seeds": [-1]}, "seeds"),
        ({"agent": "dqn", "seeds": []}, "seeds"),
        ({"agent": "cem", "settings": {"wrappers": ["os:system"]}}, "wrappers"),  # no import paths
        ({"agent": "cem", "settings": {"env_kwargs": "lit=0"}}, "env_kwargs"),
    ],
)
def test_only_the_apps_own_choices_are_taken(tmp_path: Path, body: dict[str, Any], field: str):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    answer = client.post("/api/trainings", json=body, headers=BEARER)
    assert answer.status_code == 422, answer.text
    assert answer.json()["field"] == field
    assert "\n" not in answer.json()["detail"]
    assert not (tmp_path / "runs").exists()


def test_a_dry_run_gives_the_command_and_starts_nothing(tmp_path: Path):
    client = LocalClient(create_app(Path("runs"), token=TOKEN), base_url=LOCAL)
    body = {
        "agent": "dqn",
        "env_id": "Acrobot-v1",
        "preset": "tutorial-pytorch",
        "seeds": [0, 1, 2, 5],
        "budget": "20k",
        "settings": {"lr": 0.0005, "hidden_sizes": [32, 32], "double_dqn": False, "max_grad_norm": None},
        "dry_run": True,
    }
    answer = client.post("/api/trainings", json=body, headers=BEARER)
    assert answer.status_code == 200, answer.text
    assert answer.json()["name"] is None and answer.json()["runs"] == []
    assert answer.json()["command"] == [
        "cartpole", "train", "dqn", "--env", "Acrobot-v1", "--preset", "tutorial-pytorch",
        "--seeds", "0-2,5", "--budget", "20k", "--set", "lr=0.0005", "--set", "hidden_sizes=[32, 32]",
        "--set", "double_dqn=false", "--set", "max_grad_norm=none",
    ]  # fmt: skip
    assert client.get("/api/trainings").json() == []


def test_the_command_gives_the_settings_the_json_gave():
    """Each JSON value, written as --set text, is read back by the config as the same value."""
    from cartpole.agents.registry import get_agent
    from cartpole.training.config import resolve_config

    settings = {"lr": 0.000123456789, "hidden_sizes": [48, 24], "double_dqn": False, "max_grad_norm": None}
    settings |= {"batch_size": 96, "loss": "mse", "tau": 1e-3}
    command = train_command(TrainRequest("dqn", settings=settings))
    texts = dict(part.split("=", 1) for part in command if "=" in part)
    from_json = resolve_config("dqn", get_agent("dqn").config_cls, "default", settings)
    from_text = resolve_config("dqn", get_agent("dqn").config_cls, "default", texts)
    assert from_json == from_text and len(texts) == len(settings)


def test_the_form_lists_every_setting_of_the_preset_with_its_value_and_doc(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN), base_url=LOCAL)
    options = client.get("/api/training-options", params={"agent": "dqn", "preset": "tutorial-keras"}).json()
    settings = {s["name"]: s for s in options["settings"]}
    assert settings["hidden_sizes"]["value"] == [512, 256, 64]  # the Keras tutorial's network
    assert settings["hidden_sizes"]["kind"] == "list"
    assert settings["lr"]["kind"] == "float" and settings["double_dqn"]["kind"] == "bool"
    assert all(s["doc"] and "\n" not in s["doc"] for s in settings.values())
    assert "confirm_solves" in settings and "budget" not in settings
    assert "env_kwargs" not in settings and "wrappers" not in settings  # the command line's only
    assert options["envs"][0] == "CartPole-v1" and "cartpole/CartPolePixels-v1" in options["envs"]
    pixels = client.get(
        "/api/training-options", params={"agent": "ppo", "env_id": "cartpole/CartPolePixels-v1"}
    )
    assert pixels.json()["preset"] == "pixels"  # the env's preset, as `cartpole train` picks it
    bad = client.get("/api/training-options", params={"agent": "cem", "env_id": "cartpole/CartPolePixels-v1"})
    assert bad.status_code == 422 and bad.json()["field"] == "env_id"


def test_the_schema_has_the_training_operations(tmp_path: Path):
    paths = create_app(tmp_path).openapi()["paths"]
    assert "post" in paths["/api/trainings"] and "get" in paths["/api/trainings"]
    assert "post" in paths["/api/trainings/{name}/stop"] and "post" in paths["/api/trainings/{name}/resume"]
    body = paths["/api/trainings"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert body["$ref"].endswith("TrainingIn")


# --- trainings: real processes ------------------------------------------------------------


def without_times(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in row.items() if "time" not in k and "sps" not in k} for row in rows]


def test_a_training_from_the_api_is_the_run_cartpole_train_starts(tmp_path: Path):
    runs = tmp_path / "runs"
    with served(runs) as client:
        answer = client.post("/api/trainings", json={"agent": "cem", "seeds": [3]}, headers=BEARER)
        assert answer.status_code == 201, answer.text
        name, (run,) = answer.json()["name"], answer.json()["runs"]
        state_becomes(client, name, "finished")
    folder = RunDir(runs / run)
    command = ["cartpole", "train", "cem", "--seed", "3", "--runs-dir", str(runs)]
    assert folder.config()["command"] == command  # the answer shows the runs folder by its name:
    assert answer.json()["command"] == [*command[:-1], "runs"]
    cli_runs = tmp_path / "cli"
    cli = [sys.executable, "-m", "cartpole", "train", "cem", "--seed", "3", "--runs-dir", str(cli_runs)]
    subprocess.run(cli, check=True, capture_output=True)
    (cli_run,) = [p for p in cli_runs.iterdir() if p.is_dir()]
    assert without_times(folder.read_metrics(0)[0]) == without_times(RunDir(cli_run).read_metrics(0)[0])
    ours, theirs = folder.eval_report(), RunDir(cli_run).eval_report()
    assert ours is not None and theirs is not None
    assert (ours["mean"], ours["std"], ours["episodes"], ours["solved"]) == (
        theirs["mean"], theirs["std"], theirs["episodes"], theirs["solved"]
    )  # fmt: skip


def test_a_population_from_the_api_names_every_run_folder(tmp_path: Path):
    with served(tmp_path) as client:
        answer = client.post("/api/trainings", json={"agent": "cem", "seeds": [0, 1]}, headers=BEARER)
        assert answer.status_code == 201
        assert len(answer.json()["runs"]) == 2
        assert "--seeds" in answer.json()["command"]
        state_becomes(client, answer.json()["name"], "finished")


def test_beyond_max_trainings_a_start_waits_in_the_queue_and_stop_starts_the_next(tmp_path: Path):
    with served(tmp_path, max_trainings=1) as client:
        first = client.post("/api/trainings", json=LONG_DQN, headers=BEARER).json()
        second = client.post("/api/trainings", json={**LONG_DQN, "seeds": [1]}, headers=BEARER).json()
        assert first["state"] == "running" and first["runs"]
        assert second["state"] == "queued" and second["runs"] == []
        assert training(client, second["name"])["queue_position"] == 1
        wait_for(lambda: trains(tmp_path, first["runs"][0]), what="the first to train")
        assert_runs_in_the_background(RunDir(tmp_path / first["runs"][0]).status()["pid"])
        stopped = client.post(f"/api/trainings/{first['name']}/stop", headers=BEARER)
        assert stopped.status_code == 200
        state_becomes(client, first["name"], "stopped")
        state_becomes(client, second["name"], "running")
        assert RunDir(tmp_path / first["runs"][0]).status()["state"] == "interrupted"
        assert (tmp_path / first["runs"][0] / "checkpoints" / "latest.pt").is_file()
        again = client.post(f"/api/trainings/{first['name']}/stop", headers=BEARER)
        assert again.status_code == 409
        client.post(f"/api/trainings/{second['name']}/stop", headers=BEARER)
        state_becomes(client, second["name"], "stopped")


def assert_runs_in_the_background(pid: int) -> None:
    """A training takes only the CPU time the server leaves (Linux's idle class), in the server's
    session (Linux shares CPU time between sessions first) but not its process group (a terminal's
    Ctrl-C is the server's). Windows has neither sessions nor getpgid: there the group of its own
    (CREATE_NEW_PROCESS_GROUP) is what Stop's Ctrl-Break is sent to."""
    if sys.platform == "linux":
        assert os.sched_getscheduler(pid) == os.SCHED_IDLE
    if sys.platform != "win32":  # POSIX sessions and process groups
        assert os.getsid(pid) == os.getsid(0)
        assert os.getpgid(pid) != os.getpgid(0)


def test_a_stop_as_a_training_starts_is_not_lost(tmp_path: Path):
    """Pressed before training has put up its signal handler (here, in a test runner's worker that may
    ignore SIGINT, which its children inherit), a Stop still ends the training."""
    with served(tmp_path) as client:
        started = client.post("/api/trainings", json=LONG_DQN, headers=BEARER).json()
        assert client.post(f"/api/trainings/{started['name']}/stop", headers=BEARER).status_code == 200
        state_becomes(client, started["name"], "stopped", seconds=60)


def test_a_queued_training_leaves_the_queue_when_stopped(tmp_path: Path):
    with served(tmp_path, max_trainings=1) as client:
        first = client.post("/api/trainings", json=LONG_DQN, headers=BEARER).json()
        second = client.post("/api/trainings", json={**LONG_DQN, "seeds": [1]}, headers=BEARER).json()
        assert client.post(f"/api/trainings/{second['name']}/stop", headers=BEARER).status_code == 200
        assert training(client, second["name"])["state"] == "stopped"
        client.post(f"/api/trainings/{first['name']}/stop", headers=BEARER)
        state_becomes(client, first["name"], "stopped")
        time.sleep(1)
        assert training(client, second["name"])["runs"] == []  # it never started


def test_stopping_the_server_saves_its_trainings_and_the_next_one_resumes_them(tmp_path: Path):
    with served(tmp_path) as client:
        started = client.post("/api/trainings", json=LONG_DQN, headers=BEARER).json()
        (run,) = started["runs"]
        wait_for(lambda: trains(tmp_path, run), what="training")
    status = RunDir(tmp_path / run).status()
    assert status["state"] == "interrupted" and status["stop_reason"] == "interrupted"
    steps = status["env_steps"]
    with served(tmp_path) as client:  # a restart: listed again from the runs folder
        (row,) = client.get("/api/trainings").json()
        assert (row["name"], row["state"], row["runs"]) == (started["name"], "stopped", [run])
        resumed = client.post(f"/api/trainings/{row['name']}/resume", headers=BEARER)
        assert resumed.status_code == 200, resumed.text
        state_becomes(client, row["name"], "running")
        wait_for(lambda: RunDir(tmp_path / run).status().get("env_steps", 0) > steps, what="more steps")
        assert client.post(f"/api/trainings/{row['name']}/resume", headers=BEARER).status_code == 409
        client.post(f"/api/trainings/{row['name']}/stop", headers=BEARER)
        state_becomes(client, row["name"], "stopped")
    config = RunDir(tmp_path / run).config()
    shown = [tmp_path.name if part == str(tmp_path) else part for part in config["command"]]
    assert shown == started["command"]  # a resume keeps the command that made the run


def test_a_training_an_earlier_server_left_running_is_stopped_cleanly_by_the_next(tmp_path: Path):
    """Not the server's child: Stop reaches it through the pid its status names, and it saves and
    exits as after the Stop button (the same stop_training_process: on Windows a Ctrl-Break, not
    os.kill's SIGTERM, which is TerminateProcess there)."""
    earlier = Trainings(tmp_path, max_running=1)  # a server that went away without stopping it
    long_dqn = {"budget": "2000k", "settings": {"stop_when_solved": False}}
    started = earlier.start(TrainRequest("dqn", **long_dqn, runs_dir=str(tmp_path)))
    process = started.process
    assert process is not None
    try:
        wait_for(lambda: (earlier.tick(), started.runs)[1], what="its run folder")
        (run,) = started.runs
        wait_for(lambda: trains(tmp_path, run), what="training")
        with served(tmp_path) as client:
            assert training(client, started.name)["state"] == "running"
            assert client.post(f"/api/trainings/{started.name}/stop", headers=BEARER).status_code == 200
            code = process.wait(60)
            state_becomes(client, started.name, "stopped")
    finally:
        earlier.close(timeout=60)
    assert code == 128 + signal.SIGTERM and ended_well(code)
    status = RunDir(tmp_path / run).status()
    assert status["state"] == "interrupted" and status["stop_detail"] == "interrupted (SIGTERM)", status
    assert (tmp_path / run / "checkpoints" / "latest.pt").is_file()


@kill_9
def test_a_training_whose_process_dies_shows_why_in_one_line_and_resumes(tmp_path: Path):
    with served(tmp_path) as client:
        started = client.post("/api/trainings", json=LONG_DQN, headers=BEARER).json()
        (run,) = started["runs"]
        wait_for(lambda: trains(tmp_path, run), what="training")
        os.kill(RunDir(tmp_path / run).status()["pid"], signal.SIGKILL)
        row = state_becomes(client, started["name"], "failed")
        assert "killed (SIGKILL)" in row["problem"] and "\n" not in row["problem"]
        assert client.post(f"/api/trainings/{started['name']}/resume", headers=BEARER).status_code == 200
        state_becomes(client, started["name"], "running")
        wait_for(lambda: trains(tmp_path, run), what="training again")
        client.post(f"/api/trainings/{started['name']}/stop", headers=BEARER)
        state_becomes(client, started["name"], "stopped")


def test_a_failed_commands_problem_is_its_error_line():
    output = "preset: pixels (...)\ncartpole train: error: runs/x: No space left on device (free some)\n"
    assert last_problem(output) == "runs/x: No space left on device (free some)"
    assert (
        last_problem("Traceback (most recent call last):\n  ...\nRuntimeError: boom\n")
        == "RuntimeError: boom"
    )


# --- how a training is stopped, and the exit codes that are a stop, on each platform --------------


@pytest.mark.parametrize(
    ("platform", "signum"),
    [("linux", signal.SIGTERM), ("darwin", signal.SIGTERM), ("win32", 1)],
    ids=["linux", "macos", "windows"],
)
def test_a_training_is_stopped_by_the_signal_it_saves_on(platform: str, signum: int):
    """On Windows os.kill(pid, CTRL_BREAK_EVENT) (1): Ctrl-Break to the process group whose id is
    pid, the group of its own a training is started in (CREATE_NEW_PROCESS_GROUP); SIGTERM there
    would be TerminateProcess, which ends it unsaved."""
    sent: list[tuple[int, int]] = []
    stop_training_process(4321, kill=lambda pid, signum: sent.append((pid, signum)), platform=platform)
    assert sent == [(4321, signum)]


def test_stopping_a_training_process_that_is_gone_does_nothing():
    def gone(pid: int, signum: int) -> None:
        raise ProcessLookupError(pid)

    stop_training_process(4321, kill=gone, platform="linux")
    stop_training_process(4321, kill=gone, platform="win32")


def test_the_windows_numbers_are_windows_own():
    """signal.CTRL_BREAK_EVENT and signal.SIGBREAK exist only on Windows: checked there."""
    assert getattr(signal, "CTRL_BREAK_EVENT", CTRL_BREAK_EVENT) == CTRL_BREAK_EVENT == 1
    assert getattr(signal, "SIGBREAK", SIGBREAK) == SIGBREAK == 21


@pytest.mark.parametrize(
    ("platform", "code"),
    [
        ("linux", 0),
        ("linux", 130),  # saved after SIGINT (Ctrl-C)
        ("linux", 143),  # saved after SIGTERM (Stop)
        ("linux", -signal.SIGINT),  # the signal's default, before training's handler: nothing to save
        ("linux", -signal.SIGTERM),
        ("darwin", 143),
        ("win32", 0),
        ("win32", 130),  # saved after Ctrl-C
        ("win32", 149),  # saved after Stop's Ctrl-Break: 128 + SIGBREAK (21)
        ("win32", 0xC000013A),  # STATUS_CONTROL_C_EXIT: Ctrl-Break before training's handler
    ],
)
def test_a_training_that_finished_or_was_stopped_is_no_problem(platform: str, code: int):
    assert ended_well(code, platform)


@pytest.mark.parametrize(
    ("platform", "code"),
    [
        ("linux", 1),  # a traceback
        ("linux", 2),  # bad input, a full disk
        ("linux", -9),  # SIGKILL: killed unsaved
        ("win32", 1),  # a traceback; Popen.kill (TerminateProcess with 1)
        ("win32", 2),
        ("win32", 15),  # os.kill(pid, SIGTERM): TerminateProcess with 15, unsaved
    ],
)
def test_a_training_that_failed_or_was_killed_is_a_problem(platform: str, code: int):
    assert not ended_well(code, platform)


def test_an_unknown_training_is_404(tmp_path: Path):
    client = LocalClient(create_app(tmp_path, token=TOKEN), base_url=LOCAL)
    for action in ("stop", "resume"):
        assert client.post(f"/api/trainings/nope/{action}", headers=BEARER).status_code == 404


def test_a_damaged_training_record_is_skipped(tmp_path: Path):
    (tmp_path / "trainings").mkdir()
    (tmp_path / "trainings" / "bad.json").write_text("{not json", "utf-8")
    (tmp_path / "trainings" / "other.json").write_text(json.dumps({"name": "../x"}), "utf-8")
    client = LocalClient(create_app(tmp_path, token=TOKEN), base_url=LOCAL)
    assert client.get("/api/trainings").json() == []
    assert client.get("/api/runs").json()["runs"] == []  # trainings/ is not a run


# --- cartpole serve ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--max-trainings", "0"], "--max-trainings must be at least 1"),
        (["--token", ""], "--token is empty"),
        (["--token", "a b"], "--token may hold only"),
    ],
)
def test_serve_refuses_bad_options_in_one_line(
    capsys: pytest.CaptureFixture[str], flags: list[str], message: str
):
    assert cartpole_main(["serve", "--port", "1", *flags]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_serve_prints_its_address_with_the_token(tmp_path: Path):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-m", "cartpole", "serve", "--runs-dir", str(tmp_path), "--port", str(port)]
    server = subprocess.Popen([*command, "--token", TOKEN], stdout=subprocess.PIPE, text=True)
    try:
        assert server.stdout is not None
        line = server.stdout.readline()
    finally:
        server.send_signal(signal.SIGTERM)  # a test worker's children may ignore SIGINT
        server.wait(30)
    assert f"http://127.0.0.1:{port}/?token={TOKEN}" in line
