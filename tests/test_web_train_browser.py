"""The Train page and the run page of a training, in a real headless Chromium (Playwright).

Trainings really start here: each is a ``cartpole train`` process that the app (uvicorn in a thread,
its lifespan run) starts, and stops when the server shuts down. One server and one fresh runs folder
serve the whole module.

Set CARTPOLE_WEB_SCREENSHOTS=DIR to keep screenshots (train.png, run-training.png at 1280x800).
"""

from __future__ import annotations

import json
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"browser tests need Chromium at {CHROMIUM}"),
]
playwright_api = pytest.importorskip("playwright.sync_api", reason="browser tests need playwright (pip)")
uvicorn = pytest.importorskip(
    "uvicorn", reason="the web app needs uvicorn (a dependency of cartpole: reinstall it)"
)

from cartpole.web.app import create_app  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from conftest_browser import DESKTOP, PHONE, Page, Server, free_port, screenshots_dir  # noqa: E402

TOKEN = "train-page-test-token"
TOKEN_MESSAGE = (
    "Starting a training needs the server's token: open the address `cartpole serve` printed (with ?token=)"
)
START_MS = 60_000  # a start answers once its process has named its run folders (~3 s; slow machines more)
FINISH_MS = 180_000


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("train-browser")


@pytest.fixture(scope="module")
def server(runs_dir: Path) -> Iterator[str]:
    port = free_port()
    srv = Server(create_app(runs_dir, token=TOKEN), port)
    yield f"http://127.0.0.1:{port}"
    srv.stop()


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return screenshots_dir(tmp_path_factory)


@pytest.fixture
def desktop(browser: object, server: str) -> Iterator[Page]:
    page = Page(browser, server, DESKTOP, token=TOKEN)
    yield page
    errors = page.errors
    page.close()
    assert errors == [], f"console errors: {errors}"


def trainings(server: str) -> list[dict[str, object]]:
    with urllib.request.urlopen(f"{server}/api/trainings", timeout=30) as answer:
        return json.loads(answer.read())


def run_folders(runs_dir: Path) -> set[str]:
    return {p.name for p in runs_dir.iterdir() if p.is_dir() and p.name != "trainings"}


def open_form(desktop: Page, agent: str = "dqn", path: str = "/train") -> object:
    """The Train page with ``agent`` chosen and its preset's settings shown."""
    page = desktop.goto(path)
    page.locator('#settings-table tr[data-setting="eval_every"]').wait_for()  # type: ignore[attr-defined]
    if page.input_value("#agent") != agent:  # type: ignore[attr-defined]
        page.select_option("#agent", agent)  # type: ignore[attr-defined]
        marker = "population" if agent == "cem" else "lr"
        page.locator(f'#settings-table tr[data-setting="{marker}"]').wait_for()  # type: ignore[attr-defined]
    return page


def wait_training_state(page: object, state: str, timeout: int = 60_000) -> None:
    page.wait_for_function(  # type: ignore[attr-defined]
        f"() => document.querySelector('#training-state').textContent.trim() === '{state}'",
        timeout=timeout,
    )


def wait_cart_moves(page: object) -> None:
    """Until the Now playing step counter has shown three different steps: the cart is animated."""
    page.locator("#now-playing-panel").wait_for()  # type: ignore[attr-defined]
    page.wait_for_function(  # type: ignore[attr-defined]
        """() => {
          const seen = (window.__stepsSeen = window.__stepsSeen || new Set());
          seen.add(document.querySelector('#now-playing-step').textContent.trim());
          return seen.size >= 3;
        }""",
        polling=50,
        timeout=90_000,
    )


def start_dqn_until_budget(desktop: Page) -> object:
    """Start DQN on CartPole-v1 for 20k env steps without stopping at a solve; on its run page."""
    page = open_form(desktop, "dqn")
    page.fill("#budget", "20k")  # type: ignore[attr-defined]
    page.uncheck("#set-stop_when_solved")  # type: ignore[attr-defined]
    assert "stop_when_solved" in page.inner_text("#changed-summary")  # type: ignore[attr-defined]
    page.click("#train")  # type: ignore[attr-defined]
    page.wait_for_url("**/run?name=*", timeout=START_MS)  # type: ignore[attr-defined]
    return page


