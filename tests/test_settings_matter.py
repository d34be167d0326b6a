"""Every setting of every agent, and every training setting, changes what happens.

A test that passes whatever a setting says cannot catch the setting being ignored. So:

- a generic test per config field: two learners that differ only in that field, same seed, behave
  differently after a few ``learn()`` calls (results, parameters or greedy scores differ);
- a completeness test: every field of every agent's config is in that table (or is named, with the
  reason, as not applying to the agent), so a new setting cannot arrive without a test;
- semantic tests where the meaning of a setting can be checked exactly (``learning_starts``,
  ``gradient_steps``, the loss, the epsilon schedules, hill climbing's noise adaptation, and each
  ``TrainSettings`` field through :func:`cartpole.training.train`).

Everything goes through public interfaces: the registry's ``config_cls`` and ``make_population`` (a
single run is a population of one), the seed's ``learn``, ``policy``, ``state_dict`` and
``load_state_dict``, ``train`` and run folders.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from one_seed import one_seed

from cartpole.agents.registry import agent_names, get_agent
from cartpole.core.seeding import MAX_TRAIN_SEED, eval_seed, final_eval_seed
from cartpole.envs import env_info
from cartpole.runs import load_checkpoint
from cartpole.training import train

CARTPOLE = env_info("CartPole-v1")
PROBE_OBSERVATIONS = np.random.default_rng(123).normal(scale=0.5, size=(64, 4)).astype(np.float32)
"""Fixed observations on which greedy scores are compared."""

# ----------------------------------------------------------------------------------------------
# The table: per agent, a small base config, and for each field another value (plus, where a field
# only acts together with another one, the base changes both learners share)
# ----------------------------------------------------------------------------------------------

DQN_BASE: dict[str, Any] = {
    "hidden_sizes": (16, 16),
    "num_envs": 2,
    "learning_starts": 16,
    "batch_size": 16,
    "buffer_size": 500,
    "gradient_steps": 1,
    "epsilon_decay_steps": 200,
    "tau": 0.1,
}
LINEAR_BASE: dict[str, Any] = {"population": 6, "episodes_per_candidate": 2}

Change = tuple[dict[str, Any], Any]
"""(base changes both learners share, the other value of the field)."""

DQN_CHANGES: dict[str, Change] = {
    "hidden_sizes": ({}, (16,)),
    "activation": ({}, "tanh"),
    "dropout": ({}, 0.3),
    "dueling": ({}, True),
    "lr": ({}, 1e-2),
    "lr_schedule": ({"schedule_steps": 100}, "linear"),
    "schedule_steps": ({"lr_schedule": "linear"}, 50),
    "gamma": ({}, 0.5),
    "loss": ({}, "mse"),
    "max_grad_norm": ({}, 0.05),
    "max_grad_value": ({}, 1e-4),
    "optimizer": ({}, "rmsprop"),
    # the target net frozen at its start and a fast-moving online net: their argmaxes part early
    "double_dqn": ({"lr": 1e-2, "tau": 1.0, "target_update_interval": 1000}, False),
    "target_network": ({}, False),
    "target_update_interval": ({}, 5),
    "tau": ({}, 0.5),  # the Polyak path (1.0 takes the hard-copy one)
    "buffer_size": ({}, 40),
    "batch_size": ({}, 8),
    "learning_starts": ({}, 0),
    "num_envs": ({}, 3),
    "train_freq": ({}, 2),
    "gradient_steps": ({}, 3),
    "n_step": ({}, 3),
    "epsilon_schedule": ({}, "exponential"),
    "epsilon_start": ({}, 0.5),
    "epsilon_end": ({}, 0.3),
    "epsilon_decay_steps": ({}, 50),
    "epsilon_decay_rate": ({"epsilon_schedule": "multiplicative"}, 0.9),
    "termination_reward": ({}, -10.0),
    "short_episode_reward": ({"short_episode_length": 195}, -1.0),
    "short_episode_length": ({"short_episode_reward": -1.0}, 195),
    "simulator": ({}, "gymnasium"),
}
LINEAR_CHANGES: dict[str, Change] = {
    "population": ({}, 9),
    "episodes_per_candidate": ({}, 1),
    "bias": ({}, True),
    "normalize_observations": ({}, True),
    "init_range": ({}, 2.0),
    "noise": ({}, 0.5),
    "elite_fraction": ({}, 0.5),
    "init_std": ({}, 2.0),
    "extra_std": ({}, 0.5),
    "simulator": ({}, "gymnasium"),
}

PG_BASE: dict[str, Any] = {"hidden_sizes": (16, 16), "num_envs": 4}
"""Policy-gradient agents (REINFORCE, A2C, PPO): the shared settings' base."""
PPO_BASE: dict[str, Any] = PG_BASE | {"n_steps": 16, "minibatch_size": 16, "n_epochs": 2}
A2C_BASE: dict[str, Any] = PG_BASE | {"n_steps": 8}
REINFORCE_BASE: dict[str, Any] = PG_BASE | {"num_envs": 2}
PG_CHANGES: dict[str, Change] = {
    "hidden_sizes": ({}, (16,)),
    "activation": ({}, "relu"),
    "shared_trunk": ({}, True),
    "orthogonal_init": ({}, False),
    "observation_mean": ({}, (0.3, -0.3, 0.3, -0.3)),
    "observation_std": ({}, (0.2, 0.2, 0.2, 0.2)),
    "num_envs": ({}, 3),
    "gamma": ({}, 0.5),
    "lr": ({}, 1e-2),
    "lr_schedule": ({"schedule_steps": 100}, "linear"),
    "schedule_steps": ({"lr_schedule": "linear"}, 50),
    "ent_coef": ({}, 0.5),
    "vf_coef": ({}, 2.0),
    "max_grad_norm": ({}, 0.01),
    "simulator": ({}, "gymnasium"),
}
PPO_CHANGES: dict[str, Change] = PG_CHANGES | {
    "n_steps": ({}, 8),
    "gae_lambda": ({}, 0.3),
    "n_epochs": ({}, 3),
    "minibatch_size": ({}, 8),
    "clip_range": ({}, 0.01),
    "clip_schedule": ({"schedule_steps": 100}, "linear"),
    "clip_range_vf": ({}, 0.001),
    "target_kl": ({}, 1e-6),
    "normalize_advantages": ({}, False),
    "adam_eps": ({}, 0.1),
}
A2C_CHANGES: dict[str, Change] = PG_CHANGES | {
    "n_steps": ({}, 5),
    "gae_lambda": ({}, 0.5),
    "normalize_advantages": ({}, True),
    "optimizer": ({}, "adam"),
    "rms_alpha": ({}, 0.5),
    "optimizer_eps": ({}, 0.1),
}
REINFORCE_CHANGES: dict[str, Change] = PG_CHANGES | {
    "baseline": ({}, False),
    "normalize_returns": ({}, False),
}

