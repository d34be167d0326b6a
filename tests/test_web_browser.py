"""The web app in a real headless Chromium (Playwright), served by uvicorn on 127.0.0.1.

Set CARTPOLE_WEB_SCREENSHOTS=DIR to keep screenshots of every page at 1280x800 and 390x844.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
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
from conftest_web import (  # noqa: E402
    WebRuns,
    make_cem_run,
    make_experiment,
    make_pixel_run,
    make_reported_experiment,
    make_single_generation_run,
    make_sweep,
    make_web_runs,
)

EXPERIMENT = "cem-vs-dqn"
RLIABLE = "cem-vs-dqn-finals"
SWEEP = "dqn-2seeds"


@pytest.fixture(scope="module")
def web_runs(tmp_path_factory: pytest.TempPathFactory) -> WebRuns:
    runs = make_web_runs(tmp_path_factory.mktemp("browser"))
    make_experiment(runs.root, EXPERIMENT)
    make_reported_experiment(runs.root, RLIABLE)
    make_sweep(runs.root, SWEEP)
    return runs


@pytest.fixture(scope="module")
def one_generation(web_runs: WebRuns) -> str:
    return make_single_generation_run(web_runs.root, web_runs.root / web_runs.cem)


@pytest.fixture(scope="module")
def server(web_runs: WebRuns) -> Iterator[str]:
    """uvicorn serving the app on a free port, in a background thread."""
    port = free_port()
    srv = Server(create_app(web_runs.root), port)
    yield f"http://127.0.0.1:{port}"
    srv.stop()


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return screenshots_dir(tmp_path_factory)


@pytest.fixture
def desktop(browser: object, server: str) -> Iterator[Page]:
    page = Page(browser, server, DESKTOP)
    yield page
    errors = page.errors
    page.close()
    assert errors == [], f"console errors: {errors}"


def watch_path(run: str, seed: int = 3) -> str:
    return f"/watch?run={run}&checkpoint=best&seed={seed}"


def test_runs_page_lists_the_run(desktop: Page, web_runs: WebRuns):
    page = desktop.goto("/")
    row = page.locator(f'tr[data-run="{web_runs.cem}"]')
    row.wait_for()
    assert "cem" in row.inner_text() and "solved" in row.inner_text()
    assert re.search(r"mean \d+\.\d >= 475 over 100 episodes, CartPole-v1", row.inner_text())
    corrupt = page.locator(f'tr[data-run="{web_runs.corrupt}"]').inner_text()
    assert "unreadable" in corrupt


def test_runs_page_says_how_to_make_a_run_when_there_is_none(desktop: Page):
    desktop.page.route(
        "**/api/runs", lambda route: route.fulfill(json={"runs_dir": "runs", "runs": []}, status=200)
    )
    page = desktop.goto("/")
    page.get_by_text("No runs yet").wait_for()
    assert "cartpole train cem" in page.inner_text("main")


def test_run_page_shows_curve_checkpoints_and_config(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(f"/run?name={web_runs.cem}")
    page.locator(".uplot canvas").first.wait_for()
    page.get_by_text("SOLVED: mean").wait_for()
    assert page.locator("#checkpoint-list a", has_text="Watch").count() >= 2
    assert "population" in page.inner_text("#config")


def test_run_page_of_an_undrawn_env_says_which_envs_watch_draws(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(f"/run?name={web_runs.other_env}")
    page.get_by_text("Watch draws CartPole, Acrobot-v1 and MountainCar-v0").wait_for()
    assert page.locator("#checkpoint-list a", has_text="Watch").count() == 0


def step_counter(page: object) -> tuple[int, int]:
    done, total = page.inner_text("#step").split("/")  # type: ignore[attr-defined]
    return int(done), int(total)


def test_watch_page_animates_to_the_episode_end(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function(
        "() => document.querySelector('#step').textContent.trim().startsWith('0 /') === false"
    )
    page.select_option("#speed", "4")
    first = page.locator("#stage").screenshot()
    page.wait_for_timeout(300)
    second = page.locator("#stage").screenshot()
    assert first != second  # the cart and pole move
    total = step_counter(page)[1]
    assert total > 50
    page.wait_for_function(
        f"() => document.querySelector('#step').textContent.trim() === '{total} / {total}'", timeout=15_000
    )
    assert page.inner_text("#play-pause").endswith("Play")  # stops at the end


def test_nudging_changes_the_trajectory(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function("() => watch.episode !== null && watch.frame > 30")
    page.click("#play-pause")  # pause, so the nudge lands at a known step
    before = page.evaluate("() => watch.episode.states")
    step = page.evaluate("() => Math.floor(watch.frame)")
    page.fill("#nudge-size", "3")
    page.click("#nudge-right")
    page.wait_for_function("() => watch.episode.nudges.length === 1")
    after = page.evaluate("() => watch.episode.states")
    assert after[:step] == before[:step]
    assert after[step + 1] != before[step + 1]
    assert page.evaluate("() => watch.episode.nudges[0].step") == step


def test_play_page_moves_the_cart_the_way_pressed_and_ends_when_the_pole_falls(desktop: Page):
    page = desktop.goto("/play")
    page.get_by_text("Press ← or → to start").wait_for()
    page.select_option("#speed", "2")
    for key, sign in (("ArrowRight", 1), ("ArrowLeft", -1)):
        start = page.evaluate("() => game.state[0]")
        page.keyboard.down(key)
        page.wait_for_function(f"() => ({sign}) * (game.state[0] - ({start})) > 0.02")
        page.wait_for_function("() => game.phase === 'over'", timeout=10_000)
        page.keyboard.up(key)
        title = page.inner_text("#overlay-title")
        assert "pole fell" in title or "off the track" in title
        assert int(page.inner_text("#score")) > 0
        assert int(page.inner_text("#best")) > 0
        link = page.get_attribute("#compare-link", "href")
        assert link and f"seed={page.evaluate('() => game.seed')}" in link
        page.click("#again")
        page.get_by_text("Press ← or → to start").wait_for()


def test_compare_link_watches_the_agent_from_the_humans_start(desktop: Page):
    no_runs_yet = {"runs_dir": "runs", "runs": []}
    desktop.page.route("**/api/runs", lambda route: route.fulfill(json=no_runs_yet, status=200))
    page = desktop.goto("/play")
    page.get_by_text("Press ← or → to start").wait_for()
    seed = page.evaluate("() => game.seed")
    page.select_option("#speed", "2")
    page.keyboard.down("ArrowRight")
    page.wait_for_function("() => game.phase === 'over'", timeout=10_000)
    page.keyboard.up("ArrowRight")
    page.unroute("**/api/runs")  # the agents arrive after the game ended: the link appears then
    human_start = page.evaluate("() => game.seed")
    assert human_start == seed
    page.click("#compare-link")
    page.wait_for_url(re.compile(rf".*/watch\?.*seed={seed}"))
    page.wait_for_function("() => watch.episode !== null")
    assert page.evaluate("() => watch.episode.seed") == seed


@pytest.mark.parametrize("viewport", [DESKTOP, PHONE], ids=["1280x800", "390x844"])
def test_every_page_renders_without_console_errors(
    browser: object, server: str, web_runs: WebRuns, shots: Path, viewport: dict[str, int]
):
    page = Page(browser, server, viewport)
    pages = {
        "runs": "/",
        "run": f"/run?name={web_runs.cem}",
        "watch": watch_path(web_runs.cem),
        "play": "/play",
        "run-other-env": f"/run?name={web_runs.other_env}",
        "experiments": "/experiments",
        "experiment": f"/experiment?name={EXPERIMENT}",
        "sweep": f"/sweep?name={SWEEP}",
    }
    try:
        for name, path in pages.items():
            p = page.goto(path)
            p.wait_for_load_state("networkidle")  # type: ignore[attr-defined]
            p.wait_for_timeout(400)  # type: ignore[attr-defined]
            width = p.evaluate("() => document.documentElement.scrollWidth")  # type: ignore[attr-defined]
            assert width <= viewport["width"], f"{name} scrolls sideways at {viewport}"
            p.screenshot(
                path=str(shots / f"{name}_{viewport['width']}x{viewport['height']}.png"), full_page=True
            )  # type: ignore[attr-defined]
    finally:
        errors = page.errors
        page.close()
    assert errors == [], f"console errors: {errors}"


def test_runs_page_recovers_after_the_server_restarts(browser: object, web_runs: WebRuns):
    port = free_port()
    srv = Server(create_app(web_runs.root), port)
    page = Page(browser, f"http://127.0.0.1:{port}", DESKTOP)
    try:
        p = page.goto("/")
        p.locator(f'tr[data-run="{web_runs.cem}"]').wait_for()  # type: ignore[attr-defined]
        srv.stop()
        p.locator("#runs-error").wait_for(timeout=15_000)  # type: ignore[attr-defined]
        assert "Trying again" in p.inner_text("#runs-error")  # type: ignore[attr-defined]
        srv = Server(create_app(web_runs.root), port)
        p.locator(f'tr[data-run="{web_runs.cem}"]').wait_for(timeout=30_000)  # type: ignore[attr-defined]
        assert p.locator("#runs-error").count() == 0  # type: ignore[attr-defined]
    finally:
        page.close()
        srv.stop()


def test_watch_page_refuses_a_negative_seed_by_name(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function("() => watch.episode !== null")
    page.fill("#seed", "-5")
    page.click("#seed-go")
    page.get_by_text("seed must be >= 0").wait_for()
    assert page.evaluate("() => watch.seed") == 3  # unchanged, not clamped to 0


def test_watch_address_with_a_negative_seed_says_which_field(browser: object, server: str, web_runs: WebRuns):
    page = Page(browser, server, DESKTOP)
    try:
        p = page.goto(watch_path(web_runs.cem, seed=-5))
        p.get_by_text("seed must be >= 0").wait_for()  # type: ignore[attr-defined]
    finally:
        page.close()


def test_watch_page_without_a_run_says_so(desktop: Page):
    page = desktop.goto("/watch")
    page.get_by_text("No run named in the address").wait_for()
    assert "Watch best of" not in page.inner_text("#title")


def test_a_nudge_after_the_episode_ended_is_not_counted(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function("() => watch.episode !== null")
    page.evaluate("() => { watch.frame = watch.episode.length; setPlaying(false); }")
    page.click("#nudge-right")
    page.get_by_text("The episode is over").wait_for()
    assert page.evaluate("() => watch.nudges.length") == 0


def test_play_page_explains_how_to_get_an_agent_and_notices_new_runs(browser: object, tmp_path: Path):
    runs_dir = tmp_path / "empty-runs"
    port = free_port()
    srv = Server(create_app(runs_dir), port)
    page = Page(browser, f"http://127.0.0.1:{port}", DESKTOP)
    try:
        p = page.goto("/play")
        p.locator("#no-runs").wait_for()  # type: ignore[attr-defined]
        text = p.inner_text("#no-runs")  # type: ignore[attr-defined]
        assert "cartpole train cem --runs-dir empty-runs" in text
        assert "cartpole serve --runs-dir empty-runs" in text
        name = make_cem_run(runs_dir)
        p.locator(f'#agent-select option[value="{name}"]').wait_for(state="attached", timeout=30_000)  # type: ignore[attr-defined]
        assert p.locator("#no-runs").is_hidden()  # type: ignore[attr-defined]
    finally:
        page.close()
        srv.stop()


# ---------------------------------------------------------------------------------------------------
# Experiments and sweeps
# ---------------------------------------------------------------------------------------------------


def test_experiments_page_lists_comparisons_and_sweeps(desktop: Page):
    page = desktop.goto("/experiments")
    row = page.locator(f'tr[data-experiment="{EXPERIMENT}"]')
    row.wait_for()
    assert "random-search:tutorial" in row.inner_text() and "CartPole-v1" in row.inner_text()
    sweep = page.locator(f'tr[data-sweep="{SWEEP}"]')
    assert "dqn" in sweep.inner_text() and "best.toml" in sweep.inner_text()
    assert page.locator("header nav a.active").inner_text() == "Experiments"
    row.locator("a").first.click()
    page.wait_for_url(re.compile(rf".*/experiment\?name={EXPERIMENT}$"))
    page.locator("#report-table").wait_for()


def test_experiment_page_shows_counts_cis_and_the_curves(desktop: Page):
    page = desktop.goto(f"/experiment?name={EXPERIMENT}")
    page.locator("#report-table").wait_for()
    assert page.locator("#report-table tbody tr").count() == 3
    cem = page.inner_text('tr[data-entry="cem"]')
    assert "10 / 10" in cem and "33,014\nCI [24,506, 49,99" in cem and "498.6\nCI [491.7, 500.0]" in cem
    random_search = page.inner_text('tr[data-entry="random-search:tutorial"]')
    assert "5 / 10" in random_search and "≥" in random_search  # a median that unsolved runs hold up
    assert "CartPole-v1 · 3 entries × 10 seeds" in page.inner_text("#subtitle")
    for figure in ("curves", "solve_steps"):
        image = page.locator(f"#figure-{figure}")
        image.wait_for()
        page.wait_for_function(f"() => document.querySelector('#figure-{figure}').naturalWidth > 100")
    assert "cartpole compare cem dqn" in page.inner_text("#made")
    assert f"--runs-dir runs/experiments/{EXPERIMENT}/runs" in page.inner_text("#made")


def test_experiment_page_shows_the_performance_profile_and_the_probability_of_improvement(desktop: Page):
    page = desktop.goto(f"/experiment?name={RLIABLE}")
    page.locator("#report-table").wait_for()
    for figure in ("performance_profile", "improvement"):
        page.locator(f"#figure-{figure}").wait_for()
        page.wait_for_function(f"() => document.querySelector('#figure-{figure}').naturalWidth > 100")
    captions = page.inner_text("#figures")
    assert "Performance profile (rliable)" in captions and "Probability of improvement (rliable)" in captions


def test_sweep_page_shows_trials_best_preset_and_dashboard(desktop: Page):
    page = desktop.goto(f"/sweep?name={SWEEP}")
    page.locator("#trials-table").wait_for()
    assert page.locator("#trials-table tbody tr").count() == 4
    best = page.inner_text('tr[data-trial="2"]')
    assert "best" in best and "19,800" in best and "128" in best and "complete" in best
    assert "pruned" in page.inner_text('tr[data-trial="1"]')
    assert "failed" not in page.inner_text("#counts") and "1 fail" in page.inner_text("#counts")
    assert "lr = 0.002" in page.inner_text("#best-toml")
    assert f"optuna-dashboard runs/sweeps/{SWEEP}/journal.log" in page.inner_text("#dashboard-command")
    assert f"cartpole train dqn --preset runs/sweeps/{SWEEP}/best.toml" in page.inner_text("#best")
    response = page.request.get(desktop.base + page.get_attribute("#best-link", "href"))
    assert response.status == 200 and "batch_size = 128" in response.text()


@pytest.mark.parametrize("path", ["/experiment?name=nope", "/sweep?name=nope", "/sweep?name=..%2Fx"])
def test_an_unknown_experiment_or_sweep_says_so(desktop: Page, path: str):
    page = desktop.goto(path)
    page.locator("#load-error").wait_for()
    text = page.inner_text("#load-error")
    assert "no sweep named" in text.lower() or "no experiment named" in text.lower()
    assert "Trying again" not in text
    desktop.errors = [e for e in desktop.errors if "404" not in e]  # the browser logs the 404 itself


def test_experiments_page_says_how_to_make_one_when_there_is_none(desktop: Page):
    desktop.page.route(
        "**/api/experiments", lambda route: route.fulfill(json={"experiments": [], "sweeps": []}, status=200)
    )
    page = desktop.goto("/experiments")
    page.locator("#no-experiments").wait_for()
    assert "cartpole compare cem dqn --seeds 5" in page.inner_text("#no-experiments")
    assert "cartpole sweep dqn" in page.inner_text("#no-sweeps")


@pytest.mark.parametrize(
    "path, ready",
    [
        ("/experiments", f'tr[data-experiment="{EXPERIMENT}"]'),
        (f"/sweep?name={SWEEP}", '#trials-table tr[data-trial="2"]'),
    ],
    ids=["experiments", "sweep"],
)
def test_experiment_pages_recover_after_the_server_restarts(
    browser: object, web_runs: WebRuns, path: str, ready: str
):
    port = free_port()
    srv = Server(create_app(web_runs.root), port)
    page = Page(browser, f"http://127.0.0.1:{port}", DESKTOP)
    try:
        p = page.goto(path)
        p.locator(ready).wait_for()  # type: ignore[attr-defined]
        srv.stop()
        p.locator("#load-error").wait_for(timeout=20_000)  # type: ignore[attr-defined]
        assert "Trying again" in p.inner_text("#load-error")  # type: ignore[attr-defined]
        srv = Server(create_app(web_runs.root), port)
        p.locator("#load-error").wait_for(state="detached", timeout=40_000)  # type: ignore[attr-defined]
        assert p.locator(ready).count() == 1  # type: ignore[attr-defined]
    finally:
        page.close()
        srv.stop()


# ---------------------------------------------------------------------------------------------------
# Pages that tell the truth
# ---------------------------------------------------------------------------------------------------


def test_watch_shows_what_the_agent_calls_its_scores(desktop: Page, web_runs: WebRuns):
    """A policy-gradient agent's scores are action probabilities: the page shows the API's score_label
    and the values, whatever the agent is called."""

    def as_probabilities(route: object) -> None:
        body = route.fetch().json()  # type: ignore[attr-defined]
        body["agent"] = "some-new-agent"
        body["score_label"] = "action probability"
        body["scores"] = [[0.25, 0.75] if a == 1 else [0.9, 0.1] for a in body["actions"]]
        route.fulfill(json=body)  # type: ignore[attr-defined]

    desktop.page.route("**/episode?*", as_probabilities)
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function("() => watch.episode !== null")
    page.click("#play-pause")
    page.locator("#prefs .pref").first.wait_for()
    text = page.inner_text("#prefs")
    assert "action probability" in text
    assert "0.75" in text or "0.90" in text


def test_a_run_solved_in_one_generation_has_a_readable_chart(desktop: Page, one_generation: str):
    page = desktop.goto(f"/run?name={one_generation}")
    page.locator(".uplot canvas").first.wait_for()
    page.wait_for_function("() => state.plot !== null && state.rows.length === 3")
    low, high = page.evaluate("() => [state.plot.scales.x.min, state.plot.scales.x.max]")
    assert low < 5726 < high  # the one step sits inside a real range, not a zero-width one
    assert page.evaluate("() => state.plot.data[2].every((v) => v === null)")  # no average of 1 point
    points = page.evaluate("() => state.plot.data[1].filter((v) => v !== null).length")
    assert points == 1


def test_the_moving_average_waits_for_a_full_window(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(f"/run?name={web_runs.cem}")
    page.wait_for_function("() => state.plot !== null && state.rows.length > 0")
    returns = page.evaluate("() => state.plot.data[1].filter((v) => v !== null).length")
    averages = page.evaluate("() => state.plot.data[2].filter((v) => v !== null).length")
    assert averages == max(0, returns - 19)


def test_the_config_panel_shows_one_budget(desktop: Page, one_generation: str):
    page = desktop.goto(f"/run?name={one_generation}")
    page.locator('#config tr[data-key="budget"]').wait_for()
    config = page.inner_text("#config")
    assert "20,000 env steps" in page.inner_text('#config tr[data-key="budget"]')
    assert "50gen" not in config  # the preset's budget, which --budget replaced
    assert page.inner_text("#config table").count("budget") == 1


def test_live_pages_show_a_crashed_run_as_crashed(browser: object, web_runs: WebRuns, tmp_path: Path):
    import socket as sockets
    import subprocess

    from cartpole.runs import RunDir

    runs_dir = tmp_path / "runs"
    run = RunDir.create(runs_dir, "CartPole-v1", "cem", 5)
    run.write_config(RunDir(web_runs.root / web_runs.cem).config() | {"seed": 5})
    alive = {"state": "running", "env_steps": 100, "episodes": 2, "pid": os.getpid()}
    alive |= {"host": sockets.gethostname(), "heartbeat": time.time() + 600}
    run.write_status(alive)
    run.append_metrics([{"step": 100, "episode": 2, "time": 0.5, "train/mean_return": 20.0}])
    port = free_port()
    srv = Server(create_app(runs_dir), port)
    runs_page = Page(browser, f"http://127.0.0.1:{port}", DESKTOP)
    run_page = Page(browser, f"http://127.0.0.1:{port}", DESKTOP)
    try:
        listing = runs_page.goto("/")
        detail = run_page.goto(f"/run?name={run.name}")
        listing.locator(f'tr[data-run="{run.name}"] .badge.running').wait_for()  # type: ignore[attr-defined]
        detail.locator("#subtitle .badge.running").wait_for()  # type: ignore[attr-defined]
        gone = subprocess.Popen(["true"])
        gone.wait()
        run.write_status(alive | {"pid": gone.pid})  # the training process is gone
        listing.locator(f'tr[data-run="{run.name}"] .badge.crashed').wait_for(timeout=15_000)  # type: ignore[attr-defined]
        detail.locator("#subtitle .badge.crashed").wait_for(timeout=15_000)  # type: ignore[attr-defined]
        assert "training" not in listing.inner_text(f'tr[data-run="{run.name}"]')  # type: ignore[attr-defined]
    finally:
        runs_page.close()
        run_page.close()
        srv.stop()


# ---------------------------------------------------------------------------------------------------
# Acrobot-v1 and MountainCar-v0 on Watch and Play
# ---------------------------------------------------------------------------------------------------

SCENE_ENVS = {"acrobot": "Acrobot-v1", "mountaincar": "MountainCar-v0"}
SCENE_READOUTS = {"acrobot": ("link angles", "tip height"), "mountaincar": ("position", "velocity")}

CANVAS_PIXELS = """(canvas) => {
  const { width, height } = canvas;
  const data = canvas.getContext("2d").getImageData(0, 0, width, height).data;
  const colours = new Set();
  let transparent = 0, ink = 0, inkX = 0, goal = 0;
  for (let i = 0; i < data.length; i += 4) {
    const [r, g, b, a] = [data[i], data[i + 1], data[i + 2], data[i + 3]];
    if (a === 0) transparent++;
    colours.add((r << 16) | (g << 8) | b);
    if (r === 0x26 && g === 0x3a && b === 0x7a) { ink++; inkX += (i / 4) % width; }  // link / car
    if (r === 0x17 && g === 0x80 && b === 0x4a) goal++;  // the goal line / the flag
  }
  return { width, height, transparent, colours: colours.size, ink, inkX: ink ? inkX / ink : null, goal };
}"""
"""What the canvas shows, read back from its pixels: how many are transparent (never drawn), how many
colours, how many of the link/car colour #263a7a (and their mean x), how many of the goal's #17804a."""


