"""What the web app's answers keep to, whatever a request says (issue 80's web points): it imports no
module a request names (envs only from the app's own list), names no path of this machine, answers
every refusal in one shape ``{"detail": one line, "field"}``, and takes seeds and integer settings
only as JSON integers."""

from __future__ import annotations

import importlib
import json
import pkgutil
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("fastapi", reason="the web app needs fastapi (a dependency of cartpole: reinstall it)")
pytest.importorskip("httpx", reason="FastAPI's test client needs httpx")

from fastapi.routing import APIWebSocketRoute
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from cartpole.envs import env_info
from cartpole.runs import RunDir
from cartpole.training.request import MAX_SEEDS
from cartpole.web.app import create_app
from cartpole.web.envs import OFFERED_ENVS
from cartpole.web.security import MAX_URL_BYTES

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import LOCAL, LocalClient, make_experiment, make_sweep, make_web_runs

TOKEN = "answers-token"
BEARER = {"Authorization": f"Bearer {TOKEN}"}


# ---------------------------------------------------------------------------------------------------
# Nothing a request names is imported
# ---------------------------------------------------------------------------------------------------


class Probe:
    """A module on sys.path whose import leaves a marker file: had the server imported it, we would know."""

    def __init__(self, folder: Path):
        self.name = f"cartpole_test_probe_module_{uuid.uuid4().hex[:8]}"
        self.marker = folder / f"{self.name}.imported"
        (folder / f"{self.name}.py").write_text(
            f"from pathlib import Path\nPath({str(self.marker)!r}).write_text('imported')\n", "utf-8"
        )
        importlib.invalidate_caches()

    @property
    def env(self) -> str:
        return f"{self.name}:CartPole-v1"

    def imported(self) -> bool:
        return self.marker.exists() or self.name in sys.modules


@pytest.fixture
def probe(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Probe]:
    folder = tmp_path / "modules"
    folder.mkdir()
    monkeypatch.syspath_prepend(str(folder))
    found = Probe(folder)
    yield found
    sys.modules.pop(found.name, None)


SERVERS = {
    "loopback-no-token": {},
    "read-only": {"read_only": True},
    "token-for-reads": {"reads_need_token": True},
}
"""The servers a request may reach: on this machine (no token asked of reads), read-only, bound beyond
this machine (every request sends the token here)."""


def server(tmp_path: Path, kind: str) -> TestClient:
    app = create_app(tmp_path / "runs", token=TOKEN, **SERVERS[kind])
    headers = BEARER if kind == "token-for-reads" else {}
    return LocalClient(app, base_url=LOCAL, headers=headers)


def play_refused(client: TestClient, env: str) -> WebSocketDisconnect:
    with pytest.raises(WebSocketDisconnect) as closed, client.websocket_connect(f"/ws/play?env={env}") as ws:
        ws.receive_json()
    return closed.value


def assert_refusal(answer: Any, status: int, field: str | None) -> str:
    assert answer.status_code == status, answer.text
    body = answer.json()
    assert set(body) == {"detail", "field"} and body["field"] == field, body
    assert isinstance(body["detail"], str) and "\n" not in body["detail"] and body["detail"]
    return body["detail"]


def test_the_probe_notices_an_import(probe: Probe):
    """The control: looking the probe's env up imports its module, and the marker shows it."""
    assert not probe.imported()
    env_info(probe.env)  # importing the module, as Gymnasium's make would
    assert probe.imported()


@pytest.mark.parametrize("kind", list(SERVERS))
def test_play_imports_nothing_the_request_names(tmp_path: Path, probe: Probe, kind: str):
    client = server(tmp_path, kind)
    closed = play_refused(client, probe.env)
    assert closed.code == 1008 and "cannot be played" in closed.reason and "CartPole-v1" in closed.reason
    assert len(closed.reason.encode()) <= 123 and "\n" not in closed.reason
    assert not probe.imported()