NOT_APPLICABLE: dict[str, dict[str, str]] = {
    "dqn": {
        # (gone once agents stop setting process-wide state; an entry for a missing field is harmless)
        "torch_threads": "a process-wide thread count, not learning behaviour (results do not depend on it)",
        "conv_layers": "image observations only: tests/test_dqn_pixels.py",
        "frame_difference": "image observations only: tests/test_dqn_pixels.py",
    },
    "random-search": {
        "noise": "hill climbing only",
        "elite_fraction": "CEM only",
        "init_std": "CEM only",
        "extra_std": "CEM only",
    },
    "hill-climbing": {"elite_fraction": "CEM only", "init_std": "CEM only", "extra_std": "CEM only"},
    "cem": {"init_range": "random search and hill climbing only", "noise": "hill climbing only"},
    "ppo": {},
    "a2c": {},
    "reinforce": {},
}
BASES = {
    "dqn": DQN_BASE,
    "random-search": LINEAR_BASE,
    "hill-climbing": LINEAR_BASE,
    "cem": LINEAR_BASE,
    "ppo": PPO_BASE,
    "a2c": A2C_BASE,
    "reinforce": REINFORCE_BASE,
}
# Our fast simulator and Gymnasium's env differ only in float rounding, which shows in long episodes:
# hill climbing's small default steps keep its first episodes short, so it searches wider here.
HILL_CLIMBING_CHANGES = LINEAR_CHANGES | {"simulator": ({"population": 16, "noise": 1.0}, "gymnasium")}
CHANGES = {
    "dqn": DQN_CHANGES,
    "random-search": LINEAR_CHANGES,
    "hill-climbing": HILL_CLIMBING_CHANGES,
    "cem": LINEAR_CHANGES,
    "ppo": PPO_CHANGES,
    "a2c": A2C_CHANGES,
    "reinforce": REINFORCE_CHANGES,
}
CALLS = {"dqn": 40, "random-search": 3, "hill-climbing": 3, "cem": 3, "ppo": 3, "a2c": 3, "reinforce": 2}
"""learn() calls before comparing: DQN's base makes its first update at call 8."""