def assert_scene_drawn(pixels: dict[str, float]) -> None:
    assert pixels["transparent"] == 0, f"parts of the canvas were never drawn: {pixels}"
    assert pixels["colours"] > 8, f"a blank canvas: {pixels}"
    assert pixels["ink"] > 200, f"no link or car (#263a7a) on the canvas: {pixels}"
    assert pixels["goal"] > 20, f"no goal line or flag (#17804a) on the canvas: {pixels}"


def drawn_x(scene: str, state: list[float]) -> float:
    """Where the drawing's #263a7a pixels should be, horizontally (env units, larger = further right):
    the car's position, or the mean of the two links' midpoints."""
    if scene == "mountaincar":
        return state[0]
    t1, t2 = state[0], state[1]
    return (1.5 * math.sin(t1) + 0.5 * math.sin(t1 + t2)) / 2


def readout_labels(page: object) -> tuple[str, str]:
    """The two state readouts' labels, as written (the page's CSS shows them in capitals)."""
    return page.text_content("#readout-a"), page.text_content("#readout-b")  # type: ignore[attr-defined]


def check_readouts(scene: str, state: list[float], angle: str, position: str) -> None:
    """The page's two state readouts show ``state`` (MountainCar: position, velocity; Acrobot: both
    link angles in degrees and the free end's height)."""
    if scene == "mountaincar":
        assert float(angle) == pytest.approx(state[0], abs=0.0005 + 1e-9)
        assert float(position) == pytest.approx(state[1], abs=0.00005 + 1e-9)
    else:
        degrees = [int(d) for d in re.findall(r"-?\d+", angle)]
        assert degrees == pytest.approx([math.degrees(state[0]), math.degrees(state[1])], abs=0.5 + 1e-9)
        tip = -math.cos(state[0]) - math.cos(state[0] + state[1])
        assert float(position) == pytest.approx(tip, abs=0.005 + 1e-9)