@pytest.mark.parametrize("kind", list(SERVERS))
def test_the_training_form_imports_nothing_the_request_names(tmp_path: Path, probe: Probe, kind: str):
    client = server(tmp_path, kind)
    for agent in ("dqn", "nope"):  # the env is checked first, whatever else is wrong
        answer = client.get("/api/training-options", params={"agent": agent, "env_id": probe.env})
        assert "not one the web app trains" in assert_refusal(answer, 422, "env_id")
    assert not probe.imported()


@pytest.mark.parametrize("kind", list(SERVERS))
@pytest.mark.parametrize("dry_run", [True, False], ids=["dry-run", "start"])
def test_a_training_imports_nothing_the_request_names(tmp_path: Path, probe: Probe, kind: str, dry_run: bool):
    client = server(tmp_path, kind)
    body = {"agent": "dqn", "env_id": probe.env, "dry_run": dry_run}
    answer = client.post("/api/trainings", json=body, headers=BEARER)
    if kind == "read-only":
        assert "read-only" in assert_refusal(answer, 403, None)
    else:
        assert "not one the web app trains" in assert_refusal(answer, 422, "env_id")
    without_token = client.post("/api/trainings", json=body, headers={"Authorization": "Bearer wrong"})
    assert without_token.status_code in (401, 403)
    assert not probe.imported()
    assert not (tmp_path / "runs").exists()


def test_this_is_never_imported(tmp_path: Path):
    """``this`` prints the Zen of Python as it is imported: the issue's own example."""
    before = "this" in sys.modules
    for kind in SERVERS:
        client = server(tmp_path, kind)
        assert play_refused(client, "this:CartPole-v1").code == 1008
        assert client.get("/api/training-options", params={"env_id": "this:CartPole-v1"}).status_code == 422
        client.post("/api/trainings", json={"agent": "cem", "env_id": "this:CartPole-v1"}, headers=BEARER)
        client.post(
            "/api/trainings", json={"agent": "cem", "env_id": "this:X", "dry_run": True}, headers=BEARER
        )
    assert ("this" in sys.modules) == before


def test_every_route_that_takes_an_env_is_one_these_tests_cover(tmp_path: Path):
    """The routes and WebSockets that take an env from a request: a new one fails here until it checks
    the env against OFFERED_ENVS and a test above covers it."""
    app = create_app(tmp_path / "runs")
    taking = set()
    for path, operations in app.openapi()["paths"].items():
        for method, operation in operations.items():
            names = {p["name"] for p in operation.get("parameters", [])}
            body = operation.get("requestBody", {}).get("content", {}).get("application/json", {})
            if "$ref" in body.get("schema", {}):
                model = body["schema"]["$ref"].rsplit("/", 1)[-1]
                names |= set(app.openapi()["components"]["schemas"][model]["properties"])
            if any("env" in name and "steps" not in name for name in names):
                taking.add(f"{method.upper()} {path}")
    for route in web_routes():
        params = route.dependant.query_params if isinstance(route, APIWebSocketRoute) else []
        if any("env" in p.name for p in params):
            taking.add(f"WS {route.path}")
    assert taking == {"POST /api/trainings", "GET /api/training-options", "WS /ws/play"}


def web_routes() -> Iterator[Any]:
    """Every route of the web app's routers (each module of cartpole.web with a ``router``)."""
    import cartpole.web

    for module in pkgutil.iter_modules(cartpole.web.__path__):
        router = getattr(importlib.import_module(f"cartpole.web.{module.name}"), "router", None)
        yield from getattr(router, "routes", [])


@pytest.mark.parametrize("env_id", OFFERED_ENVS)
def test_every_env_the_app_offers_can_be_played(tmp_path: Path, env_id: str):
    with server(tmp_path, "loopback-no-token").websocket_connect(f"/ws/play?env={env_id}") as ws:
        ws.send_json({"type": "reset", "seed": 3})
        assert ws.receive_json()["type"] == "state"


