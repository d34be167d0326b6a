"""What the browser tests share: a free port, uvicorn serving an app in a thread, a page that records
console errors, and where screenshots go.

Imported by tests/test_web_browser.py and tests/test_web_train_browser.py (not a conftest pytest loads
itself; the ``browser`` fixture, a headless Chromium, is in conftest.py).
"""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import pytest
import uvicorn
from fastapi import FastAPI

from cartpole.web.security import SERVER_OPTIONS

DESKTOP = {"width": 1280, "height": 800}
PHONE = {"width": 390, "height": 844}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """uvicorn serving ``app`` on ``port`` in a background thread, with ``cartpole serve``'s options;
    its lifespan runs, so trainings start, and stopping it stops them (each saves first)."""

    def __init__(self, app: FastAPI, port: int):
        config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", **SERVER_OPTIONS)
        self.uvicorn = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.uvicorn.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.uvicorn.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)

    def stop(self) -> None:
        self.uvicorn.should_exit = True
        self.thread.join(timeout=90)  # the trainings it stops save first


def screenshots_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """CARTPOLE_WEB_SCREENSHOTS when set (kept), else a temporary folder."""
    where = os.environ.get("CARTPOLE_WEB_SCREENSHOTS")
    path = Path(where) if where else tmp_path_factory.mktemp("screenshots")
    path.mkdir(parents=True, exist_ok=True)
    return path


class Page:
    """A browser page that records console errors and uncaught exceptions; with ``token`` it first
    opens ``/?token=TOKEN`` (the address `cartpole serve` prints), which sets the token's cookie."""

    def __init__(self, browser: object, base: str, viewport: dict[str, int], token: str | None = None):
        self.context = browser.new_context(viewport=viewport)  # type: ignore[attr-defined]
        self.page = self.context.new_page()
        self.base = base
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        if token is not None:
            self.page.goto(f"{base}/?token={token}")
            assert "token" not in self.page.url  # redirected to the address without it

    def goto(self, path: str) -> object:
        self.page.goto(self.base + path)
        return self.page

    def close(self) -> None:
        self.context.close()
