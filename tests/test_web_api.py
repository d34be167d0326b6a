"""The web app's JSON API and WebSockets, through FastAPI's test client (no browser, no network)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from contextlib import suppress
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from platforms import proc, sessions

pytest.importorskip("fastapi", reason="the web app needs fastapi (a dependency of cartpole: reinstall it)")
pytest.importorskip("httpx", reason="FastAPI's test client needs httpx")

import httpx
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from cartpole.agents.registry import load_policy
from cartpole.envs.fast import CartPoleEnv, CartPoleParams
from cartpole.evaluation import Policy, evaluate, start_states
from cartpole.runs import RunDir
from cartpole.web.episodes import sim_limits

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import WebRuns, local_client, make_dqn_run, make_web_runs


@pytest.fixture(scope="module")
def web_runs(tmp_path_factory: pytest.TempPathFactory) -> WebRuns:
    return make_web_runs(tmp_path_factory.mktemp("web"))


@pytest.fixture(scope="module")
def client(web_runs: WebRuns) -> TestClient:
    return local_client(web_runs.root)


@pytest.fixture(scope="module")
def dqn_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A runs folder with one small DQN run, and that run's name."""
    root = tmp_path_factory.mktemp("dqn")
    return root, make_dqn_run(root)


def episode_url(run: str, checkpoint: str = "best") -> str:
    return f"/api/runs/{run}/checkpoints/{checkpoint}/episode"


# ---------------------------------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------------------------------


def test_runs_lists_every_run_newest_first_and_survives_bad_folders(client: TestClient, web_runs: WebRuns):
    body = client.get("/api/runs").json()
    by_name = {row["name"]: row for row in body["runs"]}
    assert body["runs"][0]["name"] == web_runs.cem  # created now; the others are dated 2000 and 2020
    cem = by_name[web_runs.cem]
    assert cem["agent"] == "cem" and cem["state"] == "finished" and cem["solved"] is True
    assert cem["rule"].startswith("mean ") and ">= 475 over 100 episodes, CartPole-v1" in cem["rule"]
    assert cem["watchable"] is True
    assert by_name[web_runs.other_env]["watchable"] is False
    assert (
        by_name[web_runs.acrobot]["watchable"] is True and by_name[web_runs.mountaincar]["watchable"] is True
    )
    assert by_name[web_runs.corrupt]["state"] == "unreadable" and by_name[web_runs.corrupt]["problem"]
    assert by_name[web_runs.incomplete]["state"] == "incomplete"
    assert "CartPole-v1__cem__s9__20200101-000000" not in by_name  # the symlink out is not listed


def test_runs_made_after_start_are_noticed(tmp_path: Path):
    client = local_client(tmp_path / "not-yet")
    assert client.get("/api/runs").json()["runs"] == []
    run = RunDir.create(tmp_path / "not-yet", "CartPole-v1", "cem", 1)
    run.write_config({"agent": "cem", "env_id": "CartPole-v1", "seed": 1, "created": "2030-01-01"})
    assert [r["name"] for r in client.get("/api/runs").json()["runs"]] == [run.name]


def test_run_detail_has_config_status_eval_and_checkpoints(client: TestClient, web_runs: WebRuns):
    body = client.get(f"/api/runs/{web_runs.cem}").json()
    assert body["config"]["agent"] == "cem"
    assert body["status"]["state"] == "finished"
    assert body["eval"]["solved"] is True and body["eval"]["episodes"] >= 100
    assert body["threshold"] == 475 and body["max_episode_steps"] == 500
    assert [c["name"] for c in body["checkpoints"]][:2] == ["latest", "best"]


def test_corrupt_and_half_written_runs_are_described(client: TestClient, web_runs: WebRuns):
    corrupt = client.get(f"/api/runs/{web_runs.corrupt}")
    assert corrupt.status_code == 200 and corrupt.json()["state"] == "unreadable"
    assert corrupt.json()["config"] is None
    incomplete = client.get(f"/api/runs/{web_runs.incomplete}/metrics")
    assert incomplete.json()["rows"] == [{"step": 1, "episode": 0, "time": 0.1}]  # half line left out


