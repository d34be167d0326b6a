"""Make the two pictures the README shows, from a real training run.

- ``learning-curve.png``: the learning curve of PPO (seed 0) on CartPole-v1, drawn by the project's own
  plotting (``cartpole.plotting.plot_runs``, what ``cartpole plot`` calls);
- ``web-app.png``: a 1280x840 screenshot of the web app (``cartpole serve``) on the Watch page of that
  run, its best checkpoint replaying an episode just after a nudge to the pole.

The run is trained with the CLI in a temporary runs folder that is deleted at the end; the server is
stopped however the script ends. Needs the project installed (``pip install -e .``), the ``playwright``
package and Chromium at /usr/bin/chromium (or ``--chromium PATH``). Takes well under a minute::

    python scripts/readme_images.py [--out docs/images]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from playwright.sync_api import ConsoleMessage, Page

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO_ROOT / "docs" / "images"
DEFAULT_CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]

SEED = 0
TRAIN_ARGS = [
    "ppo",
    "--seed",
    str(SEED),
    "--device",
    "cpu",  # the same numbers on every machine, GPU or not
    "--budget",
    "60k",
    "--no-stop-when-solved",  # past the first solve, so the curve shows that it stays solved
    "--quiet",
]
CURVE_WINDOW = 20
"""Moving-average window, as on the web app's run page (100 episodes lags far behind a short PPO run)."""
CURVE_TITLE = f"PPO on CartPole-v1, seed {SEED}"
CURVE_DPI = 130  # 10 x 6.4 inches -> 1300 x 832 pixels

VIEWPORT = {"width": 1280, "height": 840}  # tall enough for the line that tells how the episode ended
EPISODE_SEED = 0
NUDGE_STEP = 60
"""The step at which the screenshot's episode gets a push to the left; the frame shown is the one, of the
next 12 (while the canvas still draws the push), where the pole leans the most that way."""
NUDGE_STRENGTH = 1.0
"""rad/s: a push the policy recovers from (at 1.2 to the left it loses the pole 27 steps later)."""
SERVER_START_TIMEOUT_S = 30.0
PAGE_TIMEOUT_MS = 30_000


def cartpole_command(*args: str) -> list[str]:
    """The ``cartpole`` CLI of the Python running this script."""
    return [sys.executable, "-m", "cartpole", *args]


