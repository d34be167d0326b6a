"""``cartpole plot``: one run, several runs aggregated, and the numbers behind the curves."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest
from PIL import Image

from cartpole.cli.main import main
from cartpole.plotting import PlotError, bootstrap_band, load_run, moving_average, plot_runs
from cartpole.runs import RunDir


def fake_run(
    runs_dir, agent: str, seed: int, episodes: int = 150, solved: bool = False, env_id: str = "CartPole-v1"
) -> RunDir:
    """A run folder with per-episode rows that improve, and an evaluation every 50 episodes."""
    run = RunDir.create(runs_dir, env_id, agent, seed)
    run.write_config({"agent": agent, "env_id": env_id, "seed": seed})
    rng = np.random.default_rng(seed)
    rows, step = [], 0
    for episode in range(1, episodes + 1):
        ret = float(min(500, 10 + 3 * episode + rng.integers(0, 40)))
        step += int(ret)
        rows.append({"step": step, "episode": episode, "time": episode / 10, "train/episode_return": ret})
        if episode % 50 == 0:
            mean = min(500.0, 3.5 * episode)
            rows.append(
                {
                    "step": step,
                    "episode": episode,
                    "time": episode / 10,
                    "eval/mean_return": mean,
                    "eval/std_return": 20.0,
                    "eval/episodes": 100,
                    "eval/solved": solved and episode == episodes,
                }
            )
    run.append_metrics(rows)
    run.write_status({"state": "finished", "solved": solved})
    run.write_eval(
        {
            "solved": solved,
            "verdict": "solved" if solved else "not solved",
            "mean": 500.0 if solved else 150.0,
        }
    )
    return run


def test_moving_average_and_bootstrap_band():
    assert moving_average(np.array([1.0, 3.0, 5.0, 7.0]), 2).tolist() == [1.0, 2.0, 4.0, 6.0]
    curves = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    mean, low, high = bootstrap_band(curves)
    assert mean.tolist() == [3.0, 4.0]
    assert np.all(low <= mean) and np.all(mean <= high) and np.all(low >= 1) and np.all(high <= 6)
    same = bootstrap_band(np.ones((4, 3)))
    assert np.allclose(same[1], 1) and np.allclose(same[2], 1)


def test_load_run_reads_train_and_eval_series(tmp_path):
    run = fake_run(tmp_path, "dqn", 0, solved=True)
    curves = load_run(run.path)
    assert curves.unit == "episode" and curves.returns.size == 150 and curves.eval_mean.size == 3
    assert curves.threshold == 475 and curves.solved and curves.eval_solved.tolist() == [False, False, True]


def test_plot_one_real_run(cem_run, tmp_path):
    out = plot_runs([cem_run], tmp_path / "one.png")
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size[0] >= 1000 and out.stat().st_size > 20_000
    assert load_run(cem_run).unit == "generation"


def test_plot_several_runs_aggregated_and_mixed_agents(tmp_path):
    runs = [fake_run(tmp_path / "runs", "dqn", s, solved=s == 0).path for s in range(3)]
    out = plot_runs(runs, tmp_path / "agg.png", x_axis="episodes")
    with Image.open(out) as image:
        assert image.size[0] >= 1000
    fake_run(tmp_path / "runs", "cem", 7, episodes=60)
    svg = plot_runs([tmp_path / "runs"], tmp_path / "all.svg")  # a folder of runs: all of them
    text = svg.read_text()
    assert "<svg" in text and len(text) > 10_000


def test_runs_of_two_envs_get_a_panel_each_with_its_own_legend(tmp_path):
    for agent in ("dqn", "ppo", "a2c", "cem"):
        fake_run(tmp_path / "runs", agent, 0)
    fake_run(tmp_path / "runs", "ppo", 1, env_id="Acrobot-v1")
    with matplotlib.rc_context({"svg.fonttype": "none"}):  # text as text, to be read back
        svg = plot_runs([tmp_path / "runs"], tmp_path / "all.svg").read_text()
    assert "CartPole-v1: a2c (1 run), cem (1 run), dqn (1 run), ppo (1 run)" in svg
    assert "Acrobot-v1__ppo__s1__" in svg  # a panel of one run is titled by its name
    assert svg.count("solved threshold 475") == 1 and "solved threshold -100" in svg


def test_more_agents_than_colors_in_one_panel_is_a_clear_error(tmp_path):
    agents = [f"agent{i}" for i in range(10)]
    for agent in agents:
        fake_run(tmp_path / "runs", agent, 0)
    with pytest.raises(PlotError, match="10 agents on CartPole-v1 are more than one figure can tell apart"):
        plot_runs([tmp_path / "runs"], tmp_path / "all.png")


def test_plot_cli(cem_run, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["plot", str(cem_run)]) == 0  # default: <run name>.png in the current folder
    assert (tmp_path / f"{cem_run.name}.png").stat().st_size > 0
    assert main(["plot", str(cem_run), "--out", "x.png", "--x", "episodes", "--window", "3"]) == 0
    assert "wrote x.png" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "plot.jpg"], "use a .png, .svg or .pdf"),
        (["--window", "0"], "--window must be >= 1"),
    ],
)
def test_plot_bad_input_is_one_line(cem_run, tmp_path, capsys, args, message):
    assert main(["plot", str(cem_run), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_plot_not_a_run(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "nope")]) == 2
    assert "not a run folder" in capsys.readouterr().err
