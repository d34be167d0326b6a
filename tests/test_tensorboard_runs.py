"""--tensorboard beyond the scalars: a run's settings as hyperparameters with the final verdict as their
metric, and its command as text, read back with TensorBoard's own event reader; in `cartpole.train`,
`compare` and `sweep` too."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("tensorboard")

from cartpole.training.callbacks import VERDICT_METRICS, hparams_of


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, timeout=600
    )


def board(run: Path) -> dict[str, Any]:
    """What TensorBoard reads from a run's tensorboard/: the hyperparameters (its HParams plugin's data),
    the hyperparameters' metric names, the scalars by tag, and the command text."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams.plugin_data_pb2 import HParamsPluginData

    events = EventAccumulator(str(run / "tensorboard"))
    events.Reload()
    plugin = {
        tag: HParamsPluginData.FromString(content)
        for tag, content in events.PluginTagToContent("hparams").items()
    }
    start = plugin["_hparams_/session_start_info"].session_start_info.hparams
    hparams = {key: value.string_value or value.number_value for key, value in start.items()}
    metrics = [m.name.tag for m in plugin["_hparams_/experiment"].experiment.metric_infos]
    scalars = {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}
    (text,) = events.Tensors("command/text_summary")
    return {
        "hparams": hparams,
        "metrics": metrics,
        "scalars": scalars,
        "command": text.tensor_proto.string_val[0].decode(),
    }


def run_folders(runs_dir: Path) -> list[Path]:
    return sorted(p.parent for p in runs_dir.glob("*/config.json"))


def test_settings_are_flattened_into_the_types_tensorboard_takes():
    record = {
        "agent": "dqn", "seed": 3, "preset": "default", "device": "cpu", "command": ["not", "a", "setting"],
        "config": {"lr": 0.001, "hidden": [64, 64], "double": True, "clip": None},
        "settings": {"env_kwargs": {"sutton_barto_reward": True}, "wrappers": []},
        "budget": {"env_steps": 50000},
    }  # fmt: skip
    assert hparams_of(record) == {
        "agent": "dqn", "seed": 3, "preset": "default", "device": "cpu",
        "config/lr": 0.001, "config/hidden": "[64, 64]", "config/double": True,
        "settings/env_kwargs/sutton_barto_reward": True, "settings/wrappers": "[]",
        "budget/env_steps": 50000,
    }  # fmt: skip


def test_a_run_logs_its_settings_with_the_verdict_as_their_metric_and_its_command(tmp_path: Path):
    from cartpole.training import train

    command = ["cartpole", "train", "cem", "--budget", "2gen", "--tensorboard"]
    outcome = train("cem", seed=4, budget="2gen", runs_dir=tmp_path, tensorboard=True, command=command)
    seen = board(outcome.run.path)
    config = json.loads((outcome.run.path / "config.json").read_text())
    assert seen["hparams"]["agent"] == "cem" and seen["hparams"]["seed"] == 4
    assert seen["hparams"]["config/population"] == config["config"]["population"]
    assert seen["hparams"]["settings/eval_simulator"] == config["settings"]["eval_simulator"]
    assert seen["metrics"] == list(VERDICT_METRICS)
    verdict = json.loads((outcome.run.path / "eval.json").read_text())
    steps = outcome.state.env_steps
    assert seen["scalars"]["verdict/mean_return"] == [(steps, pytest.approx(verdict["mean"]))]
    assert seen["scalars"]["verdict/solved"] == [(steps, float(verdict["solved"]))]
    assert seen["command"].strip() == "cartpole train cem --budget 2gen --tensorboard"


def test_notebook_train_takes_tensorboard(tmp_path: Path):
    import cartpole

    with_board = cartpole.train("cem", seed=0, budget="1gen", runs_dir=tmp_path / "a", progress=False,
                                tensorboard=True)  # fmt: skip
    assert board(with_board.path)["hparams"]["agent"] == "cem"
    without = cartpole.train("cem", seed=0, budget="1gen", runs_dir=tmp_path / "b", progress=False)
    assert not (without.path / "tensorboard").exists()


def test_compare_logs_every_run_to_tensorboard(tmp_path: Path):
    runs_dir = tmp_path / "runs"
    args = ["compare", "cem", "--seeds", "2", "--budget", "1gen", "--runs-dir", str(runs_dir)]
    done = run_cli(*args, "--tensorboard")
    assert done.returncode == 0, done.stderr
    runs = run_folders(runs_dir / "experiments" / "cem" / "runs")
    assert len(runs) == 2
    for run in runs:  # a writer per run, in its own folder, as train's
        seen = board(run)
        assert seen["hparams"]["seed"] == json.loads((run / "config.json").read_text())["seed"]
        assert "verdict/mean_return" in seen["scalars"]
        assert (
            seen["command"].split()[:3] == ["cartpole", "compare", "cem"]
            and "--tensorboard" in seen["command"]
        )


def test_sweep_logs_every_trial_run_to_tensorboard(tmp_path: Path):
    runs_dir = tmp_path / "runs"
    args = ["sweep", "cem", "--trials", "1", "--seeds", "1", "--budget", "1gen", "--runs-dir", str(runs_dir)]
    done = run_cli(*args, "--study", "board", "--tensorboard")
    assert done.returncode == 0, done.stderr
    (run,) = run_folders(runs_dir / "sweeps" / "board" / "runs")
    seen = board(run)
    assert seen["hparams"]["agent"] == "cem" and "verdict/mean_return" in seen["scalars"]
    assert seen["command"].startswith("    cartpole sweep cem --study board")