def applicable_fields(agent: str) -> list[str]:
    return [name for name in CHANGES[agent] if name not in NOT_APPLICABLE[agent]]


def config_of(agent: str, **changes: Any) -> Any:
    config = dataclasses.replace(get_agent(agent).config_cls(), **(BASES[agent] | changes))
    config.validate()
    return config


def make(agent: str, seed: int = 0, **changes: Any) -> Any:
    return one_seed(agent, config_of(agent, **changes), CARTPOLE, seed)


def fingerprint(learner: Any, calls: int) -> tuple[list[Any], dict[str, np.ndarray], np.ndarray]:
    """What a learner did in ``calls`` learn() calls: results, final tensors, greedy scores."""
    results = []
    for _ in range(calls):
        r = learner.learn()
        results.append((r.env_steps, r.episode_returns, r.episode_lengths, r.scalars))
    tensors, _ = learner.state_dict(resume=False)
    arrays = {k: v.detach().cpu().numpy() for k, v in tensors.items()}
    policy = learner.policy()
    scores = (
        policy.scores(PROBE_OBSERVATIONS) if hasattr(policy, "scores") else policy.act(PROBE_OBSERVATIONS)
    )
    return results, arrays, np.asarray(scores)


def same(a: tuple[list[Any], dict[str, np.ndarray], np.ndarray], b: tuple[Any, ...]) -> bool:
    results_a, arrays_a, scores_a = a
    results_b, arrays_b, scores_b = b
    if results_a != results_b or arrays_a.keys() != arrays_b.keys():
        return False
    if any(x.shape != arrays_b[k].shape or not np.array_equal(x, arrays_b[k]) for k, x in arrays_a.items()):
        return False
    return scores_a.shape == scores_b.shape and np.array_equal(scores_a, scores_b)


def test_every_registered_agent_is_in_the_table() -> None:
    """A new agent needs a small base config (BASES), another value per setting (CHANGES), the
    settings that do not apply to it (NOT_APPLICABLE) and a number of learn() calls (CALLS)."""
    missing = set(agent_names()) - set(CHANGES)
    assert not missing, f"add these agents to BASES, CHANGES, NOT_APPLICABLE and CALLS: {sorted(missing)}"


@pytest.mark.parametrize("agent", list(CHANGES))
def test_every_config_field_is_in_the_table(agent: str) -> None:
    """A new setting needs an entry here (and so a test that fails when it is ignored)."""
    names = {f.name for f in dataclasses.fields(get_agent(agent).config_cls)}
    untested = names - set(CHANGES[agent]) - set(NOT_APPLICABLE[agent])
    assert not untested, f"{agent}: add these settings to the table: {sorted(untested)}"
    assert set(CHANGES[agent]) <= names, f"{agent}: the table names settings that are gone"


@pytest.mark.parametrize(
    ("agent", "field"), [(agent, field) for agent in CHANGES for field in applicable_fields(agent)]
)
def test_changing_one_setting_changes_the_learning(agent: str, field: str) -> None:
    shared, other = CHANGES[agent][field]
    base = make(agent, **shared)
    assert getattr(config_of(agent, **shared), field) != other, "the table's other value must differ"
    changed = make(agent, **(shared | {field: other}))
    reference = fingerprint(base, CALLS[agent])
    assert not same(reference, fingerprint(changed, CALLS[agent])), (
        f"{agent}: {field}={other!r} changed nothing"
    )


@pytest.mark.parametrize("agent", list(CHANGES))
def test_the_same_config_and_seed_repeat_exactly(agent: str) -> None:
    """So the differences above come from the setting, not from run-to-run noise."""
    assert same(fingerprint(make(agent), CALLS[agent]), fingerprint(make(agent), CALLS[agent]))
    assert not same(
        fingerprint(make(agent, seed=0), CALLS[agent]), fingerprint(make(agent, seed=1), CALLS[agent])
    )


# ----------------------------------------------------------------------------------------------
# DQN: the meaning of the update settings
# ----------------------------------------------------------------------------------------------


def q_tensors(learner: Any) -> dict[str, torch.Tensor]:
    tensors, _ = learner.state_dict(resume=False)
    return {k: v.detach().clone() for k, v in tensors.items()}