@pytest.mark.parametrize("scene", list(SCENE_ENVS))
def test_watch_draws_an_acrobot_or_mountaincar_episode(
    desktop: Page, web_runs: WebRuns, shots: Path, scene: str
):
    from cartpole.web.physics import ACTION_LABELS

    env_id, labels, run = SCENE_ENVS[scene], ACTION_LABELS[scene], getattr(web_runs, scene)
    page = desktop.goto(watch_path(run))
    page.locator("#loading").wait_for(state="hidden", timeout=60_000)  # a cold episode worker is slow
    assert page.inner_text("#message") == ""
    page.wait_for_function("() => watch.episode !== null")
    e = page.evaluate(
        """() => { const e = watch.episode; return { scene: e.scene, env_id: e.env_id, length: e.length,
             ret: e.return, terminated: e.terminated, labels: e.action_labels, actions: e.actions,
             states: e.states, scores: e.scores, fps: e.limits.fps }; }"""
    )
    assert (e["scene"], e["env_id"], e["labels"]) == (scene, env_id, labels)
    length = e["length"]
    assert length > 10 and len(e["states"]) == length + 1

    # The step counter advances while playing, over the episode's length.
    page.click("#restart")
    page.wait_for_function("() => parseInt(document.querySelector('#step').textContent) >= 3")
    done, total = step_counter(page)
    assert total == length
    page.wait_for_function(f"() => parseInt(document.querySelector('#step').textContent) > {done}")
    page.click("#play-pause")  # pause, then show a known step
    page.wait_for_function("() => watch.playing === false")
    k = length // 2
    page.evaluate("(k) => { watch.frame = k; render(); }", k)
    assert step_counter(page) == (k, length)

    # Three score bars named by the env's actions; the chosen one is the action shown.
    prefs = page.locator("#prefs .pref")
    assert prefs.count() == 3
    assert [prefs.nth(a).locator("span").first.inner_text() for a in range(3)] == labels
    values = [float(v) for v in page.locator("#prefs .pref .val").all_inner_texts()]
    assert values == pytest.approx(e["scores"][k], abs=0.005 + 1e-9)
    chosen = labels[e["actions"][k]]
    assert page.locator("#prefs .pref.chosen").count() == 1
    assert page.locator("#prefs .pref.chosen span").first.inner_text() == chosen
    assert page.inner_text("#action") == chosen

    # The env's readouts; CartPole's nudges and physics are not offered.
    assert readout_labels(page) == SCENE_READOUTS[scene]
    check_readouts(scene, e["states"][k], page.inner_text("#angle"), page.inner_text("#position"))
    assert page.locator("#nudge-panel").is_hidden() and page.locator("#physics-panel").is_hidden()
    subtitle = page.inner_text("#subtitle")
    assert env_id in subtitle and f"{e['fps']:g} frames per second" in subtitle
    assert page.inner_text("#title") == f"Watch best of {run}"

    # The outcome in the env's own words.
    ret = f"{e['ret']:.0f}"
    if scene == "acrobot":
        said = (
            f"the free end swung above the line at step {length} (return {ret})."
            if e["terminated"]
            else f"the free end did not reach the line in {length} steps (return {ret})."
        )
    else:
        said = (
            f"the car reached the flag at step {length} (return {ret})."
            if e["terminated"]
            else f"the car did not reach the flag in {length} steps (return {ret})."
        )
    assert page.inner_text("#outcome") == f"This episode: {said}"

    # The canvas shows the scene, and the link or car where the state says.
    stage = page.locator("#stage")
    assert_scene_drawn(stage.evaluate(CANVAS_PIXELS))
    stage.screenshot(path=str(shots / f"watch-{scene}_1280x800.png"))
    where = [drawn_x(scene, s) for s in e["states"]]
    left, right = where.index(min(where)), where.index(max(where))
    assert where[right] - where[left] > 0.05, "the episode hardly moves: pick another seed"
    shown = {}
    for i in (left, right):
        page.evaluate("(i) => { watch.frame = i; render(); }", i)
        pixels = stage.evaluate(CANVAS_PIXELS)
        assert_scene_drawn(pixels)
        shown[i] = pixels["inkX"]
    assert shown[right] > shown[left] + 2, f"the drawing does not follow the state: {shown}"