# ---------------------------------------------------------------------------------------------------
# No path of this machine
# ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def awkward(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """A runs folder under tmp_path with real runs, the awkward ones, an experiment, a sweep, and a
    training record (as an earlier server left it) full of this machine's paths."""
    base = tmp_path_factory.mktemp("answers")
    runs = make_web_runs(base)
    make_experiment(runs.root, "cem-vs-dqn")
    make_sweep(runs.root, "dqn-2seeds")
    home_preset = str(Path.home() / "presets" / "mine.toml")
    cem = RunDir(runs.root / runs.cem)
    cem.write_config({**cem.config(), "command": ["cartpole", "train", "cem", "--preset", home_preset]})
    record = {
        "name": "CartPole-v1__cem__20240101-000000",
        "request": {"agent": "cem", "env_id": "CartPole-v1", "seeds": [0], "runs_dir": str(runs.root)},
        "command": ["cartpole", "train", "cem", "--runs-dir", str(runs.root.resolve())],
        "created": "2024-01-01T00:00:00+00:00",
        "runs": [],
        "problem": f"cannot read {runs.root}/x/config.json, nor {base}/elsewhere/y.toml, nor {home_preset}",
    }
    (runs.root / "trainings").mkdir()
    (runs.root / "trainings" / f"{record['name']}.json").write_text(json.dumps(record), "utf-8")
    return base, runs


def strings(value: Any) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield str(key)
            yield from strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from strings(item)


def machine_paths(base: Path) -> list[str]:
    home = str(Path.home())
    return [str(base), str(base.resolve()), "/tmp/", *([home] if home.strip("/") else [])]


def every_get_answer(client: TestClient, runs: Any) -> Iterator[tuple[str, Any]]:
    """(url, answer) for every GET route of the schema, its names filled in with every run,
    experiment and sweep there is (and names there are not: their refusals too)."""
    listed = client.get("/api/runs").json()["runs"]
    experiments = client.get("/api/experiments").json()
    names = {
        "name": [row["name"] for row in listed] + ["no-such-run"],
        "checkpoint": ["best", "latest", "nope"],
    }
    for path, operations in client.app.openapi()["paths"].items():
        if "get" not in operations or path.endswith(".png"):
            continue
        if path.startswith("/api/experiments/"):
            values = {"name": [row["name"] for row in experiments["experiments"]] + ["nope"]}
        elif path.startswith("/api/sweeps/"):
            values = {"name": [row["name"] for row in experiments["sweeps"]] + ["nope"]}
        else:
            values = names
        urls = [path]
        for key, choices in values.items():
            urls = [url.replace(f"{{{key}}}", choice) for url in urls for choice in choices]
        for url in urls:
            yield url, client.get(url)
    yield "/api/trainings", client.get("/api/trainings")  # also by run
    yield "/api/runs/x/metrics?offset=-1", client.get("/api/runs/x/metrics?offset=-1")


def test_no_answer_names_a_path_of_this_machine(awkward: tuple[Path, Any]):
    base, runs = awkward
    client = LocalClient(create_app(runs.root.absolute(), token=TOKEN), base_url=LOCAL)
    seen = 0
    for url, answer in every_get_answer(client, runs):
        assert answer.status_code < 500, (url, answer.text)
        texts = list(strings(answer.json())) if "json" in answer.headers["content-type"] else [answer.text]
        for text in texts:
            for where in machine_paths(base):
                assert where not in text, (url, where, text)
        seen += 1
    assert seen > 20
    (training,) = client.get("/api/trainings").json()
    assert training["command"][-2:] == ["--runs-dir", "runs"] and training["request"]["runs_dir"] == "runs"
    assert training["problem"] == "cannot read x/config.json, nor y.toml, nor mine.toml"
    assert client.get(f"/api/runs/{runs.cem}").json()["config"]["command"][-1] == "mine.toml"


def test_the_live_metrics_socket_names_no_path_of_this_machine(awkward: tuple[Path, Any]):
    base, runs = awkward
    client = LocalClient(create_app(runs.root.absolute()), base_url=LOCAL)
    with client.websocket_connect(f"/ws/runs/{runs.cem}/metrics") as ws:
        messages = []
        while not messages or messages[-1]["type"] != "end":
            messages.append(ws.receive_json())
    for text in strings(messages):
        assert not any(where in text for where in machine_paths(base)), text


