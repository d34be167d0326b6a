"""The web app on a shared machine: only its own hosts and origin, safe headers, no machine paths,
no reads through links, strict WebSocket messages, 414 for huge URLs (FastAPI's test client, plus one
real uvicorn server for what only the server itself does)."""

from __future__ import annotations

import http.client
import json
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urljoin

import pytest

pytest.importorskip("fastapi", reason="the web app needs fastapi (a dependency of cartpole: reinstall it)")
pytest.importorskip("httpx", reason="FastAPI's test client needs httpx")

from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse
from starlette.websockets import WebSocketDisconnect

from cartpole.web.app import create_app
from cartpole.web.live import MAX_PLAY_MESSAGE
from cartpole.web.security import MAX_URL_BYTES, SERVER_OPTIONS

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import make_cem_run

LOCAL = "http://127.0.0.1"


class Client(TestClient):
    """A test client that addresses WebSockets to its own base URL (Starlette's uses "testserver")."""

    def websocket_connect(self, url: str, *args: Any, **kwargs: Any) -> Any:
        base = str(self.base_url).replace("http", "ws", 1)
        return super().websocket_connect(urljoin(base, url), *args, **kwargs)


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("security") / "runs"
    make_cem_run(root)
    return root


@pytest.fixture(scope="module")
def run_name(runs_dir: Path) -> str:
    return next(p.name for p in runs_dir.iterdir())


@pytest.fixture(scope="module")
def client(runs_dir: Path) -> TestClient:
    return Client(create_app(runs_dir.absolute()), base_url=LOCAL)


# ---------------------------------------------------------------------------------------------------
# Hosts and origins
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "[::1]", "127.0.0.1:8000", "LOCALHOST:1"])
def test_local_hosts_are_answered(client: TestClient, host: str):
    assert client.get("/api/info", headers={"host": host}).status_code == 200


@pytest.mark.parametrize("host", ["evil.example", "127.0.0.1.evil.example", "10.0.0.5", "[::2]", ""])
def test_other_hosts_are_refused_on_every_request(client: TestClient, host: str):
    for path in ("/api/info", "/api/runs", "/", "/static/common.js", "/openapi.json"):
        assert client.get(path, headers={"host": host}).status_code == 400, path


def test_hosts_given_to_the_app_are_answered(runs_dir: Path):
    app = create_app(runs_dir, allow_hosts=["0.0.0.0", "lab-box.local", "::1", "10.0.0.5"])
    client = TestClient(app, base_url=LOCAL)
    for host in ("lab-box.local", "10.0.0.5:8000", "[::1]:8000"):
        assert client.get("/api/info", headers={"host": host}).status_code == 200, host
    assert client.get("/api/info", headers={"host": "0.0.0.0"}).status_code == 400


def test_serve_takes_allow_host_more_than_once():
    from cartpole.cli.main import build_parser

    args = build_parser().parse_args(["serve", "--allow-host", "a.local", "--allow-host", "10.1.2.3"])
    assert args.allow_host == ["a.local", "10.1.2.3"]
    assert build_parser().parse_args(["serve"]).allow_host == []


def test_a_websocket_to_another_host_is_refused(runs_dir: Path):
    client = Client(create_app(runs_dir), base_url="http://evil.example")
    with pytest.raises(WebSocketDenialResponse), client.websocket_connect("/ws/play"):
        pass


@pytest.mark.parametrize(
    "origin", ["http://evil.example", "http://127.0.0.1:9999", "null", "https://localhost.evil.example"]
)
def test_a_cross_origin_websocket_is_refused(client: TestClient, origin: str):
    with (
        pytest.raises(WebSocketDisconnect) as closed,
        client.websocket_connect("/ws/play", headers={"origin": origin}),
    ):
        pass
    assert closed.value.code == 1008


@pytest.mark.parametrize("origin", [None, LOCAL])
def test_a_same_origin_or_programs_websocket_is_accepted(client: TestClient, origin: str | None):
    headers = {"origin": origin} if origin else {}
    with client.websocket_connect("/ws/play", headers=headers) as ws:
        ws.send_text('{"type": "reset", "seed": 1}')
        assert ws.receive_json()["step"] == 0


# ---------------------------------------------------------------------------------------------------
# Headers
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "path", ["/", "/watch", "/api/runs", "/static/common.js", "/api/runs/nope", "/nowhere"]
)
def test_every_answer_carries_the_security_headers(client: TestClient, path: str):
    headers = client.get(path).headers
    csp = headers["content-security-policy"]
    assert "default-src 'self'" in csp and "frame-ancestors 'none'" in csp
    assert "unsafe-inline" not in csp and "unsafe-eval" not in csp
    assert headers["x-content-type-options"] == "nosniff"
    assert headers["referrer-policy"] == "no-referrer"


def test_pages_have_no_inline_script_or_style():
    static = Path(__file__).parents[1] / "src" / "cartpole" / "web" / "static"
    for page in static.glob("*.html"):
        text = page.read_text(encoding="utf-8")
        assert "<style" not in text and "style=" not in text, page
        for tag in text.split("<script")[1:]:
            assert tag.lstrip().startswith("src="), f"{page}: inline script"
    for script in static.glob("*.js"):
        assert "style=" not in script.read_text(encoding="utf-8"), f"{script}: inline style attribute"