def test_cem_started_from_the_train_page_is_solved_on_its_run_page(
    desktop: Page, server: str, runs_dir: Path, shots: Path
):
    page = open_form(desktop, "cem")
    assert page.input_value("#env") == "CartPole-v1"  # type: ignore[attr-defined]
    assert page.input_value("#preset") == "default"  # type: ignore[attr-defined]
    assert page.get_attribute("#budget", "placeholder").startswith("50gen")  # type: ignore[attr-defined]
    assert page.locator("#settings-table tr.changed").count() == 0  # type: ignore[attr-defined]
    page.screenshot(path=str(shots / "train.png"), full_page=True)  # type: ignore[attr-defined]
    page.click("#train")  # type: ignore[attr-defined]
    page.wait_for_url("**/run?name=*", timeout=START_MS)  # type: ignore[attr-defined]
    run = page.url.split("name=")[1]  # type: ignore[attr-defined]
    assert run in run_folders(runs_dir)
    verdict = page.locator("#verdict")  # type: ignore[attr-defined]
    verdict.wait_for(timeout=90_000)
    assert "SOLVED" in verdict.inner_text() and "NOT SOLVED" not in verdict.inner_text()
    assert "SOLVED" in page.inner_text("#eval")  # type: ignore[attr-defined]
    wait_training_state(page, "finished")
    assert page.locator("#stop").is_hidden() and page.locator("#resume").is_hidden()  # type: ignore[attr-defined]
    row = next(t for t in trainings(server) if run in t["runs"])  # type: ignore[operator]
    assert page.get_attribute("#train-again", "href") == f"/train?from={row['name']}"  # type: ignore[attr-defined]
    # Finished: Now playing plays the best checkpoint.
    page.wait_for_function(  # type: ignore[attr-defined]
        "() => document.querySelector('#now-playing-checkpoint').textContent.includes('best')"
    )
    page.screenshot(path=str(shots / "run-finished.png"), full_page=True)  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("value", "message"),
    [("-1", "lr must be > 0"), ("abc", "lr='abc' is not a valid float")],
)
def test_a_bad_setting_is_shown_beside_it_and_starts_nothing(
    desktop: Page, server: str, runs_dir: Path, value: str, message: str
):
    before, folders = len(trainings(server)), run_folders(runs_dir)
    page = open_form(desktop, "dqn")
    page.fill("#set-lr", value)  # type: ignore[attr-defined]
    assert page.locator('tr[data-setting="lr"].changed').count() == 1  # type: ignore[attr-defined]
    page.click("#train")  # type: ignore[attr-defined]
    beside = page.locator('tr[data-setting="lr"] .field-error')  # type: ignore[attr-defined]
    beside.wait_for()
    assert message in beside.inner_text()
    assert page.locator('tr[data-setting="lr"]').get_attribute("class").split().count("invalid") == 1  # type: ignore[attr-defined]
    assert "Nothing started" in page.inner_text("#train-status")  # type: ignore[attr-defined]
    assert "/train" in page.url  # type: ignore[attr-defined]
    assert len(trainings(server)) == before and run_folders(runs_dir) == folders
    desktop.errors = [e for e in desktop.errors if "422" not in e]  # the browser logs the 422 itself


def test_malformed_seeds_are_refused_beside_the_field_before_anything_is_sent(desktop: Page, server: str):
    before = len(trainings(server))
    page = open_form(desktop, "cem")
    for text, message in [("0-", "is not a seed or a range"), ("4-2", "reversed"), ("1,1", "more than once")]:
        page.fill("#seeds", text)  # type: ignore[attr-defined]
        page.click("#train")  # type: ignore[attr-defined]
        page.wait_for_function(  # type: ignore[attr-defined]
            f"() => document.querySelector('#error-seeds').textContent.includes({json.dumps(message)})"
        )
    assert len(trainings(server)) == before


def test_without_the_token_train_says_how_to_get_it_and_starts_nothing(
    browser: object, server: str, runs_dir: Path
):
    before, folders = len(trainings(server)), run_folders(runs_dir)
    page = Page(browser, server, DESKTOP)
    try:
        p = page.goto("/train")
        p.locator('#settings-table tr[data-setting="eval_every"]').wait_for()  # type: ignore[attr-defined]
        p.click("#train")  # type: ignore[attr-defined]
        p.locator("#train-error").wait_for()  # type: ignore[attr-defined]
        assert p.inner_text("#train-error").strip() == TOKEN_MESSAGE  # type: ignore[attr-defined]
        assert "/train" in p.url  # type: ignore[attr-defined]
    finally:
        errors = [e for e in page.errors if "401" not in e]  # the browser logs the 401 itself
        page.close()
    assert errors == [], f"console errors: {errors}"
    assert len(trainings(server)) == before and run_folders(runs_dir) == folders


def test_a_run_page_reloaded_while_it_trains_still_follows_it(desktop: Page, server: str):
    page = start_dqn_until_budget(desktop)
    wait_training_state(page, "running")
    page.locator(".uplot canvas").first.wait_for()  # type: ignore[attr-defined]
    page.reload()  # type: ignore[attr-defined]
    wait_training_state(page, "running")
    page.locator(".uplot canvas").first.wait_for()  # type: ignore[attr-defined]
    wait_cart_moves(page)
    assert page.inner_text("#now-playing-checkpoint").strip() == "checkpoint: latest"  # type: ignore[attr-defined]
    page.click("#stop")  # type: ignore[attr-defined]  # leave the CPU to the next test
    wait_training_state(page, "stopped")
    assert page.locator("#resume").is_visible()  # type: ignore[attr-defined]