def test_a_corrupt_runs_problem_names_its_file_inside_the_runs_folder(client: TestClient, web_runs: WebRuns):
    listed = {row["name"]: row for row in client.get("/api/runs").json()["runs"]}[web_runs.corrupt]
    detail = client.get(f"/api/runs/{web_runs.corrupt}").json()
    for problem in (listed["problem"], detail["problem"]):
        assert problem.startswith(f"{Path(web_runs.corrupt, 'config.json')} is unreadable: ")
        assert str(web_runs.root) not in problem


def test_metrics_offset_returns_only_newer_rows(client: TestClient, web_runs: WebRuns):
    everything = client.get(f"/api/runs/{web_runs.cem}/metrics").json()
    assert everything["offset"] == 0 and everything["next_offset"] == len(everything["rows"]) > 2
    rest = client.get(f"/api/runs/{web_runs.cem}/metrics", params={"offset": 2}).json()
    assert rest["rows"] == everything["rows"][2:]
    done = client.get(f"/api/runs/{web_runs.cem}/metrics", params={"offset": everything["next_offset"]})
    assert done.json()["rows"] == []


def test_openapi_schema_documents_the_api(client: TestClient):
    paths = client.get("/openapi.json").json()["paths"]
    assert {"/api/runs", "/api/runs/{name}", "/api/runs/{name}/metrics"} <= set(paths)
    assert "/api/runs/{name}/checkpoints/{checkpoint}/episode" in paths


# ---------------------------------------------------------------------------------------------------
# Episodes
# ---------------------------------------------------------------------------------------------------


def test_episode_matches_what_evaluate_played(client: TestClient, web_runs: WebRuns):
    report = RunDir(web_runs.root / web_runs.cem).eval_report()
    assert report is not None
    seed, expected = report["seeds"][0], report["lengths"][0]
    body = client.get(episode_url(web_runs.cem), params={"seed": seed}).json()
    assert body["length"] == expected == len(body["actions"]) == len(body["rewards"])
    assert len(body["states"]) == body["length"] + 1
    np.testing.assert_array_equal(body["states"][0], start_states("CartPole-v1", [seed])[0])
    assert body["score_label"] == "linear score" and len(body["scores"]) == body["length"]
    assert all(np.argmax(s) == a for s, a in zip(body["scores"], body["actions"], strict=True))
    assert body["limits"]["fps"] == 50


def test_episode_agrees_with_evaluate_under_gymnasium(web_runs: WebRuns):
    """The server's simulator and Gymnasium's give the same episode length for the same policy."""
    from cartpole.web.episodes import play_episode

    policy = load_policy(web_runs.root / web_runs.cem / "checkpoints" / "best.pt")
    report = evaluate(policy, "CartPole-v1", episodes=5, seed=123)
    for seed, length in zip(report.seeds, report.lengths, strict=True):
        episode, _ = play_episode(policy, "CartPole-v1", seed)
        assert len(episode.actions) == length


def test_physics_overrides_and_nudges_change_the_trajectory(client: TestClient, web_runs: WebRuns):
    plain = client.get(episode_url(web_runs.cem), params={"seed": 5}).json()
    heavy = client.get(episode_url(web_runs.cem), params={"seed": 5, "gravity": 30, "length": 2}).json()
    assert heavy["physics"]["gravity"] == 30 and heavy["physics"]["length"] == 2
    assert heavy["states"][5] != plain["states"][5]
    nudged = client.get(episode_url(web_runs.cem), params={"seed": 5, "nudge_at": 20, "nudge": 1.5}).json()
    assert nudged["states"][:20] == plain["states"][:20]
    assert nudged["states"][20][3] == pytest.approx(plain["states"][20][3] + 1.5)
    assert nudged["nudges"] == [{"step": 20, "theta_dot_change": 1.5}]
    two = client.get(
        episode_url(web_runs.cem), params=[("nudge_at", 5), ("nudge", 1), ("nudge_at", 9), ("nudge", -1)]
    )
    assert len(two.json()["nudges"]) == 2


def test_dqn_episode_shows_q_values(dqn_runs: tuple[Path, str]):
    root, name = dqn_runs
    body = local_client(root).get(episode_url(name, "latest"), params={"seed": 1}).json()
    assert body["agent"] == "dqn" and body["score_label"] == "Q-values"
    assert len(body["scores"]) == body["length"] and len(body["scores"][0]) == 2


