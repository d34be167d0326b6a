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
    other_env: str
    acrobot: str
    mountaincar: str
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


def make_classic_run(runs_dir: Path, env_id: str) -> str:
    """A real, tiny CEM run on ``env_id`` (Acrobot-v1, MountainCar-v0): one generation of 8."""
    settings = {"population": 8, "episodes_per_candidate": 1}
    outcome = train("cem", env_id, seed=0, budget="1gen", overrides=settings, runs_dir=runs_dir, quiet=True)
    # Dated before the CartPole CEM run, which the runs list must show first: made in the same second,
    # the list would order them by name (seconds are all `created` keeps).
    run = RunDir(outcome.run.path)
    run.write_config({**run.config(), "created": "2020-06-01T00:00:00+00:00"})
    return outcome.run.name


def make_other_env_run(runs_dir: Path, cem_run: Path) -> str:
    """A run folder that records an env Watch does not draw: its curves show, but it cannot be watched."""
    run = RunDir.create(runs_dir, "Pendulum-v1", "cem", 3)
    config = RunDir(cem_run).config()
    run.write_config({**config, "env_id": "Pendulum-v1", "seed": 3, "created": "2000-01-01T00:00:00+00:00"})
    run.write_status({"state": "finished", "env_steps": 100, "episodes": 2, "solved": False})
    run.append_metrics([{"step": 50, "episode": 1, "time": 0.1, "train/episode_return": -500.0}])
    shutil.copy(cem_run / "checkpoints" / "best.pt", run.checkpoint_path("best"))
    return run.name


PIXELS = "cartpole/CartPolePixels-v1"


def make_pixel_run(runs_dir: Path) -> str:
    """A run folder of an untrained PPO on CartPole from pixels: its ``best`` checkpoint holds the
    convolutional network as initialized (seed 0), enough to watch what it sees. Written by hand, as
    a run's checkpoint is, because training one, even briefly, takes half a minute (its verdict plays
    100 episodes on Gymnasium's own pictures)."""
    from cartpole.agents.registry import build_population, get_agent
    from cartpole.core.config import config_to_dict
    from cartpole.envs import env_info
    from cartpole.runs import Checkpoint, save_checkpoint
    from cartpole.training.config import resolve_config

    spec = get_agent("ppo")
    config, _ = resolve_config(
        "ppo", spec.config_cls, "pixels", {"num_envs": 1, "n_steps": 16, "minibatch_size": 16}
    )
    tensors, learner = build_population(spec, config, env_info(PIXELS), [0]).seed_state_dict(0, resume=False)
    run = RunDir.create(runs_dir, PIXELS, "ppo", 0)
    record = {
        "agent": "ppo",
        "env_id": PIXELS,
        "seed": 0,
        "preset": "pixels",
        "config": config_to_dict(config),
    }
    run.write_config({**record, "created": "2021-01-01T00:00:00+00:00"})  # older than the CEM run
    run.write_status({"state": "finished", "env_steps": 0, "episodes": 0, "solved": False})
    meta = {**record, "step": 0, "learner": learner, "resumable": False}
    save_checkpoint(run.checkpoint_path("best"), Checkpoint(meta=meta, tensors=tensors))
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
    acrobot, mountaincar = (make_classic_run(root, env_id) for env_id in ("Acrobot-v1", "MountainCar-v0"))
    cem = make_cem_run(root)  # the newest run
    other_env = make_other_env_run(root, root / cem)
    outside = base / "elsewhere" / "secret-run"
    corrupt, incomplete = make_awkward_runs(root, outside)
    return WebRuns(root, cem, other_env, acrobot, mountaincar, corrupt, incomplete, outside)


DOCS_EXPERIMENT = Path(__file__).parents[1] / "docs" / "experiments" / "cem-dqn-random-search"
"""A real `cartpole compare` report (cem, dqn, random-search:tutorial over 10 seeds) with its figures."""


def make_experiment(runs_dir: Path, name: str = "cem-vs-dqn") -> str:
    """An experiment folder as `cartpole compare` leaves it: its report, figures and experiment.json."""
    folder = runs_dir / "experiments" / name
    folder.mkdir(parents=True)
    for file in ("report.json", "report.md", "curves.png", "solve_steps.png"):
        shutil.copy(DOCS_EXPERIMENT / file, folder / file)
    command = ["cartpole", "compare", "cem", "dqn", "random-search:tutorial", "--seeds", "10"]
    (folder / "experiment.json").write_text(
        json.dumps({"env_id": "CartPole-v1", "budget": None, "command": command}), "utf-8"
    )
    return name