def test_a_started_training_names_no_path_of_this_machine(tmp_path: Path):
    client = LocalClient(create_app(tmp_path / "runs", token=TOKEN), base_url=LOCAL)
    answer = client.post(
        "/api/trainings", json={"agent": "cem", "seeds": [2], "dry_run": True}, headers=BEARER
    )
    assert answer.json()["command"] == ["cartpole", "train", "cem", "--seed", "2", "--runs-dir", "runs"]
    relative = LocalClient(create_app(Path("my-runs"), token=TOKEN), base_url=LOCAL)
    answer = relative.post("/api/trainings", json={"agent": "cem", "dry_run": True}, headers=BEARER)
    assert answer.json()["command"] == ["cartpole", "train", "cem", "--runs-dir", "my-runs"]  # as given


# ---------------------------------------------------------------------------------------------------
# Every refusal in one shape
# ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> TestClient:
    return LocalClient(create_app(tmp_path_factory.mktemp("shape") / "runs", token=TOKEN), base_url=LOCAL)


def start(client: TestClient, **body: Any) -> Any:
    return client.post("/api/trainings", json={"agent": "dqn", "dry_run": True, **body}, headers=BEARER)


def test_too_many_seeds_is_one_line_about_seeds(client: TestClient):
    detail = assert_refusal(start(client, seeds=list(range(5000))), 422, "seeds")
    assert detail == f"seeds: at most {MAX_SEEDS} seeds, got 5000"


def test_an_object_as_a_setting_is_one_line_naming_the_setting(client: TestClient):
    detail = assert_refusal(start(client, settings={"lr": {"value": 0.1}}), 422, "lr")
    assert detail.startswith("settings.lr must be ") and detail.endswith("got an object")


def test_an_unknown_field_is_one_line_naming_it(client: TestClient):
    assert assert_refusal(start(client, foo=1), 422, None) == 'unknown field "foo"'


def test_an_oversized_network_is_reported_against_hidden_sizes_not_seeds(client: TestClient):
    answer = start(client, settings={"lr": 0.001, "hidden_sizes": [1_000_000, 1_000_000]})
    assert "memory" in assert_refusal(answer, 422, "hidden_sizes")


def test_too_many_seeds_for_the_memory_is_still_about_seeds(client: TestClient):
    """4096 DQN seeds on pixels (each a replay of frames, about 600 MB): one fits, they do not."""
    seeds, pixels = list(range(MAX_SEEDS)), "cartpole/CartPolePixels-v1"
    answer = start(client, env_id=pixels, seeds=seeds, settings={"lr": 0.0005})
    assert "memory" in assert_refusal(answer, 422, "seeds")


REFUSALS = [
    ("GET", "/api/nowhere", {}, 404),
    ("PUT", "/api/runs", {"headers": BEARER}, 405),
    ("GET", "/api/runs/no-such-run", {}, 404),
    ("GET", "/api/runs/x/metrics?offset=-1", {}, 422),
    ("GET", "/api/runs/x/metrics?offset=abc", {}, 422),
    ("GET", "/api/training-options?agent=nope", {}, 422),
    ("GET", "/api/training-options?agent=" + "x" * 300, {}, 422),
    ("GET", "/api/experiments/nope", {}, 404),
    ("GET", "/api/sweeps/nope/best.toml", {}, 404),
    ("POST", "/api/trainings", {"json": {"agent": "dqn"}}, 401),
    (
        "POST",
        "/api/trainings",
        {"json": {"agent": "dqn"}, "headers": {**BEARER, "Origin": "http://evil"}},
        403,
    ),
    (
        "POST",
        "/api/trainings",
        {"content": b"{nope", "headers": {**BEARER, "content-type": "application/json"}},
        422,
    ),
    ("POST", "/api/trainings", {"json": [1, 2], "headers": BEARER}, 422),
    ("POST", "/api/trainings", {"json": {}, "headers": BEARER}, 422),
    ("POST", "/api/trainings/nope/stop", {"headers": BEARER}, 404),
    ("POST", "/api/trainings/" + "x" * 300 + "/stop", {"headers": BEARER}, 422),
    ("GET", "/api/runs?pad=" + "x" * MAX_URL_BYTES, {}, 414),
    ("GET", "/api/runs", {"headers": {"host": "evil.example"}}, 400),
    ("GET", "/?token=wrong", {}, 401),
]


