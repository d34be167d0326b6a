"""Presets for other envs than CartPole reach their env's registry threshold (slow: minutes)."""

from __future__ import annotations

import pytest

from cartpole.training import train
from cartpole.training.session import train_population


@pytest.mark.slow  # not marked `learning`: CEM is numpy, so torch's other float kernels change nothing
def test_cem_mountaincar_preset_solves_mountaincar_on_most_seeds(tmp_path):
    """``cartpole train cem --env MountainCar-v0 --preset mountaincar``: a verified solve (100 fresh
    episodes, mean >= -110) on 2 of 3 seeds within the preset's budget. The best linear policies average
    about -106, so the margin is narrow: a statistic over seeds, not one seed's path."""
    solved = []
    for seed in (0, 1, 2):
        outcome = train("cem", "MountainCar-v0", seed=seed, preset="mountaincar", runs_dir=tmp_path)
        assert outcome.report is not None
        solved.append(outcome.report.solved)
    assert sum(solved) >= 2, solved


@pytest.mark.slow
@pytest.mark.learning
def test_dqn_mountaincar_preset_reaches_the_flag_on_every_seed_and_solves_on_some(tmp_path):
    """``cartpole train dqn --env MountainCar-v0 --preset mountaincar`` (the RL Zoo's settings), seeds
    0-2 trained as one population: every seed's verdict well above -200 (its greedy policy drives up
    to the flag) and at least one verified solve (mean >= -110). Measured: -141.2, -108.9 and -99.8;
    unseen seeds 9300-9306 solved 7 of 7 (benchmarks/README.md#other-envs). The preset before this
    one ended at -200 on some seeds."""
    outcome = train_population("dqn", [0, 1, 2], "MountainCar-v0", preset="mountaincar", runs_dir=tmp_path)
    means = {seed: report.mean for seed, report in outcome.reports.items()}
    assert len(means) == 3
    assert all(mean >= -160 for mean in means.values()), means
    assert any(report.solved for report in outcome.reports.values()), means
