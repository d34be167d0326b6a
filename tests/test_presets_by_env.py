"""Presets follow the env: one table (presets/by_env.toml) picks an agent's preset when none is named,
for `cartpole train`, compare entries, sweeps and cartpole.train alike, and says which; a preset made
for another kind of observation than the env gives is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import cartpole
from cartpole.cli.main import main
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.experiments.entries import Entry, ExperimentError, parse_entries

PIXELS = "cartpole/CartPolePixels-v1"


def the_config(runs_dir: Path) -> dict:
    (config,) = runs_dir.glob("*/config.json")
    return json.loads(config.read_text())


def test_cartpole_presets_shows_the_table(capsys):
    assert main(["presets"]) == 0
    out = capsys.readouterr().out
    assert "presets by env" in out and "by_env.toml" in out
    assert f"{PIXELS}: dqn pixels, ppo pixels" in out
    assert "MountainCar-v0: dqn mountaincar, ppo mountaincar" in out
    assert "Acrobot-v1: ppo acrobot, a2c acrobot, reinforce acrobot" in out
    assert main(["presets", "cem"]) == 0
    assert "MountainCar-v0: cem mountaincar" in capsys.readouterr().out


def test_train_without_a_preset_takes_the_envs_and_says_which_in_one_line(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    args = ["train", "cem", "--env", "MountainCar-v0", "--budget", "1gen", "--runs-dir", str(runs_dir)]
    cheap = ["--set", "population=4", "--set", "episodes_per_candidate=1", "--set", "eval_screen_episodes=2"]
    assert main([*args, *cheap, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert the_config(runs_dir)["preset"] == "mountaincar"
    assert [line for line in out.splitlines() if line.startswith("preset:")] == [
        "preset: mountaincar (cem's preset for MountainCar-v0, by_env.toml; --preset NAME for another)"
    ]


def test_train_on_cartpole_keeps_the_default_and_says_nothing_of_it(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    args = ["train", "random-search", "--budget", "1gen", "--set", "population=4", "--quiet"]
    assert main([*args, "--runs-dir", str(runs_dir)]) == 0
    assert the_config(runs_dir)["preset"] == "default"
    assert "preset:" not in capsys.readouterr().out


def test_ppo_on_pixels_without_a_preset_trains_and_judges_as_the_pixels_preset(tmp_path, capsys):
    """`cartpole train ppo --env cartpole/CartPolePixels-v1` is `--preset pixels`: its settings, its
    verdict on Gymnasium's own pictures. (Before, the state preset trained and the run ended at 9.45.)"""
    runs_dir = tmp_path / "runs"
    args = ["train", "ppo", "--env", PIXELS, "--seed", "3", "--budget", "512", "--runs-dir", str(runs_dir)]
    assert main([*args, "--quiet"]) == 0
    assert "preset: pixels (ppo's preset for cartpole/CartPolePixels-v1" in capsys.readouterr().out
    config = the_config(runs_dir)
    assert config["preset"] == "pixels" and config["config"]["num_envs"] == 32
    assert config["settings"]["verdict_simulator"] == "gymnasium"
    verdict = json.loads(next(runs_dir.glob("*/eval.json")).read_text())
    assert (verdict["env_id"], verdict["simulator"], verdict["episodes"]) == (PIXELS, "gymnasium", 100)


@pytest.mark.parametrize(
    ("agent", "env_id", "preset", "message"),
    [
        ("ppo", "CartPole-v1", "pixels", "made for image observations"),
        ("dqn", "Acrobot-v1", "tutorial-pytorch-pixels", "made for image observations"),
        ("ppo", PIXELS, "default", "made for state vectors, but cartpole/CartPolePixels-v1's observations"),
        ("dqn", PIXELS, "mountaincar", "use --preset pixels or tutorial-pytorch-pixels"),
        ("a2c", PIXELS, None, "a2c has no preset for images"),
    ],
)
def test_a_preset_for_another_kind_of_observation_is_refused_in_one_line(
    agent, env_id, preset, message, tmp_path, capsys
):
    runs_dir = tmp_path / "runs"
    named = [] if preset is None else ["--preset", preset]
    args = ["train", agent, "--env", env_id, *named, "--budget", "64", "--runs-dir", str(runs_dir)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not runs_dir.exists()


def test_a_preset_file_is_taken_as_it_is_on_any_env(tmp_path):
    from cartpole.agents.presets import resolve_preset

    assert resolve_preset("ppo", env_info(PIXELS), "mine.toml") == "mine.toml"
    assert resolve_preset("ppo", env_info("CartPole-v1"), "mine.toml") == "mine.toml"
    with pytest.raises(ConfigError, match="made for image observations"):
        resolve_preset("ppo", env_info("CartPole-v1"), "pixels")


def test_compare_entries_pick_their_presets_as_train_does():
    entries = parse_entries(["ppo", "dqn:pixels", "dqn:tutorial-pytorch-pixels"], PIXELS)
    assert entries == [
        Entry("ppo", "pixels"),
        Entry("dqn", "pixels"),
        Entry("dqn", "tutorial-pytorch-pixels"),
    ]
    assert [e.picked for e in entries] == [True, False, False]
    assert [e.label for e in parse_entries(["a2c", "cem"], "Acrobot-v1")] == ["a2c:acrobot", "cem"]
    with pytest.raises(ExperimentError, match=r"entry 'ppo:default'.*made for state vectors"):
        parse_entries(["ppo:default"], PIXELS)


def test_compare_refuses_a_preset_for_another_kind_of_observation_in_one_line(tmp_path, capsys):
    runs_dir = tmp_path / "runs"
    assert main(["compare", "ppo:pixels", "--budget", "256", "--runs-dir", str(runs_dir)]) == 2
    err = capsys.readouterr().err
    assert "made for image observations" in err and len(err.strip().splitlines()) == 1, err
    assert not runs_dir.exists()


def test_a_sweep_without_a_preset_tunes_from_the_envs(tmp_path, capsys):
    from cartpole.experiments.sweep import make_spec

    spec = make_spec(tmp_path, "s", "ppo", None, 2, [0, 1], env_id="MountainCar-v0")
    assert spec.preset == "mountaincar"
    assert make_spec(tmp_path, "s", "ppo", None, 2, [0, 1]).preset == "default"
    args = [
        "sweep",
        "ppo",
        "--preset",
        "pixels",
        "--trials",
        "1",
        "--study",
        "s",
        "--runs-dir",
        str(tmp_path),
    ]
    assert main(args) == 2
    assert "made for image observations" in capsys.readouterr().err


def test_the_notebook_api_picks_the_preset_as_the_command_does(tmp_path, capsys):
    run = cartpole.train("a2c", "Acrobot-v1", budget="256", runs_dir=tmp_path, progress=False)
    assert run.summary.preset == "acrobot"
    ppo = cartpole.train(
        "ppo", "Acrobot-v1", preset="default", budget="256", runs_dir=tmp_path, progress=False
    )
    assert ppo.summary.preset == "default"