def gym_state(env_id: str, seed: int, actions: list[int]) -> list[float]:
    """Gymnasium's env's own state after ``reset(seed=seed)`` and ``actions``."""
    import gymnasium as gym

    env = gym.make(env_id)
    try:
        env.reset(seed=seed)
        for action in actions:
            env.step(action)
        return [float(v) for v in env.unwrapped.state]  # type: ignore[attr-defined]
    finally:
        env.close()


def same_state(a: list[float], b: list[float]) -> bool:
    return len(a) == len(b) and all(abs(x - y) <= 1e-9 for x, y in zip(a, b, strict=True))


def played_until(page: object, steps: int) -> dict[str, object]:
    """Wait until the game has played at least ``steps`` steps (its return is -1 a step); its step
    count, state, score and readouts, read at one moment."""
    handle = page.wait_for_function(  # type: ignore[attr-defined]
        f"""() => -game.score >= {steps} && {{ steps: -game.score, seed: game.seed,
             state: game.state.slice(), phase: game.phase,
             score: document.querySelector('#score').textContent,
             angle: document.querySelector('#angle').textContent,
             position: document.querySelector('#position').textContent }}""",
        timeout=30_000,
    )
    return handle.json_value()


RECORD_ACTIONS = """() => {
  window.sentActions = [];
  const send = game.socket.send.bind(game.socket);
  game.socket.send = (text) => {
    const message = JSON.parse(text);
    if (message.type === "step") window.sentActions.push(message.action);
    return send(text);
  };
}"""
"""Wraps the page's WebSocket send to keep every step's action, in order."""