def make_reported_experiment(runs_dir: Path, name: str = "cem-vs-dqn-finals") -> str:
    """An experiment folder whose report `cartpole compare` wrote from records of finished runs (their
    final verdicts made up, no training): every figure, rliable's views included."""
    import numpy as np

    from cartpole.experiments.entries import Entry
    from cartpole.experiments.figures import EvalCurve
    from cartpole.experiments.report import Results, write_report

    finals = {Entry("cem"): [500.0, 497.5, 430.0, 500.0], Entry("dqn"): [480.0, 350.0, 500.0, 210.0]}
    records = {
        entry: [
            {
                "agent": entry.agent,
                "preset": entry.preset,
                "seed": seed,
                "run": f"{entry.slug}-s{seed}",
                "state": "finished",
                "solved_in_training": final >= 475,
                "solve_steps": 20000,
                "solve_cpu_seconds": 1.0,
                "solve_wall_seconds": 1.0,
                "env_steps": 50000,
                "cpu_seconds": 2.0,
                "wall_seconds": 2.0,
                "final_mean": final,
                "final_solved": final >= 475,
            }
            for seed, final in enumerate(values)
        ]
        for entry, values in finals.items()
    }
    curve = EvalCurve(np.array([0.0, 20000.0, 50000.0]), np.array([20.0, 300.0, 500.0]), True, 475.0)
    folder = runs_dir / "experiments" / name
    folder.mkdir(parents=True)
    write_report(Results("CartPole-v1", None, [0, 1, 2, 3], records, {e: [curve] for e in finals}), folder)
    command = ["cartpole", "compare", "cem", "dqn", "--seeds", "4", "--name", name]
    (folder / "experiment.json").write_text(
        json.dumps({"env_id": "CartPole-v1", "budget": None, "command": command}), "utf-8"
    )
    return name


def make_sweep(runs_dir: Path, name: str = "dqn-2seeds") -> str:
    """A sweep folder as `cartpole sweep` leaves it: sweep.json, an Optuna journal with a complete, a
    pruned and a failed trial, and best.toml (made with Optuna's API, no training)."""
    import optuna
    from optuna.distributions import FloatDistribution, IntDistribution
    from optuna.storages.journal import JournalFileBackend
    from optuna.trial import TrialState, create_trial

    folder = runs_dir / "sweeps" / name
    folder.mkdir(parents=True)
    spec = {
        "name": name,
        "agent": "dqn",
        "preset": str(runs_dir.parent / "elsewhere" / "presets" / "dqn-base.toml"),
        "env_id": "CartPole-v1",
        "budget": "30000",
        "seeds_per_trial": 2,
        "trials": 3,
        "space_text": "",
        "storage": None,
        "folder": str(folder),
        "sampler_seed": 0,
        "space": {"lr": {"low": 1e-4, "high": 1e-2, "log": True}, "batch_size": {"low": 32, "high": 256}},
    }
    (folder / "sweep.json").write_text(json.dumps(spec), "utf-8")
    storage = optuna.storages.JournalStorage(JournalFileBackend(str(folder / "journal.log")))
    study = optuna.create_study(study_name=name, storage=storage, direction="minimize")
    distributions = {"lr": FloatDistribution(1e-4, 1e-2, log=True), "batch_size": IntDistribution(32, 256)}
    trials = [
        (TrialState.COMPLETE, 24066.0, {"lr": 1e-3, "batch_size": 64}, [22000.0, 26132.0]),
        (TrialState.PRUNED, None, {"lr": 5e-3, "batch_size": 200}, [60000.0]),
        (TrialState.COMPLETE, 19800.0, {"lr": 2e-3, "batch_size": 128}, [18000.0, 21600.0]),
        (TrialState.FAIL, None, {"lr": 3e-4, "batch_size": 32}, []),
    ]
    for state, value, params, costs in trials:
        attrs: dict[str, Any] = {}
        for seed, cost in enumerate(costs):
            attrs[f"cost_seed{seed}"] = cost
            attrs[f"run_seed{seed}"] = str(
                folder / "runs" / f"CartPole-v1__dqn__s{seed}__20261123-1000{seed}0"
            )
        study.add_trial(
            create_trial(
                state=state,
                value=value,
                params=params,
                distributions=distributions,
                user_attrs=attrs,
                intermediate_values={0: costs[0]} if state == TrialState.PRUNED else None,
            )
        )
    (folder / "best.toml").write_text(
        f'description = "cartpole sweep {name} (dqn, from preset dqn-base.toml): trial 2"\n'
        'lr = 0.002\nbatch_size = 128\nbudget = "30000"\n',
        "utf-8",
    )
    return name


def make_single_generation_run(runs_dir: Path, cem_run: Path) -> str:
    """A CEM run that solved in its first generation: every metrics row at one env step. Its config
    records a --budget that replaced the preset's (settings.budget "50gen", budget 20,000 env steps)."""
    run = RunDir.create(runs_dir, "CartPole-v1", "cem", 11)
    config = RunDir(cem_run).config()
    settings = {**config.get("settings", {}), "budget": "50gen"}
    run.write_config({**config, "seed": 11, "settings": settings, "budget": {"env_steps": 20000}})
    step = 5726
    run.append_metrics(
        [
            {"step": step, "episode": 64, "time": 1.0, "eval/mean_return": 500.0, "eval/episodes": 20},
            {"step": step, "episode": 64, "time": 1.0, "train/iteration": 1, "train/mean_return": 89.5},
            {"step": step, "episode": 64, "time": 2.0, "eval/mean_return": 498.0, "eval/episodes": 100},
        ]
    )
    run.write_status({"state": "finished", "env_steps": step, "episodes": 64, "solved": True})
    shutil.copy(cem_run / "checkpoints" / "best.pt", run.checkpoint_path("best"))
    shutil.copy(cem_run / "eval.json", run.path / "eval.json")
    return run.name