def test_dqn_from_the_train_page_plays_stops_resumes_and_finishes(desktop: Page, server: str, shots: Path):
    page = start_dqn_until_budget(desktop)
    run = page.url.split("name=")[1]  # type: ignore[attr-defined]
    wait_training_state(page, "running")
    wait_cart_moves(page)
    assert "checkpoint: latest" in page.inner_text("#now-playing-checkpoint")  # type: ignore[attr-defined]
    page.locator(".uplot canvas").first.wait_for()  # type: ignore[attr-defined]
    page.wait_for_function("() => state.rows.length >= 5", timeout=FINISH_MS)  # type: ignore[attr-defined]
    page.screenshot(path=str(shots / "run-training.png"), full_page=True)  # type: ignore[attr-defined]
    page.click("#stop")  # type: ignore[attr-defined]
    wait_training_state(page, "stopped")
    assert page.locator("#stop").is_hidden()  # type: ignore[attr-defined]
    stopped_at = page.evaluate("() => Math.max(0, ...state.rows.map((r) => r.step))")  # type: ignore[attr-defined]
    page.click("#resume")  # type: ignore[attr-defined]
    page.wait_for_function(  # type: ignore[attr-defined]
        "() => ['queued', 'running', 'finished']"
        ".includes(document.querySelector('#training-state').textContent.trim())"
    )
    wait_training_state(page, "finished", timeout=FINISH_MS)
    verdict = page.locator("#verdict")  # type: ignore[attr-defined]
    verdict.wait_for(timeout=30_000)
    assert "SOLVED" in verdict.inner_text()  # SOLVED or NOT SOLVED: the verdict is shown
    # The curve followed the resumed run to its end: rows past the step it stopped at.
    page.wait_for_function(  # type: ignore[attr-defined]
        f"() => state.rows.some((r) => r.step > {stopped_at})", timeout=30_000
    )
    row = next(t for t in trainings(server) if run in t["runs"])  # type: ignore[operator]
    assert row["state"] == "finished"
    assert row["request"]["budget"] == "20k"  # type: ignore[index]
    assert row["request"]["settings"] == {"stop_when_solved": False}  # type: ignore[index]


def start_by_api(server: str, body: dict[str, object]) -> dict[str, object]:
    """POST /api/trainings as a program does (the token as a bearer token)."""
    request = urllib.request.Request(
        f"{server}/api/trainings",
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json", "Authorization": f"Bearer {TOKEN}"},
        method="POST",
    )
    with urllib.request.urlopen(request, timeout=60) as answer:
        return json.loads(answer.read())


def test_train_again_fills_the_form_from_a_training_or_a_run(desktop: Page, server: str):
    settings = {"population": 8, "stop_when_solved": False}
    started = start_by_api(server, {"agent": "cem", "seeds": [3, 4], "budget": "2gen", "settings": settings})
    page = desktop.goto(f"/train?from={started['name']}")
    page.wait_for_function(  # type: ignore[attr-defined]
        "() => document.querySelector('#train-status').textContent.startsWith('Filled from training')"
    )
    assert page.input_value("#agent") == "cem" and page.input_value("#budget") == "2gen"  # type: ignore[attr-defined]
    assert page.input_value("#seeds") == "3,4" and page.input_value("#set-population") == "8"  # type: ignore[attr-defined]
    assert page.locator("#set-stop_when_solved").is_checked() is False  # type: ignore[attr-defined]
    assert page.locator("#settings-table tr.changed").count() == 2  # type: ignore[attr-defined]
    deadline = time.monotonic() + 60
    while not started["runs"]:  # queued behind the other tests' trainings
        assert time.monotonic() < deadline, "the training never started"
        time.sleep(0.5)
        started = next(t for t in trainings(server) if t["name"] == started["name"])
    run = started["runs"][0]  # type: ignore[index]
    page = desktop.goto(f"/run?name={run}")
    page.locator("#train-again").wait_for()  # type: ignore[attr-defined]
    page.wait_for_function(  # type: ignore[attr-defined]
        "() => document.querySelector('#train-again').getAttribute('href').startsWith('/train?from=')"
    )
    page = desktop.goto(f"/train?run={run}")  # from the run's own record: its seed, budget, --set values
    page.wait_for_function(  # type: ignore[attr-defined]
        "() => document.querySelector('#train-status').textContent.startsWith('Filled from run')"
    )
    assert page.input_value("#agent") == "cem" and page.input_value("#seeds") == "3"  # type: ignore[attr-defined]
    assert page.input_value("#budget") == "2gen"  # type: ignore[attr-defined]
    assert page.input_value("#set-population") == "8"  # type: ignore[attr-defined]
    assert page.locator("#set-stop_when_solved").is_checked() is False  # type: ignore[attr-defined]


def test_train_page_fits_a_phone(browser: object, server: str, shots: Path):
    page = Page(browser, server, PHONE, token=TOKEN)
    try:
        p = page.goto("/train")
        p.locator('#settings-table tr[data-setting="eval_every"]').wait_for()  # type: ignore[attr-defined]
        width = p.evaluate("() => document.documentElement.scrollWidth")  # type: ignore[attr-defined]
        assert width <= PHONE["width"], "the Train page scrolls sideways on a phone"
        p.screenshot(path=str(shots / "train_390x844.png"))  # type: ignore[attr-defined]
    finally:
        errors = page.errors
        page.close()
    assert errors == [], f"console errors: {errors}"