def reference_episode(
    policy: Policy, seed: int, physics: dict[str, float], nudges: dict[int, float]
) -> dict[str, Any]:
    """The episode the plain way: our single env stepped one action at a time, the time limit by hand."""
    env = CartPoleEnv(params=replace(CartPoleParams(), **physics))
    env.state = start_states("CartPole-v1", [seed])[0]
    states: list[list[float]] = []
    actions: list[int] = []
    scores: list[list[float]] = []
    terminated = truncated = False
    while not (terminated or truncated):
        assert env.state is not None
        if len(actions) in nudges:
            env.state[3] += nudges[len(actions)]  # in place: applies to the next step
        states.append(env.state.tolist())
        obs = env.state.astype(np.float32)[None]
        if hasattr(policy, "scores"):
            row = policy.scores(obs)[0]
            scores.append([float(v) for v in row])
            actions.append(int(np.argmax(row)))
        else:
            actions.append(int(policy.act(obs)[0]))
        _, _, terminated, _, _ = env.step(actions[-1])
        truncated = len(actions) >= 500
    states.append(env.state.tolist())
    return {
        "length": len(actions),
        "return": float(len(actions)),
        "terminated": terminated,
        "truncated": truncated,
        "states": states,
        "actions": actions,
        "rewards": [1.0] * len(actions),
        "scores": scores or None,
    }


EPISODE_CASES = [
    ({}, {}),
    ({"gravity": 30.0, "length": 2.0}, {}),
    ({"masspole": 0.7, "masscart": 0.2, "force_mag": 25.0}, {0: 0.4}),
    ({}, {10: 1.5, 11: -0.25, 40: -3.0}),
]


@pytest.mark.parametrize(("physics", "nudges"), EPISODE_CASES)
@pytest.mark.parametrize("agent", ["cem", "dqn"])
def test_episode_api_equals_a_plain_loop_over_the_single_env(
    web_runs: WebRuns,
    dqn_runs: tuple[Path, str],
    agent: str,
    physics: dict[str, float],
    nudges: dict[int, float],
):
    root, name = (web_runs.root, web_runs.cem) if agent == "cem" else dqn_runs
    policy = load_policy(root / name / "checkpoints" / "best.pt")
    client = local_client(root)
    for seed in (0, 3, 2**33 + 5):
        query: list[tuple[str, Any]] = [("seed", seed), *physics.items()]
        query += [item for step, change in nudges.items() for item in (("nudge_at", step), ("nudge", change))]
        body = client.get(episode_url(name), params=query).json()
        expected = reference_episode(policy, seed, physics, nudges)
        assert {key: body[key] for key in expected} == expected, (agent, seed, physics, nudges)


def test_a_policy_without_scores_plays_the_same_episode_as_the_plain_loop():
    from cartpole.web.episodes import play_episode

    class Balancer:  # act only: no scores to show
        def act(self, observations: np.ndarray) -> np.ndarray:
            return (np.asarray(observations) @ [0.05, 0.3, 1.0, 0.3] > 0).astype(np.int64)

    for seed, physics in ((1, {}), (2, {"gravity": 40.0})):
        episode, sim = play_episode(Balancer(), "CartPole-v1", seed, physics, {30: 2.0})
        got = episode.to_dict(sim_limits(sim), "linear score")
        expected = reference_episode(Balancer(), seed, physics, {30: 2.0})
        assert {key: got[key] for key in expected} == expected
        assert got["score_label"] is None


def test_runs_on_envs_watch_does_not_draw_cannot_be_watched(client: TestClient, web_runs: WebRuns):
    response = client.get(episode_url(web_runs.other_env))
    assert response.status_code == 409 and "Pendulum-v1 cannot be drawn" in response.json()["detail"]
    assert client.get(f"/api/runs/{web_runs.other_env}/metrics").json()["rows"]  # curves still show


