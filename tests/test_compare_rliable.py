"""compare's rliable views: the score matrix, performance profiles and the probability of improvement,
checked against rliable's own definitions (metrics.probability_of_improvement,
library.create_performance_profile and its bootstraps) on small fixed inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from cartpole.experiments.entries import Entry
from cartpole.experiments.figures import EvalCurve
from cartpole.experiments.report import Results, write_report
from cartpole.experiments.stats import (
    improvement_probability,
    improvement_summary,
    performance_profile,
    profile_taus,
)


def test_probability_of_improvement_counts_pairs_with_ties_half():
    x, y = np.array([1.0, 2, 3, 3, 5]), np.array([0.0, 3, 4])
    # by hand: 1 beats 0; 2 beats 0; each 3 beats 0 and ties 3 (1.5); 5 beats all three: 8 of 15 pairs
    assert improvement_probability(x, y) == pytest.approx(8 / 15)
    # rliable's own formula: scipy's Mann-Whitney U of x over y, divided by n * m
    assert improvement_probability(x, y) == pytest.approx(
        mannwhitneyu(x, y, alternative="greater").statistic / 15
    )
    assert improvement_probability(y, x) == pytest.approx(1 - 8 / 15)


def test_probability_of_improvement_of_equal_or_separated_runs():
    assert improvement_summary([500.0] * 4, [500.0] * 4) == {"probability": 0.5, "ci95": [0.5, 0.5]}
    assert improvement_summary([499.0, 500.0], [9.0, 10.0, 11.0]) == {"probability": 1.0, "ci95": [1.0, 1.0]}
    assert improvement_summary([1.0], [2.0]) == {"probability": 0.0, "ci95": None}  # one run: no CI
    assert improvement_summary([], [2.0]) == {"probability": None, "ci95": None}


def rliable_independent_bootstrap(x: np.ndarray, y: np.ndarray, reps: int, seed: int) -> list[float]:
    """rliable's StratifiedIndependentBootstrap with one task, percentile interval, written as a loop."""
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(reps):
        a, b = rng.choice(x, x.size), rng.choice(y, y.size)
        values.append(mannwhitneyu(a, b, alternative="greater").statistic / (a.size * b.size))
    return [float(v) for v in np.percentile(values, [2.5, 97.5])]


def test_probability_of_improvement_ci_is_rliables_bootstrap():
    x = np.array([480.0, 500, 500, 310, 495, 500, 470, 500, 250, 500])
    y = np.array([500.0, 420, 300, 500, 180, 460, 500, 390, 440, 475])
    summary = improvement_summary(x, y)
    low, high = rliable_independent_bootstrap(x, y, 2000, seed=1)
    assert summary["probability"] == pytest.approx(mannwhitneyu(x, y, alternative="greater").statistic / 100)
    assert summary["ci95"][0] == pytest.approx(low, abs=0.04)
    assert summary["ci95"][1] == pytest.approx(high, abs=0.04)
    assert summary["ci95"][0] < summary["probability"] < summary["ci95"][1]


def test_performance_profile_is_the_fraction_of_runs_above_each_tau():
    scores = [100.0, 200, 300, 400, 500]
    profile = performance_profile(scores, np.array([0.0, 100, 250, 500]))
    # rliable's run_score_deviation: np.mean(scores > tau), strictly above
    assert profile["fraction"] == [1.0, 0.8, 0.6, 0.0]
    assert profile["ci95_low"][0] == profile["ci95_high"][0] == 1.0  # every resample is above 0
    assert profile["ci95_low"][1] < 0.8 < profile["ci95_high"][1] or profile["ci95_high"][1] == 1.0
    assert profile["ci95_low"][-1] == profile["ci95_high"][-1] == 0.0
    one = performance_profile([450.0], np.array([400.0, 500]))
    assert one == {"fraction": [1.0, 0.0], "ci95_low": [1.0, 0.0], "ci95_high": [1.0, 0.0]}


def test_profile_taus_run_from_below_every_score_to_the_highest_and_take_in_the_threshold():
    taus = profile_taus([200.0, 300.0], [475.0])
    assert taus[0] < 200 and taus[-1] == 475.0 and len(taus) == 101
    assert len(profile_taus([500.0, 500.0])) == 101  # equal scores still give a range


def record(entry: Entry, seed: int, final: float) -> dict[str, object]:
    solved = final >= 475
    return {
        "agent": entry.agent, "preset": entry.preset, "seed": seed, "run": f"/runs/{entry.slug}{seed}",
        "state": "finished", "solved_in_training": solved, "solve_steps": 1000 if solved else None,
        "solve_wall_seconds": 1.0 if solved else None, "solve_cpu_seconds": 1.5 if solved else None,
        "env_steps": 1000 if solved else 5000, "wall_seconds": 2.0, "cpu_seconds": 3.0,
        "final_mean": final, "final_solved": solved,
    }  # fmt: skip


def test_the_report_holds_the_score_matrix_profiles_and_improvements(tmp_path: Path):
    cem, dqn = Entry("cem"), Entry("dqn")
    finals = {cem: {0: 500.0, 1: 480.0, 2: 300.0}, dqn: {0: 200.0, 2: 490.0}}  # dqn's seed 1 not finished
    curve = EvalCurve(np.array([0.0, 1000.0]), np.array([20.0, 500.0]), True, 475.0)
    results = Results(
        "CartPole-v1",
        None,
        [0, 1, 2],
        {e: [record(e, s, v) for s, v in by_seed.items()] for e, by_seed in finals.items()},
        {cem: [curve], dqn: []},
    )
    _, written = write_report(results, tmp_path)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    scores = on_disk["scores"]
    assert scores["entries"] == ["cem", "dqn"] and scores["seeds"] == [0, 1, 2]
    assert scores["matrix"] == [[500.0, 200.0], [480.0, None], [300.0, 490.0]]
    # as rliable reads it: a (runs x tasks) matrix per algorithm, here one task per entry's column
    matrix = np.array(scores["matrix"], dtype=float)
    score_dict = {e: matrix[~np.isnan(matrix[:, i]), i][:, None] for i, e in enumerate(scores["entries"])}
    assert score_dict["dqn"].shape == (2, 1)
    profile = on_disk["performance_profile"]
    assert profile["threshold"] == 475.0 and len(profile["taus"]) == 101
    assert (
        profile["entries"]["cem"]["fraction"][0] == 1.0 and profile["entries"]["dqn"]["fraction"][-1] == 0.0
    )
    (pair,) = on_disk["probability_of_improvement"]
    assert (pair["x"], pair["y"]) == ("cem", "dqn")
    assert pair["probability"] == pytest.approx(4 / 6)  # of 6 pairs: 500 beats both, 480 and 300 beat 200
    assert (tmp_path / "performance_profile.png") in written and (tmp_path / "improvement.png") in written
    text = (tmp_path / "report.md").read_text()
    assert "P(cem > dqn) = 0.67 [" in text and "![improvement](improvement.png)" in text


def test_one_entry_has_a_profile_but_no_improvement_figure(tmp_path: Path):
    cem = Entry("cem")
    results = Results("CartPole-v1", "3gen", [0, 1], {cem: [record(cem, 0, 500.0), record(cem, 1, 20.0)]}, {})
    report, written = write_report(results, tmp_path)
    assert report["probability_of_improvement"] == [] and report["performance_profile"]["threshold"] is None
    assert (tmp_path / "performance_profile.png") in written
    assert not (tmp_path / "improvement.png").exists()