def sent_after(page: object, action: int) -> int:
    """Wait until the page has sent ``action``; how many steps it had sent then (the first of them
    that shows ``action`` is the last)."""
    page.wait_for_function(f"() => window.sentActions.includes({action})", timeout=30_000)  # type: ignore[attr-defined]
    return int(page.evaluate("() => window.sentActions.length"))  # type: ignore[attr-defined]


def runs_of(actions: list[int]) -> list[int]:
    """The actions with repeats collapsed: [2, 2, 0, 0, 0, 1] -> [2, 0, 1]."""
    return [a for i, a in enumerate(actions) if i == 0 or actions[i - 1] != a]


def test_watch_of_acrobot_ignores_cartpole_physics_in_the_address(desktop: Page, web_runs: WebRuns):
    """A Watch address with CartPole's physics (say, copied from a CartPole run) still plays an
    Acrobot run, as Gymnasium has it, without the CartPole panels."""
    page = desktop.goto(watch_path(web_runs.acrobot) + "&length=1.5&gravity=5")
    page.locator("#loading").wait_for(state="hidden", timeout=60_000)
    page.wait_for_function("() => watch.episode !== null")
    assert page.inner_text("#message") == ""
    assert page.evaluate("() => watch.episode.scene") == "acrobot"
    assert page.locator("#nudge-panel").is_hidden() and page.locator("#physics-panel").is_hidden()
    assert "length" not in page.url and "gravity" not in page.url