def train_run(runs_dir: Path) -> Path:
    """Train the run with the CLI in ``runs_dir`` and return its folder."""
    result = subprocess.run(
        cartpole_command("train", *TRAIN_ARGS, "--runs-dir", str(runs_dir)),
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        raise RuntimeError(f"cartpole train failed ({result.returncode}):\n{result.stdout}{result.stderr}")
    runs = [path for path in runs_dir.iterdir() if path.is_dir()]
    if len(runs) != 1:
        raise RuntimeError(f"expected one run folder in {runs_dir}, found {len(runs)}")
    return runs[0]


def draw_learning_curve(run: Path, out: Path) -> Path:
    """Draw the run's learning curve to ``out`` with the project's plotting."""
    from cartpole.plotting import plot_runs

    return plot_runs([run], out, window=CURVE_WINDOW, title=CURVE_TITLE, dpi=CURVE_DPI)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_until_answering(url: str, server: subprocess.Popen[bytes], log: Path) -> None:
    """Poll ``url`` until it answers 200; fail if the server exits or takes too long."""
    deadline = time.monotonic() + SERVER_START_TIMEOUT_S
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(f"cartpole serve exited with {server.returncode}:\n{log.read_text()}")
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        time.sleep(0.1)
    raise RuntimeError(f"{url} did not answer within {SERVER_START_TIMEOUT_S:g} s:\n{log.read_text()}")


def stop_server(server: subprocess.Popen[bytes]) -> None:
    """Stop the server: SIGTERM, then SIGKILL if it lingers."""
    if server.poll() is not None:
        return
    server.terminate()
    try:
        server.wait(timeout=10)
    except subprocess.TimeoutExpired:
        server.kill()
        server.wait(timeout=10)


@contextmanager
def serving(runs_dir: Path, log: Path) -> Iterator[str]:
    """Run ``cartpole serve`` for ``runs_dir`` on a free port; yield its base URL; stop it on exit."""
    port = free_port()
    with log.open("wb") as log_file:
        server = subprocess.Popen(
            cartpole_command("serve", "--runs-dir", str(runs_dir), "--port", str(port)),
            stdout=log_file,
            stderr=subprocess.STDOUT,
        )
        try:
            base = f"http://127.0.0.1:{port}"
            wait_until_answering(f"{base}/api/info", server, log)
            yield base
        finally:
            stop_server(server)


def show_nudged_episode(page: Page) -> None:
    """On a loaded Watch page: push the pole left at NUDGE_STEP, then pause where it leans the most after."""
    page.wait_for_function("() => watch.episode !== null && watch.maxScore !== undefined")
    page.evaluate(f"() => {{ setPlaying(false); watch.frame = {NUDGE_STEP}; render(); }}")
    strength = page.locator("#nudge-size")
    strength.evaluate("(input, value) => { input.value = value; }", str(NUDGE_STRENGTH))
    strength.dispatch_event("input")  # the page shows the strength beside the slider
    page.click("#nudge-left")
    page.wait_for_function("() => watch.episode.nudges.length === 1 && watch.playing")
    page.evaluate(
        """(step) => {
            setPlaying(false);
            const states = watch.episode.states;
            let best = step;
            for (let i = step; i < Math.min(step + 12, states.length); i++) {
                if (states[i][2] < states[best][2]) best = i;  // leaning left: the most negative angle
            }
            watch.frame = best;
            render();
            document.activeElement.blur();
        }""",
        NUDGE_STEP,
    )
    if page.evaluate("() => watch.episode.terminated"):
        raise RuntimeError(f"the policy did not recover from the nudge: {page.inner_text('#outcome')}")
    page.mouse.move(0, VIEWPORT["height"] - 1)  # no hover highlight on the button just clicked
    page.wait_for_timeout(300)  # let the canvas and the bars paint


def record_console_error(message: ConsoleMessage, errors: list[str]) -> None:
    if message.type == "error":
        errors.append(message.text)


def screenshot_watch_page(base: str, run_name: str, out: Path, chromium: Path) -> Path:
    """Screenshot the Watch page of the run's best checkpoint at VIEWPORT."""
    from playwright.sync_api import sync_playwright

    url = f"{base}/watch?run={run_name}&checkpoint=best&seed={EPISODE_SEED}"
    errors: list[str] = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(chromium), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(PAGE_TIMEOUT_MS)
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.on("console", lambda msg: record_console_error(msg, errors))
            page.goto(url)
            show_nudged_episode(page)
            if errors:
                raise RuntimeError(f"the Watch page reported errors: {errors}")
            out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(out))
        finally:
            browser.close()
    return out


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_OUT, help=f"folder for the PNGs (default: {DEFAULT_OUT})"
    )
    parser.add_argument(
        "--chromium",
        type=Path,
        default=DEFAULT_CHROMIUM,
        help=f"Chromium executable (default: {DEFAULT_CHROMIUM})",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="readme-images-") as tmp:
        runs_dir = Path(tmp) / "runs"
        runs_dir.mkdir()
        run = train_run(runs_dir)
        curve = draw_learning_curve(run, args.out / "learning-curve.png")
        print(f"wrote {curve} ({curve.stat().st_size // 1024} KiB)")
        with serving(runs_dir, Path(tmp) / "serve.log") as base:
            shot = screenshot_watch_page(base, run.name, args.out / "web-app.png", args.chromium)
        print(f"wrote {shot} ({shot.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
