"""The JSON API fuzzed from its own OpenAPI schema (schemathesis): no request gets a 5xx answer."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="the fuzz test needs schemathesis (the test extra)")
from hypothesis import HealthCheck, settings  # noqa: E402

from cartpole.web.app import create_app  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import WebRuns, make_experiment, make_sweep, make_web_runs  # noqa: E402

EXPERIMENT, SWEEP = "cem-vs-dqn", "dqn-2seeds"


@pytest.fixture(scope="module")
def fuzz_runs(tmp_path_factory: pytest.TempPathFactory) -> WebRuns:
    runs = make_web_runs(tmp_path_factory.mktemp("fuzz"))
    make_experiment(runs.root, EXPERIMENT)
    make_sweep(runs.root, SWEEP)
    return runs


@pytest.fixture(scope="module")
def api_schema(fuzz_runs: WebRuns):
    """The schema of an app over a runs folder with real and awkward runs (answering the test
    client's host name, "testserver", as ``--allow-host testserver`` would)."""
    runs = fuzz_runs
    return schemathesis.openapi.from_asgi("/openapi.json", create_app(runs.root, allow_hosts=["testserver"]))


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_request_gets_a_server_error(case, fuzz_runs: WebRuns):
    if case.path_parameters and "checkpoint" in case.path_parameters:
        # Made-up run names only ever reach the 404: fuzz the episode's query on a real checkpoint.
        case.path_parameters.update(name=fuzz_runs.cem, checkpoint="best")
    response = case.call()
    assert response.status_code < 500, f"{case.method} {case.formatted_path} {case.query}: {response.text}"