def unchanged(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("learning_starts", [0, 30, 75])
def test_no_gradient_step_before_learning_starts(learning_starts: int) -> None:
    learner = make("dqn", learning_starts=learning_starts, num_envs=4, gradient_steps=1)
    initial = q_tensors(learner)
    env_steps = 0
    while True:
        result = learner.learn()
        env_steps += result.env_steps
        updates = result.scalars["train/gradient_steps"]
        if env_steps < learning_starts:
            assert updates == 0 and "train/loss" not in result.scalars
            assert unchanged(q_tensors(learner), initial)
        else:  # the first call that reaches learning_starts trains
            assert updates == 1
            assert not unchanged(q_tensors(learner), initial)
            break


@pytest.mark.parametrize(("gradient_steps", "train_freq"), [(1, 1), (3, 1), (2, 3), (0, 1)])
def test_gradient_steps_per_round_and_rounds_every_train_freq_calls(
    gradient_steps: int, train_freq: int
) -> None:
    learner = make("dqn", learning_starts=0, gradient_steps=gradient_steps, train_freq=train_freq)
    initial = q_tensors(learner)
    for call in range(1, 13):
        counted = learner.learn().scalars["train/gradient_steps"]
        assert counted == (call // train_freq) * gradient_steps
    assert unchanged(q_tensors(learner), initial) == (gradient_steps == 0)


def zeroed_learner(loss: str) -> Any:
    """A learner whose Q-network answers 0 everywhere, with gamma 0: every TD error is exactly 1."""
    learner = make("dqn", loss=loss, gamma=0.0, learning_starts=0, gradient_steps=1)
    tensors, data = learner.state_dict(resume=True)
    networks = ("q_net.", "target_net.")
    learner.load_state_dict(
        {k: torch.zeros_like(v) if k.startswith(networks) else v for k, v in tensors.items()}, data
    )
    return learner


def test_loss_setting_picks_huber_or_mse() -> None:
    """On a batch whose TD errors are all 1: Huber (smooth L1) gives 0.5, MSE gives 1."""
    for loss, expected in (("huber", 0.5), ("mse", 1.0)):
        result = zeroed_learner(loss).learn()
        assert result.scalars["train/gradient_steps"] == 1
        assert result.scalars["train/q_mean"] == 0.0
        assert result.scalars["train/loss"] == pytest.approx(expected, abs=1e-6), loss


def epsilons(learner: Any, calls: int) -> list[tuple[int, float, float]]:
    """(env steps before the call, epsilon used, gradient steps before the call) per call."""
    rows, steps, updates = [], 0, 0.0
    for _ in range(calls):
        result = learner.learn()
        rows.append((steps, result.scalars["train/epsilon"], updates))
        steps += result.env_steps
        updates = result.scalars["train/gradient_steps"]
    return rows


def test_epsilon_schedules_follow_their_settings() -> None:
    start, end, decay = 0.9, 0.1, 40
    shared = {"epsilon_start": start, "epsilon_end": end, "epsilon_decay_steps": decay}
    for steps, eps, _ in epsilons(make("dqn", epsilon_schedule="linear", **shared), 40):
        assert eps == pytest.approx(end + (start - end) * max(0.0, 1 - steps / decay))
    for steps, eps, _ in epsilons(make("dqn", epsilon_schedule="exponential", **shared), 40):
        assert eps == pytest.approx(end + (start - end) * math.exp(-steps / decay))
    multiplicative = make("dqn", epsilon_schedule="multiplicative", epsilon_decay_rate=0.9, **shared)
    for _, eps, updates in epsilons(multiplicative, 60):
        assert eps == pytest.approx(max(end, start * 0.9**updates))


def test_dropout_trains_but_the_greedy_policy_is_deterministic() -> None:
    learner = make("dqn", dropout=0.5, learning_starts=0)
    for _ in range(10):
        learner.learn()
    policy = learner.policy()
    first = policy.scores(PROBE_OBSERVATIONS)
    np.testing.assert_array_equal(policy.scores(PROBE_OBSERVATIONS), first)
    np.testing.assert_array_equal(learner.policy().scores(PROBE_OBSERVATIONS), first)


# ----------------------------------------------------------------------------------------------
# Hill climbing: the noise halves after an improvement and doubles otherwise
# ----------------------------------------------------------------------------------------------


def test_hill_climbing_noise_halves_on_improvement_and_doubles_otherwise() -> None:
    learner = make("hill-climbing", seed=1, noise=0.2, population=4, episodes_per_candidate=1)
    kept, seen = -math.inf, set()
    for _ in range(25):
        noise_before = learner.state_dict(resume=True)[1]["noise"]
        result = learner.learn()
        noise_after = learner.state_dict(resume=True)[1]["noise"]
        improved = result.scalars["train/kept_score"] > kept
        kept = result.scalars["train/kept_score"]
        expected = max(noise_before / 2, 1e-3) if improved else min(noise_before * 2, 2.0)
        assert noise_after == pytest.approx(expected), (improved, noise_before, noise_after)
        seen.add(improved)
    assert seen == {True, False}, "the run must show both an improvement and a failure"


# ----------------------------------------------------------------------------------------------
# TrainSettings, through train(): each setting changes the run folder's record
# ----------------------------------------------------------------------------------------------

QUICK_UNSOLVED = {"population": 2, "episodes_per_candidate": 1}
"""Random search with two candidates a generation: cheap, and rarely solved in a few generations."""


def eval_rows(outcome: Any) -> list[dict[str, Any]]:
    return [row for row in outcome.run.metrics() if "eval/mean_return" in row]


def test_budget_setting_sets_the_default_budget(tmp_path: Path) -> None:
    for generations in (2, 5):
        overrides = QUICK_UNSOLVED | {"budget": f"{generations}gen"}
        outcome = train(
            "random-search", seed=0, overrides=overrides, runs_dir=tmp_path, stop_when_solved=False
        )
        assert outcome.state.iterations == generations


def test_eval_every_sets_how_often_training_evaluates(tmp_path: Path) -> None:
    counts = {}
    for eval_every in (0, 10**9):
        overrides = QUICK_UNSOLVED | {"eval_every": eval_every, "eval_screen_episodes": 2}
        outcome = train(
            "random-search",
            seed=0,
            overrides=overrides,
            budget="6gen",
            runs_dir=tmp_path,
            stop_when_solved=False,
        )
        counts[eval_every] = len(eval_rows(outcome))
    assert counts == {0: 6, 10**9: 1}  # after every generation / only the final policy at the end


def test_eval_screen_episodes_sets_the_screen_size(tmp_path: Path) -> None:
    for episodes in (3, 7):
        overrides = QUICK_UNSOLVED | {"eval_every": 0, "eval_screen_episodes": episodes}
        outcome = train("random-search", seed=0, overrides=overrides, budget="3gen", runs_dir=tmp_path)
        screens = [row for row in eval_rows(outcome) if row["eval/mean_return"] < CARTPOLE.reward_threshold]
        assert screens and all(row["eval/episodes"] == episodes for row in screens)


def test_eval_episodes_and_eval_simulator_shape_the_full_evaluation_and_the_verdict(cem_run: Path) -> None:
    runs_dir = cem_run.parent
    for episodes, simulator in ((100, "gymnasium"), (130, "fast")):
        # Without a verdict_simulator of its own (the default presets name one), the verdict's is this.
        overrides = {"eval_episodes": episodes, "eval_simulator": simulator, "verdict_simulator": "none"}
        outcome = train("cem", seed=0, overrides=overrides, runs_dir=runs_dir)
        full = [row for row in eval_rows(outcome) if row["eval/mean_return"] >= CARTPOLE.reward_threshold]
        assert full and all(row["eval/episodes"] == episodes for row in full)
        assert all(row["eval/simulator"] == simulator for row in full)
        assert outcome.report is not None
        assert outcome.report.episodes == episodes and outcome.report.simulator == simulator


def test_verdict_simulator_judges_the_final_policy_apart_from_the_evaluations_in_training(
    cem_run: Path,
) -> None:
    overrides = {"eval_simulator": "fast", "verdict_simulator": "gymnasium"}
    outcome = train("cem", seed=0, overrides=overrides, runs_dir=cem_run.parent)
    full = [row for row in eval_rows(outcome) if row["eval/mean_return"] >= CARTPOLE.reward_threshold]
    assert full and all(row["eval/simulator"] == "fast" for row in full)
    assert outcome.report is not None and outcome.report.simulator == "gymnasium"


def test_stop_when_solved_setting(tmp_path: Path) -> None:
    iterations = {}
    for stop in (True, False):
        overrides = {"stop_when_solved": stop, "eval_every": 0, "eval_simulator": "fast"}
        outcome = train("cem", seed=0, overrides=overrides, budget="10gen", runs_dir=tmp_path)
        assert outcome.state.solved
        iterations[stop] = outcome.state.iterations
    assert iterations[True] < 10 and iterations[False] == 10


class Crash(Exception):
    """The process dies here: nothing after it, not even a final save, happens."""


@contextmanager
def learners_that_crash_after(agent: str, calls: int) -> Iterator[None]:
    """While active, ``agent``'s populations die at their ``calls + 1``-th learn() and can save nothing
    after that (as under kill -9: only what was already on disk is left)."""
    spec = get_agent(agent)
    make_population = spec.make_population

    def crashing_population(*args: Any) -> Any:
        population = make_population(*args)
        learn, seed_state_dict, count = population.learn, population.seed_state_dict, [0]

        def learn_or_die() -> Any:
            count[0] += 1
            if count[0] > calls:
                raise Crash
            return learn()

        def state_dict_unless_dead(seed: int, resume: bool) -> Any:
            if count[0] > calls:
                raise Crash
            return seed_state_dict(seed, resume)

        population.learn, population.seed_state_dict = learn_or_die, state_dict_unless_dead
        return population

    object.__setattr__(spec, "make_population", crashing_population)  # the spec is frozen: put it back
    try:
        yield
    finally:
        object.__setattr__(spec, "make_population", make_population)


def latest_step_after_a_crash(runs_dir: Path, checkpoint_every: int, calls: int) -> int | None:
    """Env steps saved in ``latest.pt`` by a run that crashed at its ``calls + 1``-th generation."""
    overrides = {"population": 2, "episodes_per_candidate": 1, "checkpoint_every": checkpoint_every,
                 "eval_every": 10**9}  # fmt: skip
    with learners_that_crash_after("random-search", calls), pytest.raises(Crash):
        train(
            "random-search",
            seed=0,
            overrides=overrides,
            budget="1e9",
            runs_dir=runs_dir,
            stop_when_solved=False,
        )
    (run,) = [p for p in runs_dir.iterdir() if p.is_dir()]
    latest = run / "checkpoints" / "latest.pt"
    return int(load_checkpoint(latest).meta["step"]) if latest.is_file() else None


def test_checkpoint_every_bounds_the_work_a_crash_loses(tmp_path: Path) -> None:
    often = latest_step_after_a_crash(tmp_path / "often", checkpoint_every=50, calls=30)
    rarely = latest_step_after_a_crash(tmp_path / "rarely", checkpoint_every=10**9, calls=30)
    assert often is not None and often > 0
    assert rarely is None or rarely < often


# ----------------------------------------------------------------------------------------------
# The final verdict's seeds: derived from the run seed, used by no in-training evaluation
# ----------------------------------------------------------------------------------------------


def test_final_verdict_uses_fresh_seeds_derived_from_the_run_seed(tmp_path: Path) -> None:
    overrides = {"eval_every": 0, "eval_episodes": 100, "eval_simulator": "fast"}
    outcomes = {
        (seed, folder): train(
            "cem", seed=seed, overrides=overrides, budget="4gen", runs_dir=tmp_path / folder
        )
        for seed, folder in ((0, "a"), (0, "b"), (1, "c"))
    }
    verdicts = {key: outcome.report for key, outcome in outcomes.items()}
    assert all(report is not None for report in verdicts.values())
    seeds = {key: report.seeds for key, report in verdicts.items()}  # type: ignore[union-attr]
    assert seeds[(0, "a")] == seeds[(0, "b")], "the same run seed gives the same verdict seeds"
    assert set(seeds[(0, "a")]).isdisjoint(seeds[(1, "c")]), "another run seed gives other seeds"
    assert seeds[(0, "a")][0] == final_eval_seed(0)
    for (seed, folder), outcome in outcomes.items():
        verdict_seeds = seeds[(seed, folder)]
        assert min(verdict_seeds) > MAX_TRAIN_SEED, "no training seed is a verdict seed"
        written = json.loads((outcome.run.path / "eval.json").read_text())
        assert written["seeds"] == verdict_seeds
        # in-training evaluation j (screens even, full ones odd) plays seeds eval_seed(seed, j) + k
        used = {eval_seed(seed, j) + k for j in range(2 * outcome.state.evaluations) for k in range(100)}
        assert used.isdisjoint(verdict_seeds)
