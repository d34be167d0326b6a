"""Does the built wheel work as a user installs it? Run with the python of a venv that installed the wheel
(not editable), from a folder outside the source tree (`.ci/wheel` does both):

    python .ci/wheel_check.py WHEEL

It checks, each failure one line and exit 1:
- cartpole is imported from that venv, not from a source tree;
- `cartpole presets` lists presets;
- `cartpole train cem` trains to a verdict (eval.json written, exit 0);
- `cartpole serve` answers 200 for every page of the app and every script and stylesheet each links;
- `cartpole.open_run(RUN).show()` gives HTML holding the player script exactly as the wheel ships it.
"""

from __future__ import annotations

import html.parser
import json
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zipfile
from pathlib import Path

PLAYER = "cartpole/notebook/static/player.js"


def cartpole_cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    command = [str(Path(sys.executable).with_name("cartpole")), *args]
    done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    if done.returncode != 0:
        raise SystemExit(f"`cartpole {' '.join(args)}` exited {done.returncode}:\n{done.stdout}{done.stderr}")
    return done


def check_installed_copy() -> None:
    import cartpole

    where = Path(cartpole.__file__).resolve()
    if not where.is_relative_to(Path(sys.prefix).resolve()):
        raise SystemExit(f"cartpole was imported from {where}, not from the venv at {sys.prefix}")
    print(f"  cartpole imported from {where.parent}")


def check_presets() -> None:
    out = cartpole_cli("presets").stdout
    if "tutorial-keras" not in out:
        raise SystemExit(f"`cartpole presets` does not list tutorial-keras:\n{out}")
    print(f"  cartpole presets: {len(out.splitlines())} lines")


def check_train(runs: Path) -> Path:
    cartpole_cli("train", "cem", "--runs-dir", str(runs))
    (run,) = runs.iterdir()
    verdict = json.loads((run / "eval.json").read_text())
    print(f"  cartpole train cem: {run.name}, verdict mean {verdict.get('mean')}")
    return run


class Links(html.parser.HTMLParser):
    """The same-origin scripts, stylesheets and pages a page links."""

    def __init__(self) -> None:
        super().__init__()
        self.paths: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if name in ("src", "href") and value and value.startswith("/") and not value.startswith("//"):
                self.paths.add(value)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def fetch(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as answer:
            return answer.status, answer.read().decode("utf-8", "replace")
    except urllib.error.HTTPError as error:
        return error.code, ""


def wait_for(url: str, server: subprocess.Popen[bytes], seconds: float = 60) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise SystemExit(f"cartpole serve exited {server.returncode} before answering")
        try:
            fetch(url)
            return
        except OSError:
            time.sleep(0.2)
    raise SystemExit(f"cartpole serve did not answer {url} within {seconds:.0f} s")


def check_serve(runs: Path) -> None:
    from cartpole.web.app import PAGES

    port = free_port()
    base = f"http://127.0.0.1:{port}"
    command = [str(Path(sys.executable).with_name("cartpole")), "serve", "--runs-dir", str(runs)]
    server = subprocess.Popen([*command, "--port", str(port)], stdout=subprocess.DEVNULL)
    try:
        wait_for(base + "/", server)
        linked: set[str] = set()
        for page in PAGES:
            status, text = fetch(base + page)
            if status != 200:
                raise SystemExit(f"cartpole serve: page {page} answered {status}")
            parser = Links()
            parser.feed(text)
            linked |= parser.paths
        for path in sorted(linked):
            status, _ = fetch(base + path)
            if status != 200:
                raise SystemExit(f"cartpole serve: {path} (linked from a page) answered {status}")
        status, listing = fetch(base + "/api/runs")
        if status != 200 or next(runs.iterdir()).name not in listing:
            raise SystemExit(f"cartpole serve: /api/runs answered {status} without the trained run")
        print(f"  cartpole serve: {len(PAGES)} pages and the {len(linked)} paths they link answer 200")
    finally:
        server.terminate()
        server.wait(timeout=30)


def check_notebook_player(run: Path, wheel: Path) -> None:
    import cartpole

    with zipfile.ZipFile(wheel) as archive:
        shipped = archive.read(PLAYER).decode("utf-8")
    page = cartpole.open_run(run).show(episodes=1)._repr_html_()
    if shipped not in page:
        raise SystemExit(f"open_run(...).show() gives HTML without the wheel's {PLAYER}")
    print(f"  open_run(...).show(): {len(page):,} characters of HTML with the wheel's player script")


def main() -> int:
    wheel = Path(sys.argv[1]).resolve()
    work = Path.cwd()
    if (work / "pyproject.toml").exists() or (work / "src" / "cartpole").exists():
        raise SystemExit(f"run this from outside the source tree, not {work}")
    os.environ.setdefault("MPLBACKEND", "Agg")
    runs = work / "runs"
    check_installed_copy()
    check_presets()
    run = check_train(runs)
    check_serve(runs)
    check_notebook_player(run, wheel)
    print(f"the wheel {wheel.name} installs and works from {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
