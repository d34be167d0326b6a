"""One `--seeds` syntax in train, compare and sweep: a number alone is a count (10: seeds 0-9); a
range (0-99), a list (3,5,8) or both (0-9,20) name the seeds. Earlier forms still work (compare's
--first-seed with a count, sweep's --seeds-per-trial) or are refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cartpole.cli.main import main
from cartpole.training.session import parse_seeds


def seeds_of_runs(folder: Path) -> list[int]:
    return sorted(json.loads(p.read_text())["seed"] for p in folder.glob("*/config.json"))


def test_a_number_alone_is_a_count_and_anything_else_names_seeds():
    assert parse_seeds("5") == [0, 1, 2, 3, 4]
    assert parse_seeds(" 2 ") == [0, 1]
    assert parse_seeds("5-5") == [5]  # one seed alone
    assert parse_seeds("3-4") == [3, 4]
    assert parse_seeds("5,8") == [5, 8]
    assert parse_seeds("0-1,7") == [0, 1, 7]


def test_train_takes_a_count(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    args = ["train", "random-search", "--seeds", "3", "--budget", "1gen", "--set", "population=4", "--quiet"]
    assert main([*args, "--runs-dir", str(runs_dir)]) == 0
    assert seeds_of_runs(runs_dir) == [0, 1, 2]
    out = capsys.readouterr().out
    assert "runs: 3 in" in out and "(seeds 0-2)" in out


def test_compare_takes_a_range_and_a_list(tmp_path):
    runs_dir = tmp_path / "runs"
    base = ["compare", "random-search", "--budget", "1gen", "--runs-dir", str(runs_dir)]
    assert main([*base, "--seeds", "3-4", "--name", "r"]) == 0
    assert seeds_of_runs(runs_dir / "experiments" / "r" / "runs") == [3, 4]
    assert main([*base, "--seeds", "2,5", "--name", "l"]) == 0
    report = json.loads((runs_dir / "experiments" / "l" / "report.json").read_text())
    assert report["seeds"] == [2, 5]


def test_compare_keeps_its_count_and_first_seed(tmp_path):
    runs_dir = tmp_path / "runs"
    args = ["compare", "random-search", "--seeds", "2", "--first-seed", "6", "--budget", "1gen"]
    assert main([*args, "--name", "c", "--runs-dir", str(runs_dir)]) == 0
    assert seeds_of_runs(runs_dir / "experiments" / "c" / "runs") == [6, 7]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["compare", "cem", "--seeds", "0-1", "--first-seed", "5"], "--first-seed shifts a count"),
        (["compare", "cem", "--seeds", "1-0"], "is reversed"),
        (
            ["sweep", "cem", "--trials", "1", "--study", "s", "--seeds", "2", "--seeds-per-trial", "2"],
            "not both",
        ),
        (["sweep", "cem", "--trials", "1", "--study", "s", "--seeds", "x"], "'x' is not a seed or a range"),
        (["train", "cem", "--seeds", "0"], "a count of no seeds"),
    ],
)
def test_bad_seeds_are_one_line_and_exit_2(args, message, tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    assert main([*args, "--runs-dir", str(runs_dir)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not runs_dir.exists()


def test_sweep_takes_the_same_syntax(tmp_path):
    runs_dir = tmp_path / "runs"
    args = ["sweep", "random-search", "--trials", "1", "--budget", "1gen", "--runs-dir", str(runs_dir)]
    assert main([*args, "--seeds", "3-4", "--study", "s"]) == 0
    assert seeds_of_runs(runs_dir / "sweeps" / "s" / "runs") == [3, 4]
    spec = json.loads((runs_dir / "sweeps" / "s" / "sweep.json").read_text())
    assert spec["seeds"] == [3, 4] and spec["seeds_per_trial"] == 2
    assert main([*args, "--seeds-per-trial", "1", "--study", "k"]) == 0  # the earlier form
    assert seeds_of_runs(runs_dir / "sweeps" / "k" / "runs") == [0]
