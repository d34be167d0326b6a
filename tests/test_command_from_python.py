"""A run started from Python (``cartpole.train`` in a notebook, ``cartpole.training.train`` in a script)
records the ``cartpole train`` command that starts the same run, as the CLI would write it, not the
Python process's command line (a kernel's, or ``-``): TensorBoard's command text and a hub card's "How
it was trained" show it. Running that command gives the same run."""

from __future__ import annotations

import json
from pathlib import Path

from cartpole.training.budget import Budget


def config_of(run: Path) -> dict:  # type: ignore[type-arg]
    return json.loads((run / "config.json").read_text())


def test_a_notebook_run_records_the_command_that_trains_it_again(tmp_path: Path):
    import cartpole
    from cartpole.cli.main import main

    run = cartpole.train("cem", seed=3, budget="2gen", runs_dir=tmp_path / "a", progress=False, population=8)
    command = config_of(run.path)["command"]
    assert command == ["cartpole", "train", "cem", "--seed", "3", "--budget", "2gen", "--set", "population=8",
                       "--runs-dir", str(tmp_path / "a")]  # fmt: skip
    again = [*command[1:-1], str(tmp_path / "b")]  # the same command, another runs folder
    assert main(again) == 0
    (other,) = (tmp_path / "b").iterdir()
    fields = ("agent", "env_id", "seed", "preset", "config", "settings", "budget")
    assert {k: config_of(other)[k] for k in fields} == {k: config_of(run.path)[k] for k in fields}
    verdicts = [json.loads((folder / "eval.json").read_text())["mean"] for folder in (run.path, other)]
    assert verdicts[0] == verdicts[1]


def test_a_script_records_every_choice_as_the_cli_would_write_it(tmp_path: Path):
    from cartpole.training.session import python_command

    command = python_command(
        "dqn", [3], "Acrobot-v1", "default", {"lr": 0.001, "hidden_sizes": [64, 64]},
        Budget(env_steps=5000), tmp_path, "cpu", False, True, False,
    )  # fmt: skip
    assert command == [
        "cartpole", "train", "dqn", "--seed", "3", "--env", "Acrobot-v1", "--preset", "default",
        "--budget", "5000", "--set", "lr=0.001", "--set", "hidden_sizes=[64, 64]", "--runs-dir",
        str(tmp_path), "--device", "cpu", "--no-stop-when-solved", "--tensorboard",
    ]  # fmt: skip
    kwargs = python_command("cem", [0], "CartPole-v1", None, {"env_kwargs": {"sutton_barto_reward": True,
                            "label": "5"}}, None, "runs", "auto", True, False, False)  # fmt: skip
    assert kwargs == ["cartpole", "train", "cem", "--seed", "0", "--set", "stop_when_solved=true",
                      "--env-kwargs", "sutton_barto_reward=true", 'label="5"']  # fmt: skip


def test_a_population_from_python_records_its_seeds(tmp_path: Path):
    from cartpole.training.session import python_command, train_population

    outcome = train_population("random-search", [0, 1, 2, 7], budget=Budget(iterations=1), runs_dir=tmp_path)
    command = config_of(outcome.runs[7].path)["command"]
    assert command == ["cartpole", "train", "random-search", "--seeds", "0-2,7", "--budget", "1gen",
                       "--runs-dir", str(tmp_path)]  # fmt: skip
    alone = python_command("cem", [5], "CartPole-v1", None, None, "90s", "runs", "auto", None, False, True)
    assert alone[3:5] == ["--seeds", "5-5"]  # --seeds 5 would be a count: seeds 0-4
