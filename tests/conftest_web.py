"""Run folders for the web tests: real trained runs plus the awkward cases a server must survive.

Imported by tests/test_web_api.py and tests/test_web_browser.py (not a conftest pytest loads itself).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urljoin

from fastapi.testclient import TestClient

from cartpole.runs import RunDir
from cartpole.training import train
from cartpole.web.app import create_app

LOCAL = "http://127.0.0.1"


class LocalClient(TestClient):
    """A test client whose requests, WebSocket ones too, are addressed to 127.0.0.1 (Starlette's
    client addresses WebSockets to "testserver", a host the app refuses)."""

    def websocket_connect(self, url: str, *args: Any, **kwargs: Any) -> Any:
        return super().websocket_connect(urljoin(LOCAL.replace("http", "ws", 1), url), *args, **kwargs)


def local_client(runs_dir: Path) -> TestClient:
    """A client of the app serving ``runs_dir``, as a browser on this machine would address it."""
    return LocalClient(create_app(runs_dir), base_url=LOCAL)


@dataclass(frozen=True)
class WebRuns:
    """A runs folder and the names of the runs in it, by kind."""

    root: Path
    cem: str
    acrobot: str
    corrupt: str
    incomplete: str
    outside: Path


def make_cem_run(runs_dir: Path) -> str:
    """A real CEM run on CartPole-v1 (solves in about a second)."""
    outcome = train("cem", "CartPole-v1", seed=0, runs_dir=runs_dir, quiet=True)
    return outcome.run.name


def make_dqn_run(runs_dir: Path) -> str:
    """A real, small (unsolved) DQN run: enough for Q-values per step."""
    outcome = train("dqn", "CartPole-v1", seed=0, budget="3000", runs_dir=runs_dir, quiet=True)
    return outcome.run.name


def make_acrobot_run(runs_dir: Path, cem_run: Path) -> str:
    """A run folder that records another env: its curves show, but it cannot be watched."""
    run = RunDir.create(runs_dir, "Acrobot-v1", "cem", 3)
    config = RunDir(cem_run).config()
    run.write_config({**config, "env_id": "Acrobot-v1", "seed": 3, "created": "2000-01-01T00:00:00+00:00"})
    run.write_status({"state": "finished", "env_steps": 100, "episodes": 2, "solved": False})
    run.append_metrics([{"step": 50, "episode": 1, "time": 0.1, "train/episode_return": -500.0}])
    shutil.copy(cem_run / "checkpoints" / "best.pt", run.checkpoint_path("best"))
    return run.name


def make_awkward_runs(runs_dir: Path, outside: Path) -> tuple[str, str]:
    """A corrupt run (config.json garbage), a half-written one (no config yet), a symlink out."""
    corrupt = runs_dir / "CartPole-v1__dqn__s7__20200101-000000"
    corrupt.mkdir()
    (corrupt / "config.json").write_text("{not json", encoding="utf-8")
    incomplete = runs_dir / "CartPole-v1__dqn__s8__20200101-000000"
    (incomplete / "checkpoints").mkdir(parents=True)
    (incomplete / "metrics.jsonl").write_text('{"step": 1, "episode": 0, "time": 0.1}\n{"step": 2', "utf-8")
    outside.mkdir(parents=True, exist_ok=True)
    (outside / "config.json").write_text(json.dumps({"agent": "cem", "env_id": "CartPole-v1"}), "utf-8")
    (runs_dir / "CartPole-v1__cem__s9__20200101-000000").symlink_to(outside, target_is_directory=True)
    return corrupt.name, incomplete.name


def make_web_runs(base: Path) -> WebRuns:
    root = base / "runs"
    cem = make_cem_run(root)
    acrobot = make_acrobot_run(root, root / cem)
    outside = base / "elsewhere" / "secret-run"
    corrupt, incomplete = make_awkward_runs(root, outside)
    return WebRuns(root, cem, acrobot, corrupt, incomplete, outside)