@pytest.mark.parametrize("scene", list(SCENE_ENVS))
def test_play_acrobot_or_mountaincar_steps_gymnasiums_env_with_the_keys(
    desktop: Page, web_runs: WebRuns, shots: Path, scene: str
):
    """→ is action 2, ← action 0, no key action 1: the page's states are exactly Gymnasium's env's
    from the seed the server reset it with, for those actions."""
    env_id = SCENE_ENVS[scene]
    page = desktop.goto(f"/play?env={env_id}")
    page.get_by_text("Press ← or → to start").wait_for()
    name = "Acrobot" if scene == "acrobot" else "MountainCar"
    assert page.inner_text("#title") == f"Play {name} yourself"
    assert page.title() == f"Play · {env_id}"
    assert page.input_value("#env-select") == env_id
    assert page.locator("#physics-panel").is_hidden()
    assert readout_labels(page) == SCENE_READOUTS[scene]
    assert page.inner_text("#score") == "0"
    run = getattr(web_runs, scene)  # only this env's run is offered to compare with
    page.locator(f'#agent-select option[value="{run}"]').wait_for(state="attached")
    assert page.eval_on_selector_all("#agent-select option", "(os) => os.map((o) => o.value)") == [run]

    seed = page.evaluate("() => game.seed")
    assert same_state(page.evaluate("() => game.state"), gym_state(env_id, seed, []))
    stage = page.locator("#stage")
    page.wait_for_function("() => game.sceneLimits !== undefined")
    page.wait_for_timeout(100)  # a frame or two drawn
    assert_scene_drawn(stage.evaluate(CANVAS_PIXELS))

    # Every action the page sends is recorded: the keys decide them, Gymnasium's env must follow them.
    page.evaluate(RECORD_ACTIONS)

    def played(steps: int) -> tuple[dict[str, object], list[int]]:
        reading = played_until(page, steps)
        actions = page.evaluate("() => window.sentActions.slice()")[: int(reading["steps"])]  # type: ignore[call-overload]
        assert same_state(reading["state"], gym_state(env_id, seed, actions))  # type: ignore[arg-type]
        check_readouts(scene, reading["state"], reading["angle"], reading["position"])
        return reading, actions

    # → starts the game and pushes/turns one way (action 2); the score counts -1 a step.
    page.keyboard.down("ArrowRight")
    first, actions = played(4)
    assert first["phase"] == "running" and page.locator("#overlay").is_hidden()
    assert first["score"] == str(-len(actions)) and set(actions) == {2}
    for other in (0, 1):
        assert not same_state(first["state"], gym_state(env_id, seed, [other] * len(actions)))  # type: ignore[arg-type]
    assert_scene_drawn(stage.evaluate(CANVAS_PIXELS))
    stage.screenshot(path=str(shots / f"play-{scene}_1280x800.png"))

    # ← (pressed before → is let go: no step without a key between) is action 0. Steps go on while
    # the keys travel to the page, so the readings wait for the page to have sent the new action.
    page.keyboard.down("ArrowLeft")
    page.keyboard.up("ArrowRight")
    _, actions = played(sent_after(page, 0))
    assert runs_of(actions) == [2, 0], f"holding ← did not push/turn the other way (action 0): {actions}"

    # No key: action 1 (no torque / no push).
    page.keyboard.up("ArrowLeft")
    third, actions = played(sent_after(page, 1))
    assert third["seed"] == seed
    assert runs_of(actions) == [2, 0, 1], f"with no key held the env did not get action 1: {actions}"

    if scene == "mountaincar":  # to the time limit, fast: the car never reaches the flag this way
        page.select_option("#speed", "2")
        page.wait_for_function("() => game.phase === 'over'", timeout=30_000)
        title = page.inner_text("#overlay-title")
        assert title == "The car never reached the flag in 200 steps (return -200)"
        assert page.inner_text("#score") == "-200" and page.inner_text("#best") == "-200"
        link = page.get_attribute("#compare-link", "href")
        assert link and f"run={run}" in link and f"seed={seed}" in link


