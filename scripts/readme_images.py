"""Make the two pictures the README shows: a real training run's curve, and the web app's Train page.

- ``learning-curve.png``: the learning curve of PPO (seed 0) on CartPole-v1, drawn by the project's own
  plotting (``cartpole.plotting.plot_runs``, what ``cartpole plot`` calls);
- ``web-train.png``: a 1280x900 screenshot of the web app's Train page (``cartpole serve``): DQN picked,
  one setting and the budget changed, and beside them a training of PPO that the page's API started.

The run is trained with the CLI in a temporary runs folder that is deleted at the end; the server is
stopped however the script ends. Needs the project installed (``pip install -e .``), the ``playwright``
package and Chromium at /usr/bin/chromium (or ``--chromium PATH``). Takes well under a minute::

    python scripts/readme_images.py [--out docs/images]
"""

from __future__ import annotations

import argparse
import json
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

VIEWPORT = {"width": 1280, "height": 900}  # the form and the trainings beside it
TOKEN = "readme-images"
TRAINING = {"agent": "ppo", "budget": "2000k", "settings": {"stop_when_solved": False}}
"""The training listed beside the form while the picture is taken (the server stops it at the end)."""
FORM = {"agent": "dqn", "budget": "50k", "lr": "0.002"}
"""What the form shows changed."""
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
            cartpole_command("serve", "--runs-dir", str(runs_dir), "--port", str(port), "--token", TOKEN),
            stdout=log_file,
            stderr=subprocess.STDOUT,
        )
        try:
            base = f"http://127.0.0.1:{port}"
            wait_until_answering(f"{base}/api/info", server, log)
            yield base
        finally:
            stop_server(server)


def start_training(base: str) -> None:
    """Start TRAINING through the server's API, as the Train page does (with the token)."""
    request = urllib.request.Request(
        f"{base}/api/trainings",
        json.dumps(TRAINING).encode(),
        {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(request, timeout=60) as response:
        if response.status != 201:
            raise RuntimeError(f"POST /api/trainings answered {response.status}")


def fill_form(page: Page) -> None:
    """On a loaded Train page: pick FORM's agent, change its budget and learning rate."""
    page.locator('#settings-table tr[data-setting="eval_every"]').wait_for()
    page.select_option("#agent", FORM["agent"])
    page.locator('#settings-table tr[data-setting="lr"]').wait_for()
    page.fill("#budget", FORM["budget"])
    page.fill('#settings-table [data-setting-input="lr"]', FORM["lr"])
    page.dispatch_event('#settings-table [data-setting-input="lr"]', "change")
    page.locator("#queue tr[data-training]").first.wait_for()
    page.evaluate("() => { document.activeElement.blur(); window.scrollTo(0, 0); }")
    page.wait_for_timeout(300)  # let the highlight paint


def record_console_error(message: ConsoleMessage, errors: list[str]) -> None:
    if message.type == "error":
        errors.append(message.text)


def screenshot_train_page(base: str, out: Path, chromium: Path) -> Path:
    """Screenshot the Train page at VIEWPORT, with a training running beside the form."""
    from playwright.sync_api import sync_playwright

    start_training(base)
    errors: list[str] = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(chromium), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(PAGE_TIMEOUT_MS)
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.on("console", lambda msg: record_console_error(msg, errors))
            page.goto(f"{base}/train?token={TOKEN}")  # the address `cartpole serve` prints sets the cookie
            fill_form(page)
            if errors:
                raise RuntimeError(f"the Train page reported errors: {errors}")
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
            shot = screenshot_train_page(base, args.out / "web-train.png", args.chromium)
        print(f"wrote {shot} ({shot.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