@pytest.mark.parametrize(
    ("method", "url", "options", "status"), REFUSALS, ids=[f"{r[3]}-{r[1][:40]}" for r in REFUSALS]
)
def test_every_refusal_has_one_shape(client: TestClient, method: str, url: str, options: dict, status: int):
    answer = client.request(method, url, follow_redirects=False, **options)
    assert answer.status_code == status, answer.text
    body = answer.json()
    assert set(body) == {"detail", "field"}, body
    assert isinstance(body["detail"], str) and body["detail"] and "\n" not in body["detail"]
    assert body["field"] is None or isinstance(body["field"], str)


def test_a_query_refusal_names_its_parameter(client: TestClient):
    detail = assert_refusal(client.get("/api/runs/x/metrics?offset=-1"), 422, "offset")
    assert detail == "offset must be >= 0, got -1"


def test_a_websocket_query_that_does_not_validate_closes_with_one_line(client: TestClient):
    closed = play_refused(client, "x" * 100)
    assert closed.code == 1008 and closed.reason == "env: at most 64 characters, got 100"


# ---------------------------------------------------------------------------------------------------
# Seeds and integer settings: JSON integers only
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seeds", [["1"], [1.0], [True], [0, 2.5], True, "0-4"])
def test_seeds_are_json_integers(client: TestClient, seeds: Any):
    detail = assert_refusal(start(client, seeds=seeds), 422, "seeds")
    assert detail.startswith("seeds")


@pytest.mark.parametrize(
    ("agent", "settings", "field", "detail"),
    [
        ("dqn", {"batch_size": 64.0}, "batch_size", "batch_size must be an integer, got 64.0"),
        ("dqn", {"batch_size": "64"}, "batch_size", 'batch_size must be an integer, got "64"'),
        ("ppo", {"num_envs": 8.0}, "num_envs", "num_envs must be an integer, got 8.0"),
        ("dqn", {"eval_every": 1e4}, "eval_every", "eval_every must be an integer, got 10000.0"),
        (
            "dqn",
            {"hidden_sizes": [64.0, 64]},
            "hidden_sizes",
            "hidden_sizes must be a list of integers, got [64.0, 64]",
        ),
        ("dqn", {"double_dqn": "false"}, "double_dqn", 'double_dqn must be true or false, got "false"'),
        ("dqn", {"lr": "0.001"}, "lr", 'lr must be a number, got "0.001"'),
        (
            "dqn",
            {"max_grad_norm": "none"},
            "max_grad_norm",
            'max_grad_norm must be a number or null, got "none"',
        ),
    ],
)
def test_a_setting_takes_a_value_of_its_own_json_type(
    client: TestClient, agent: str, settings: dict, field: str, detail: str
):
    assert assert_refusal(start(client, agent=agent, settings=settings), 422, field) == detail


def test_a_bool_for_an_integer_setting_gets_the_clis_message(client: TestClient):
    detail = assert_refusal(start(client, settings={"batch_size": True}), 422, "batch_size")
    assert detail == "batch_size='true' is not a valid int (a whole number is needed)"


def test_a_budget_is_text(client: TestClient):
    assert assert_refusal(start(client, budget=50000), 422, "budget") == "budget must be text, got 50000"


def test_floats_stay_floats_and_integers_are_taken(client: TestClient):
    answer = start(
        client, seeds=[0, 1], settings={"lr": 1, "tau": 0.005, "batch_size": 32, "max_grad_norm": None}
    )
    assert answer.status_code == 200, answer.text
    assert "lr=1" in " ".join(answer.json()["command"]) and "batch_size=32" in " ".join(
        answer.json()["command"]
    )