@pytest.mark.parametrize(
    "start, switch_to",
    [("Acrobot-v1", "MountainCar-v0"), ("MountainCar-v0", "CartPole-v1"), ("CartPole-v1", "Acrobot-v1")],
)
def test_play_env_select_switches_the_game(desktop: Page, start: str, switch_to: str):
    titles = {
        "CartPole-v1": "Play CartPole yourself",
        "Acrobot-v1": "Play Acrobot yourself",
        "MountainCar-v0": "Play MountainCar yourself",
    }
    page = desktop.goto(f"/play?env={start}")
    page.get_by_text("Press ← or → to start").wait_for()  # connected: leaving now closes a live socket
    assert page.inner_text("#title") == titles[start]
    page.select_option("#env-select", switch_to)
    page.wait_for_url(re.compile(rf".*/play\?env={re.escape(switch_to)}$"))
    page.get_by_text("Press ← or → to start").wait_for()
    assert page.inner_text("#title") == titles[switch_to]
    assert page.input_value("#env-select") == switch_to
    assert page.locator("#physics-panel").is_hidden() == (switch_to != "CartPole-v1")
    scene = "cartpole" if switch_to == "CartPole-v1" else switch_to.split("-")[0].lower()
    assert page.evaluate("() => ENV.scene") == scene


