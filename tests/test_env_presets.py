"""Presets for other envs than CartPole reach their env's registry threshold (slow: minutes)."""

from __future__ import annotations

import numpy as np
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
@pytest.mark.timeout(1200)  # about 5 minutes alone; more under other float kernels or beside other work
def test_dqn_mountaincar_preset_solves_some_seeds(tmp_path):
    """``cartpole train dqn --env MountainCar-v0 --preset mountaincar`` (the RL Zoo's settings), seeds
    0-2 trained as one population: at least one verified solve and a median verdict >= -125.
    Measured: -141.2, -108.9, -99.8; with ``ATEN_CPU_CAPABILITY=default`` -105.6, -200.0 (seed 1 never
    drove up to the flag greedily within the budget), -103.4. Unseen seeds:
    benchmarks/README.md#mountaincar."""
    outcome = train_population("dqn", [0, 1, 2], "MountainCar-v0", preset="mountaincar", runs_dir=tmp_path)
    means = {seed: report.mean for seed, report in outcome.reports.items()}
    assert len(means) == 3
    assert float(np.median(list(means.values()))) >= -125, means
    assert any(report.solved for report in outcome.reports.values()), means


@pytest.mark.slow
@pytest.mark.learning
def test_ppo_mountaincar_preset_solves_most_seeds(tmp_path):
    """``cartpole train ppo --env MountainCar-v0 --preset mountaincar`` (observations standardized),
    seeds 0-4 as one population: at least 2 verified solves and a median verdict >= -125. Seeds 0-2
    under the three float paths CI runs: 7 of 9 solved, the others -111.8 and -167.3 (PPO can lose
    what it found). Unseen seeds: benchmarks/README.md#mountaincar."""
    seeds = [0, 1, 2, 3, 4]
    outcome = train_population("ppo", seeds, "MountainCar-v0", preset="mountaincar", runs_dir=tmp_path)
    means = {seed: report.mean for seed, report in outcome.reports.items()}
    assert len(means) == 5
    assert float(np.median(list(means.values()))) >= -125, means
    assert sum(report.solved for report in outcome.reports.values()) >= 2, means


@pytest.mark.slow
@pytest.mark.learning
@pytest.mark.parametrize("agent", ["a2c", "reinforce", "ppo"])
def test_acrobot_presets_solve_most_seeds(tmp_path, agent):
    """``cartpole train a2c|reinforce|ppo --env Acrobot-v1 --preset acrobot`` (A2C: an entropy bonus;
    REINFORCE also a larger step; PPO: its former 64x64 default), seeds 0-4 as one population: at least
    3 verified solves (100 fresh episodes, mean >= -100) and a median verdict >= -110. Measured: with
    one torch thread, A2C solved at least 4 of 5 under each of the three float paths CI runs; with two
    threads (other kernels), A2C -83.3, -101.2, -89.3, -97.8, -103.2 (3 of 5), and 5 of 5 with
    ``ATEN_CPU_CAPABILITY=default``; REINFORCE 5 of 5 in both, -97.3 the worst; PPO 5 of 5 with one
    thread and with ``MKL_CBWR=COMPATIBLE`` (-100.0 the worst), 4 of 5 with ``ATEN_CPU_CAPABILITY=default``
    (seed 0 at -500). Their default presets leave some seeds at -500, never swinging up. Unseen seeds:
    benchmarks/README.md#acrobot."""
    seeds = [0, 1, 2, 3, 4]
    outcome = train_population(agent, seeds, "Acrobot-v1", preset="acrobot", runs_dir=tmp_path)
    means = {seed: report.mean for seed, report in outcome.reports.items()}
    assert len(means) == 5
    assert float(np.median(list(means.values()))) >= -110, means
    assert sum(report.solved for report in outcome.reports.values()) >= 3, means
