"""The JSON API fuzzed from its own OpenAPI schema (schemathesis): no request gets a 5xx answer.

Each operation of the schema is one pytest case; Hypothesis draws requests from schemathesis's
strategy for it (valid and invalid ones). Only schemathesis's public schema API is used, not its pytest
plugin: that plugin's fixture-based schemas read pytest internals (`request.node._nodeid`, gone in
pytest 9.2), and a plain `@given` works with every pytest.

Each request that would change something (a POST) is sent twice: without the token, where it must get
401 or 403, and with it, made a dry run (``"dry_run": true`` in a JSON object body), so that fuzzing
starts no training.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="the fuzz test needs schemathesis (the test extra)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from cartpole.web.app import create_app  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import WebRuns, make_experiment, make_sweep, make_web_runs  # noqa: E402

EXPERIMENT, SWEEP = "cem-vs-dqn", "dqn-2seeds"
TOKEN = "fuzz-token"


def operation_labels() -> list[str]:
    """Labels such as `GET /api/runs` of the app's operations (the schema does not depend on the runs)."""
    schema = schemathesis.openapi.from_dict(create_app(Path("/nonexistent-runs")).openapi())
    return sorted(result.ok().label for result in schema.get_all_operations())


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
    app = create_app(fuzz_runs.root, allow_hosts=["testserver"], token=TOKEN)
    return schemathesis.openapi.from_asgi("/openapi.json", app)


def test_the_schema_has_operations_to_fuzz():
    assert len(operation_labels()) >= 5


@pytest.mark.parametrize("label", operation_labels())
def test_no_request_gets_a_server_error(label: str, api_schema, fuzz_runs: WebRuns):
    method, path = label.split(" ", 1)
    operation = api_schema[path][method]
    modes = [schemathesis.GenerationMode.POSITIVE, schemathesis.GenerationMode.NEGATIVE]

    @given(case=st.one_of(*(operation.as_strategy(mode) for mode in modes)))
    @settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    def no_server_error(case) -> None:
        if case.path_parameters and "checkpoint" in case.path_parameters:
            # Made-up run names only ever reach the 404: fuzz the episode's query on a real checkpoint.
            case.path_parameters.update(name=fuzz_runs.cem, checkpoint="best")
        if method == "POST":
            refused = case.call()
            assert refused.status_code in (401, 403), f"{label} without the token: {refused.status_code}"
            if isinstance(case.body, dict):
                case.body["dry_run"] = True
            response = case.call(headers={"Authorization": f"Bearer {TOKEN}"})
        else:
            response = case.call()
        assert response.status_code < 500, f"{label} {case.path_parameters} {case.query}: {response.text}"

    no_server_error()
    assert not (fuzz_runs.root / "trainings").exists(), "fuzzing started a training"
