"""Every command end to end in tmp_path, and every bad input: one line, exit 2, no traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from cartpole.cli.main import main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, timeout=300
    )


def test_train_eval_runs_end_to_end(tmp_path):
    runs_dir = tmp_path / "runs"
    done = run_cli("train", "cem", "--seed", "1", "--runs-dir", str(runs_dir))
    assert done.returncode == 0, done.stderr
    assert "SOLVED" in done.stdout
    # Two different claims, each named: the in-training solve, and the verdict on the kept best policy.
    assert "solved in training: first at " in done.stdout
    assert "verdict on the best checkpoint (kept at env step " in done.stdout
    assert "judged on 100 fresh episodes:" in done.stdout
    (run,) = runs_dir.iterdir()
    assert run.name.startswith("CartPole-v1__cem__s1__")
    names = {p.name for p in run.iterdir()} | {p.name for p in (run / "checkpoints").iterdir()}
    assert {"config.json", "status.json", "metrics.jsonl", "eval.json", "latest.pt", "best.pt"} <= names
    config = json.loads((run / "config.json").read_text())
    assert config["command"][:3] == ["cartpole", "train", "cem"]
    assert json.loads((run / "eval.json").read_text())["solved"] is True

    listed = run_cli("runs", "--runs-dir", str(runs_dir))
    assert listed.returncode == 0 and "cem" in listed.stdout and "yes" in listed.stdout

    evaluated = run_cli("eval", str(run), "--episodes", "100", "--seed", "5", "--json")
    report = json.loads(evaluated.stdout)
    assert report["solved"] and report["seeds"][0] == 5 and report["simulator"] == "gymnasium"


def test_in_process_commands(cem_run, capsys):
    assert main(["eval", str(cem_run / "checkpoints" / "best.pt"), "--episodes", "10"]) == 0
    assert "CANNOT CALL SOLVED" in capsys.readouterr().out
    assert main(["runs", "--runs-dir", str(cem_run.parent), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["agent"] == "cem"
    assert main(["presets"]) == 0
    assert "tutorial" in capsys.readouterr().out
    assert main(["runs", "--runs-dir", str(cem_run.parent / "empty")]) == 0
    assert "no runs" in capsys.readouterr().out


def bad_checkpoints(tmp_path: Path, cem_run: Path) -> dict[str, Path]:
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes((cem_run / "checkpoints" / "best.pt").read_bytes()[:200])
    foreign = tmp_path / "foreign.pt"
    foreign.write_text("not a checkpoint at all")
    return {"missing": tmp_path / "missing.pt", "truncated": truncated, "foreign": foreign,
            "not-a-run": tmp_path}  # fmt: skip


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["train", "nope"], "invalid choice: 'nope'"),
        (["train", "cem", "--env", "NoSuchEnv-v9"], "unknown environment 'NoSuchEnv-v9'"),
        (["train", "cem", "--env", "Pendulum-v1"], "Discrete actions"),
        (["train", "cem", "--seed", "x"], "invalid int value"),
        (["train", "cem", "--seed", "-1"], "seed must be between"),
        (["train", "cem", "--budget", "lots"], "bad budget"),
        (["train", "cem", "--preset", "nope"], "unknown preset 'nope'"),
        (["train", "cem", "--set", "population"], "--set expects KEY=VALUE"),
        (["train", "cem", "--set", "population=-3"], "population must be >= 1"),
        (["train", "cem", "--set", "speed=3"], "unknown setting 'speed'"),
        (["train", "--resume", "/no/such/run"], "is not a run folder"),
        (["eval", "x", "--episodes", "0"], "--episodes must be between 1 and 1,000,000"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path):
    done = run_cli(*args, "--runs-dir", str(tmp_path)) if args[0] == "train" else run_cli(*args)
    assert done.returncode == 2
    assert message in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir()), "bad input must not create a run folder"


@pytest.mark.parametrize("kind", ["missing", "truncated", "foreign", "not-a-run"])
def test_bad_checkpoints(kind, tmp_path, cem_run, capsys):
    path = bad_checkpoints(tmp_path, cem_run)[kind]
    assert main(["eval", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cartpole eval: error: ") and len(err.strip().splitlines()) == 1
    assert (cem_run / "checkpoints" / "best.pt").is_file()


@pytest.mark.parametrize(
    "command", ["train", "eval", "runs", "presets", "plot", "record", "serve", "compare", "sweep", "export"]
)
def test_help_prints_its_text_as_written(command, capsys):
    """argparse leaves a description as it is: a "%%" meant for a help string shows up doubled."""
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert f"usage: cartpole {command}" in out and "%%" not in out


def test_the_parser_imports_no_database_or_web_library():
    """Every command builds the whole parser first: SQLAlchemy, Optuna and FastAPI (slow imports) wait
    for the commands that use them."""
    code = (
        "import sys\nfrom cartpole.cli.main import build_parser\nbuild_parser()\n"
        "print(sorted(m for m in ('sqlalchemy', 'optuna', 'fastapi', 'matplotlib') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize(("env_id", "threads"), [("CartPole-v1", 1), ("cartpole/CartPolePixels-v1", 3)])
def test_train_takes_one_torch_thread_on_states_and_leaves_the_count_on_images(env_id, threads, capsys):
    """Without --torch-threads, `cartpole train` sets torch to one thread for the small networks on
    state observations, and leaves it as it is (torch's default: one per core) on images."""
    torch.set_num_threads(3)
    assert main(["train", "ppo", "--env", env_id, "--budget", "never"]) == 2  # refused after the setup
    assert "bad budget 'never'" in capsys.readouterr().err
    assert torch.get_num_threads() == threads