@pytest.mark.parametrize(
    ("kind", "env_id", "scene"),
    [("acrobot", "Acrobot-v1", "acrobot"), ("mountaincar", "MountainCar-v0", "mountaincar")],
)
def test_acrobot_and_mountaincar_episodes_are_gymnasiums_own(
    client: TestClient, web_runs: WebRuns, kind: str, env_id: str, scene: str
):
    """The episode of a checkpoint on Acrobot or MountainCar: Gymnasium's env from reset(seed), the
    env's own state at every step (what the drawing needs), the policy's scores, evaluate()'s return."""
    import gymnasium as gym

    run = getattr(web_runs, kind)
    response = client.get(f"{episode_url(run)}?seed=11")
    assert response.status_code == 200, response.text
    got = response.json()
    assert (got["env_id"], got["scene"], len(got["action_labels"])) == (env_id, scene, 3)
    assert len(got["states"]) == got["length"] + 1 == len(got["actions"]) + 1 == len(got["scores"]) + 1
    env = gym.make(env_id)
    env.reset(seed=11)
    assert got["states"][0] == pytest.approx(np.asarray(env.unwrapped.state).tolist())
    policy = load_policy(web_runs.root / run)
    assert got["return"] == evaluate(policy, env_id, 1, seed=11).returns[0] == sum(got["rewards"])
    assert [int(np.argmax(s)) for s in got["scores"]] == got["actions"]
    assert got["terminated"] or got["length"] == env.spec.max_episode_steps
    for query in ("gravity=5", "nudge_at=3&nudge=1.0"):
        refused = client.get(f"{episode_url(run)}?{query}")
        assert refused.status_code == 422 and "CartPole only" in refused.json()["detail"]


def test_a_checkpoint_that_does_not_fit_its_runs_env_is_refused(client: TestClient, web_runs: WebRuns):
    """A CartPole agent's checkpoint in a run that says Acrobot: 409 naming both, never a 500."""
    run = RunDir.create(web_runs.root, "Acrobot-v1", "cem", 5)
    run.write_config({**RunDir(web_runs.root / web_runs.cem).config(), "env_id": "Acrobot-v1", "seed": 5})
    shutil.copy(web_runs.root / web_runs.cem / "checkpoints" / "best.pt", run.checkpoint_path("best"))
    try:
        response = client.get(episode_url(run.name))
        assert response.status_code == 409
        assert "CartPole-v1" in response.json()["detail"] and "Acrobot-v1" in response.json()["detail"]
    finally:
        shutil.rmtree(run.path)


# ---------------------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "path",
    [
        "/api/runs/..",
        "/api/runs/..%2Fruns",
        "/api/runs/%2e%2e",
        "/api/runs/..%2F..%2Fetc",
        "/api/runs/%2Fetc%2Fpasswd",
        "/api/runs/.hidden",
        "/api/runs/no-such-run",
        "/api/runs/CartPole-v1__cem__s9__20200101-000000",  # symlink out of the folder
        "/api/runs/CartPole-v1__cem__s9__20200101-000000/metrics",
    ],
)
def test_unsafe_or_unknown_run_names_are_404(client: TestClient, path: str):
    assert client.get(path).status_code == 404


@pytest.mark.parametrize("checkpoint", ["nope", "..", "best.pt", "%2E%2E%2Fconfig", "..%2F..%2Fconfig"])
def test_unsafe_or_unknown_checkpoints_are_404(client: TestClient, web_runs: WebRuns, checkpoint: str):
    assert client.get(episode_url(web_runs.cem, checkpoint)).status_code == 404


def test_an_unknown_checkpoint_names_the_ones_the_run_has(client: TestClient, web_runs: WebRuns):
    response = client.get(episode_url(web_runs.cem, "newest"))
    assert response.status_code == 404
    detail = response.json()["detail"]
    assert "has no checkpoint 'newest'; it has: " in detail and "latest" in detail and "best" in detail
    assert "CheckpointName" not in detail


def test_checkpoint_symlinked_out_of_the_run_is_404(tmp_path: Path, web_runs: WebRuns):
    root = tmp_path / "runs"
    shutil_copy = __import__("shutil").copytree
    shutil_copy(web_runs.root / web_runs.cem, root / web_runs.cem)
    (root / web_runs.cem / "checkpoints" / "evil.pt").symlink_to(web_runs.root / web_runs.cem / "config.json")
    assert local_client(root).get(episode_url(web_runs.cem, "evil")).status_code == 404