@pytest.fixture(scope="module")
def pixel_run(web_runs: WebRuns) -> str:
    """An (untrained) PPO run on CartPole from pixels, in the served runs folder."""
    return make_pixel_run(web_runs.root)


# The "now" frame of the agent's view at step k, read back from its canvas (FrameStackDraw draws
# frame pixels 3x3, under a 16-pixel label, the last of 4 cells in a column with 8-pixel gaps),
# against the episode's own frame k: how many pixels differ.
VIEW_MISMATCHES = """(k) => {
  const e = watch.episode, v = e.view, frames = FrameStackDraw.decode(v);
  const canvas = document.getElementById("agent-view");
  const x0 = 0, y0 = 3 * (3 * v.height + 16 + 8) + 16;
  const pixels = canvas.getContext("2d").getImageData(x0, y0, 3 * v.width, 3 * v.height).data;
  let wrong = 0;
  for (let r = 0; r < v.height; r++) for (let c = 0; c < v.width; c++) {
    const drawn = pixels[((3 * r + 1) * 3 * v.width + 3 * c + 1) * 4];
    if (drawn !== frames[k][r * v.width + c]) wrong++;
  }
  return wrong;
}"""


def test_watch_shows_what_a_pixel_agent_sees_beside_the_scene(desktop: Page, pixel_run: str):
    page = desktop.goto(watch_path(pixel_run))
    page.locator("#loading").wait_for(state="hidden", timeout=60_000)  # a cold episode worker is slow
    assert page.inner_text("#message") == ""
    page.wait_for_function("() => watch.episode !== null && watch.episode.view !== null")
    page.click("#play-pause")  # pause, then show known steps
    page.wait_for_function("() => watch.playing === false")
    assert page.locator("#view-panel").is_visible()
    assert "What the agent sees" in page.inner_text("#view-panel")
    length = page.evaluate("() => watch.episode.length")
    for k in (0, length // 2, length):
        page.evaluate("(k) => { watch.frame = k; render(); }", k)
        assert page.evaluate(VIEW_MISMATCHES, k) == 0, k
        assert f"at step {k}" in page.inner_text("#view-note")
    # Not blank: the cart and pole are darker than the white screen.
    dark = page.evaluate(
        """() => { const c = document.getElementById("agent-view");
             const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
             let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i + 3] === 255 && d[i] < 128) n++;
             return n; }"""
    )
    assert dark > 100
    page.evaluate("() => { watch.frame = 1; render(); }")
    assert page.locator("#prefs .pref").count() == 2  # the per-action scores, as for any agent


def test_watch_of_a_state_agent_shows_no_agent_view(desktop: Page, web_runs: WebRuns):
    page = desktop.goto(watch_path(web_runs.cem))
    page.wait_for_function("() => watch.episode !== null")
    assert page.locator("#view-panel").is_hidden()