# ---------------------------------------------------------------------------------------------------
# No machine paths, no reads through links
# ---------------------------------------------------------------------------------------------------


def test_no_absolute_path_of_the_machine_in_answers(client: TestClient, runs_dir: Path, run_name: str):
    where = str(runs_dir.absolute().parent)
    answers = [
        client.get("/api/info"),
        client.get("/api/runs"),
        client.get(f"/api/runs/{run_name}"),
        client.get("/api/runs/no-such-run"),
        client.get(f"/api/runs/{run_name}/checkpoints/nope/episode"),
    ]
    for answer in answers:
        assert where not in answer.text, answer.url
    assert client.get("/api/runs").json()["runs_dir"] == "runs"
    command = client.get(f"/api/runs/{run_name}").json()["config"]["command"]
    assert isinstance(command, list)


def test_a_dangling_checkpoint_link_is_skipped_not_a_500(tmp_path: Path, runs_dir: Path, run_name: str):
    root = tmp_path / "runs"
    shutil.copytree(runs_dir / run_name, root / run_name)
    (root / run_name / "checkpoints" / "ghost.pt").symlink_to(tmp_path / "gone.pt")
    client = Client(create_app(root), base_url=LOCAL)
    detail = client.get(f"/api/runs/{run_name}")
    assert detail.status_code == 200
    assert "ghost" not in [c["name"] for c in detail.json()["checkpoints"]]
    assert client.get(f"/api/runs/{run_name}/checkpoints/ghost/episode").status_code == 404


def test_a_checkpoint_linked_out_of_the_runs_folder_is_neither_listed_nor_read(
    tmp_path: Path, runs_dir: Path, run_name: str
):
    root = tmp_path / "runs"
    shutil.copytree(runs_dir / run_name, root / run_name)
    outside = tmp_path / "elsewhere.pt"
    shutil.copy(runs_dir / run_name / "checkpoints" / "best.pt", outside)
    (root / run_name / "checkpoints" / "borrowed.pt").symlink_to(outside)
    client = Client(create_app(root), base_url=LOCAL)
    listed = client.get(f"/api/runs/{run_name}").json()["checkpoints"]
    assert "borrowed" not in [c["name"] for c in listed] and "best" in [c["name"] for c in listed]
    assert client.get(f"/api/runs/{run_name}/checkpoints/borrowed/episode").status_code == 404


# ---------------------------------------------------------------------------------------------------
# WebSocket messages and URL size
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("action", ["1.0", "true", '"1"', "3", "-1", "null"])
def test_an_action_must_be_an_integer_from_0_to_2(client: TestClient, action: str):
    """(2 is Acrobot's and MountainCar's third action: CartPole answers it with an error message.)"""
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text('{"type": "reset", "seed": 1}')
        ws.receive_json()
        ws.send_text(f'{{"type": "step", "action": {action}}}')
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    assert closed.value.code == 1008 and "action" in closed.value.reason


def test_an_unknown_message_type_gets_an_error_message_and_the_game_goes_on(client: TestClient):
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text('{"type": "teleport"}')
        reply = ws.receive_json()
        assert reply["type"] == "error" and "teleport" in reply["message"] and "reset" in reply["message"]
        ws.send_text('{"type": "reset", "seed": 1}')
        assert ws.receive_json()["type"] == "state"


def test_an_oversized_message_closes_the_socket(client: TestClient):
    with client.websocket_connect("/ws/play") as ws:
        ws.send_text(json.dumps({"type": "reset", "seed": 1, "pad": "x" * MAX_PLAY_MESSAGE}))
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    assert closed.value.code == 1009


def test_a_url_over_the_limit_is_414(client: TestClient, run_name: str):
    response = client.get(f"/api/runs/{run_name}/metrics?offset=0&pad={'x' * MAX_URL_BYTES}")
    assert response.status_code == 414


@pytest.fixture(scope="module")
def server(runs_dir: Path) -> Iterator[int]:
    """uvicorn with the options ``cartpole serve`` uses, on a free port, in a background thread."""
    uvicorn = pytest.importorskip("uvicorn")
    config = uvicorn.Config(
        create_app(runs_dir), host="127.0.0.1", port=0, log_level="warning", **SERVER_OPTIONS
    )
    srv = uvicorn.Server(config)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not srv.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    yield srv.servers[0].sockets[0].getsockname()[1]
    srv.should_exit = True
    thread.join(timeout=10)


def test_the_server_answers_a_270_kb_url_with_414_not_a_reset(server: int):
    connection = http.client.HTTPConnection("127.0.0.1", server, timeout=10)
    connection.request("GET", "/api/runs?pad=" + "x" * 270_000)
    assert connection.getresponse().status == 414
    connection.close()


def test_the_server_refuses_a_foreign_host(server: int):
    connection = http.client.HTTPConnection("127.0.0.1", server, timeout=10)
    connection.request("GET", "/api/runs", headers={"Host": "rebound.evil.example"})
    assert connection.getresponse().status == 400
    connection.close()