@pytest.mark.parametrize(
    "params",
    [
        {"seed": -1},
        {"seed": "abc"},
        {"seed": 2**60},
        {"gravity": -1},
        {"gravity": "nan"},
        {"gravity": "inf"},
        {"length": 0},
        {"masspole": 1000},
        {"masscart": "heavy"},
        {"force_mag": 1e9},
        {"nudge_at": 3},  # no nudge value
        {"nudge_at": 10_000, "nudge": 1},
        {"nudge_at": 3, "nudge": 99},
    ],
)
def test_bad_episode_queries_are_422_with_a_message(client: TestClient, web_runs: WebRuns, params: dict):
    response = client.get(episode_url(web_runs.cem), params=params)
    assert response.status_code == 422
    assert response.json()["detail"]


@pytest.mark.parametrize("offset", [-1, "x", 10**12])
def test_bad_metrics_offset_is_422(client: TestClient, web_runs: WebRuns, offset: object):
    response = client.get(f"/api/runs/{web_runs.cem}/metrics", params={"offset": offset})
    assert response.status_code == 422 and response.json()["detail"]


# ---------------------------------------------------------------------------------------------------
# WebSockets
# ---------------------------------------------------------------------------------------------------


def test_play_session_steps_on_the_server(client: TestClient):
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text(json.dumps({"type": "reset", "seed": 42}))
        first = ws.receive_json()
        assert first["step"] == 0 and first["seed"] == 42 and first["physics"]["gravity"] == 9.8
        np.testing.assert_array_equal(first["state"], start_states("CartPole-v1", [42])[0])
        for _ in range(10):
            ws.send_text(json.dumps({"type": "step", "action": 1}))
            reply = ws.receive_json()
        assert reply["step"] == 10 and reply["return"] == 10 and reply["state"][1] > first["state"][1]
        while not (reply["terminated"] or reply["truncated"]):
            ws.send_text(json.dumps({"type": "step", "action": 1}))
            reply = ws.receive_json()
        assert reply["terminated"] and reply["step"] < 100  # always pushing right: the pole falls
        ws.send_text(json.dumps({"type": "step", "action": 1}))
        assert ws.receive_json()["type"] == "error"  # an ended episode needs a reset; socket stays open
        ws.send_text(json.dumps({"type": "reset", "physics": {"gravity": 1.0}}))
        again = ws.receive_json()
        assert again["step"] == 0 and again["physics"]["gravity"] == 1.0 and isinstance(again["seed"], int)


@pytest.mark.parametrize(
    "message",
    [
        "not json",
        "{}",
        '{"type": "step", "action": 3}',
        '{"type": "step", "action": "left"}',
        '{"type": "step", "action": 1.0}',
        '{"type": "step", "action": true}',
        '{"type": "step", "action": 1, "extra": 2}',
        '{"type": "reset", "seed": -5}',
        "[1, 2, 3]",
        b"\x00\x01binary",
    ],
)
def test_play_garbage_closes_with_a_reason_and_the_server_carries_on(client: TestClient, message):
    with client.websocket_connect("/ws/play") as ws:
        if isinstance(message, bytes):
            ws.send_bytes(message)
        else:
            ws.send_text(message)
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    assert closed.value.code == 1008 and closed.value.reason
    with client.websocket_connect("/ws/play") as ws:  # the server is fine
        ws.send_text('{"type": "reset", "seed": 1}')
        assert ws.receive_json()["step"] == 0


def test_play_rejects_bad_physics_with_an_error_message(client: TestClient):
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text(json.dumps({"type": "reset", "physics": {"gravity": -3}}))
        reply = ws.receive_json()
        assert reply["type"] == "error" and "gravity" in reply["message"]


def test_play_refuses_envs_it_cannot_draw(client: TestClient):
    with (
        pytest.raises(WebSocketDisconnect) as closed,
        client.websocket_connect("/ws/play?env=Pendulum-v1") as ws,
    ):
        ws.receive_json()
    assert "cannot be played" in closed.value.reason and "Acrobot-v1" in closed.value.reason


def test_cartpole_has_no_third_action(client: TestClient):
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text(json.dumps({"type": "reset", "seed": 1}))
        assert ws.receive_json()["scene"] == "cartpole"
        ws.send_text(json.dumps({"type": "step", "action": 2}))
        reply = ws.receive_json()
        assert reply["type"] == "error" and "0 (push left) or 1 (push right)" in reply["message"]


@pytest.mark.parametrize("env_id", ["Acrobot-v1", "MountainCar-v0"])
def test_acrobot_and_mountaincar_play_gymnasiums_env_on_the_server(client: TestClient, env_id: str):
    import gymnasium as gym

    env = gym.make(env_id)
    env.reset(seed=8)
    with client.websocket_connect(f"/ws/play?env={env_id}") as ws:
        ws.send_text(json.dumps({"type": "reset", "seed": 8}))
        first = ws.receive_json()
        assert (first["scene"], len(first["action_labels"]), first["step"]) == (
            env_id.split("-")[0].lower(),
            3,
            0,
        )
        assert first["state"] == pytest.approx(np.asarray(env.unwrapped.state).tolist())
        assert first["limits"]["fps"] > 0 and first["physics"] == {}
        for action in (0, 1, 2, 2, 0):
            ws.send_text(json.dumps({"type": "step", "action": action}))
            reply = ws.receive_json()
            env.step(action)
            assert reply["state"] == pytest.approx(np.asarray(env.unwrapped.state).tolist())
        assert reply["step"] == 5 and reply["return"] == -5.0
        ws.send_text(json.dumps({"type": "reset", "physics": {"gravity": 5.0}}))
        refused = ws.receive_json()
        assert refused["type"] == "error" and "CartPole only" in refused["message"]


def test_live_metrics_of_a_finished_run_sends_rows_then_ends(client: TestClient, web_runs: WebRuns):
    total = len(client.get(f"/api/runs/{web_runs.cem}/metrics").json()["rows"])
    with client.websocket_connect(f"/ws/runs/{web_runs.cem}/metrics?offset=1") as ws:
        messages = []
        while not messages or messages[-1]["type"] != "end":
            messages.append(ws.receive_json())
    rows = [row for m in messages if m["type"] == "metrics" for row in m["rows"]]
    assert len(rows) == total - 1
    assert any(m["type"] == "status" and m["status"]["state"] == "finished" for m in messages)


def test_live_metrics_pushes_rows_as_they_are_appended(tmp_path: Path):
    run = RunDir.create(tmp_path, "CartPole-v1", "dqn", 0)
    run.write_config({"agent": "dqn", "env_id": "CartPole-v1", "seed": 0})
    run.write_status({"state": "running", "env_steps": 0})
    client = local_client(tmp_path)
    with client.websocket_connect(f"/ws/runs/{run.name}/metrics") as ws:
        assert ws.receive_json()["type"] == "status"
        run.append_metrics([{"step": 10, "episode": 1, "time": 0.1, "train/episode_return": 10.0}])
        message = ws.receive_json()
        assert message["type"] == "metrics" and message["rows"][0]["step"] == 10
        run.write_status({"state": "finished", "env_steps": 10})
        types = []
        while not types or types[-1] != "end":
            types.append(ws.receive_json()["type"])
        assert "status" in types


def test_live_metrics_garbage_and_unknown_runs_close_with_a_reason(client: TestClient, web_runs: WebRuns):
    with pytest.raises(WebSocketDisconnect) as closed, client.websocket_connect("/ws/runs/../metrics") as ws:
        ws.receive_json()
    with (
        pytest.raises(WebSocketDisconnect) as closed,
        client.websocket_connect("/ws/runs/nope/metrics") as ws,
    ):
        ws.receive_json()
    assert closed.value.code == 1008 and "no run" in closed.value.reason
    run = RunDir(web_runs.root / web_runs.other_env)
    run.write_status({"state": "running"})  # keep it open
    try:
        with client.websocket_connect(f"/ws/runs/{web_runs.other_env}/metrics") as ws:
            ws.send_text("garbage")
            with pytest.raises(WebSocketDisconnect) as closed:
                while True:
                    ws.receive_json()
        assert closed.value.code == 1008 and closed.value.reason
    finally:
        run.write_status({"state": "finished"})


# ---------------------------------------------------------------------------------------------------
# Pages and CLI
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("page", ["/", "/run", "/watch", "/play"])
def test_pages_are_served_without_any_cdn(client: TestClient, page: str):
    response = client.get(page)
    assert response.status_code == 200 and "<html" in response.text
    assert "http://" not in response.text and "https://" not in response.text


def test_static_files_need_no_internet():
    static = Path(__file__).parents[1] / "src" / "cartpole" / "web" / "static"
    for path in static.rglob("*"):
        if path.suffix in (".html", ".css") or (path.suffix == ".js" and "vendor" not in path.parts):
            text = path.read_text(encoding="utf-8")
            assert "https://" not in text and "http://" not in text, path
    assert (static / "vendor" / "uPlot.LICENSE").is_file()


def test_serve_binds_this_machine_only_by_default(monkeypatch, tmp_path: Path, capsys):
    """``cartpole serve`` without --host hands uvicorn 127.0.0.1 (other machines cannot reach it)."""
    import uvicorn

    from cartpole.cli.main import main

    served: list[dict[str, Any]] = []
    monkeypatch.setattr(uvicorn, "run", lambda app, **kwargs: served.append(kwargs))
    assert main(["serve", "--runs-dir", str(tmp_path)]) == 0
    assert served and served[0]["host"] == "127.0.0.1" and served[0]["port"] == 8000
    assert "warning" not in capsys.readouterr().out
    assert main(["serve", "--runs-dir", str(tmp_path), "--host", "0.0.0.0"]) == 0
    assert served[1]["host"] == "0.0.0.0" and "other machines can reach" in capsys.readouterr().out


def test_the_web_app_never_tests_an_agents_name():
    """What a policy's scores mean comes from its agent (AgentSpec.score_label, through the API), so a
    new agent (ppo, a2c, ...) shows its own label with no change to the pages or the app."""
    import re

    from cartpole.agents.registry import agent_names

    web = Path(__file__).parents[1] / "src" / "cartpole" / "web"
    sources = [*web.glob("*.py"), *(web / "static").glob("*.js"), *(web / "static").glob("*.html")]
    for agent in agent_names():
        quoted = re.compile(rf"""["'`]{re.escape(agent)}["'`]""")
        for source in sources:
            assert not quoted.search(source.read_text(encoding="utf-8")), f"{source.name} names {agent!r}"


def children_of(pid: int) -> set[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@proc
@pytest.mark.parametrize(
    "stop", [signal.SIGTERM, getattr(signal, "SIGKILL", None)], ids=["sigterm", "kill-9"]
)  # no SIGKILL on Windows, which has no /proc either: skipped there
def test_the_episode_worker_ends_with_the_server(tmp_path, stop):
    """However the server ends, the worker processes that compute Watch episodes end with it."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-m", "cartpole", "serve", "--runs-dir", str(tmp_path), "--port", str(port)]
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        workers: set[int] = set()
        while not workers and time.monotonic() < deadline:
            time.sleep(0.2)
            with suppress(httpx.TransportError):
                httpx.get(f"http://127.0.0.1:{port}/api/info", timeout=5).raise_for_status()
                workers = children_of(server.pid)
        assert workers, "the server started no worker"
    finally:
        server.send_signal(stop)
        server.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(alive(pid) for pid in workers)


@proc
@sessions
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT], ids=["sigterm", "ctrl-c"])
def test_serve_stopped_through_its_process_group_ends_without_a_word_from_its_workers(tmp_path, stop):
    """A service manager's SIGTERM, or a terminal's Ctrl+C, reaches the whole process group: server,
    episode worker and multiprocessing's resource tracker. They end without a leaked-semaphore warning
    and without a worker's traceback."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-m", "cartpole", "serve", "--runs-dir", str(tmp_path), "--port", str(port)]
    server = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 60
        workers: set[int] = set()
        while len(workers) < 2 and time.monotonic() < deadline:  # the resource tracker and a worker
            time.sleep(0.2)
            with suppress(httpx.TransportError):
                httpx.get(f"http://127.0.0.1:{port}/api/info", timeout=5).raise_for_status()
                workers = children_of(server.pid)
        assert len(workers) >= 2, "the server started no worker"
        time.sleep(1.0)  # the worker warms up (imports) meanwhile
    finally:
        os.killpg(server.pid, stop)
        _, err = server.communicate(timeout=60)
    assert "leaked semaphore" not in err and "Traceback" not in err, err
