"""Population training (``cartpole train ppo --seeds``): independent seeds, ordinary run folders,
batched verdicts that match single evaluations, resume, and bad input refused before any folder."""

from __future__ import annotations

import io
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from platforms import kill_9, stop_signal_to_a_process

from cartpole.agents.actor_critic.a2c import A2CConfig, PopulationA2C
from cartpole.agents.actor_critic.policy_gradient import seeded_actor_critic
from cartpole.agents.actor_critic.ppo import PopulationPPO, PPOConfig
from cartpole.agents.actor_critic.reinforce import PopulationReinforce, ReinforceConfig
from cartpole.agents.learner import LearnResult
from cartpole.agents.registry import build_population, get_agent, load_policy
from cartpole.cli.main import main
from cartpole.core.errors import InputError
from cartpole.core.names import RunState
from cartpole.core.seeding import final_eval_seed
from cartpole.envs import env_info
from cartpole.evaluation import evaluate
from cartpole.runs import RunDir, load_checkpoint, summarize_run
from cartpole.training import engine, train
from cartpole.training.callbacks import screened_evaluation
from cartpole.training.config import TrainSettings
from cartpole.training.engine import PopulationEvaluations
from cartpole.training.session import parse_seeds, resume_population, train_population
from cartpole.training.setup import RunSetup

CARTPOLE = env_info("CartPole-v1")
SMALL = {"n_steps": 8, "num_envs": 4, "n_epochs": 2, "minibatch_size": 16, "hidden_sizes": (16, 16)}


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """As ``cartpole train`` runs (--threads 1): on a shared 2-core machine a second torch thread makes
    these small ops wait for each other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def small_config(**changes: object) -> PPOConfig:
    return PPOConfig(**(SMALL | changes))  # type: ignore[arg-type]


A2C_SMALL = {"n_steps": 8, "num_envs": 4, "hidden_sizes": (16, 16)}


def small_population(agent: str, seeds: list[int], device: str = "cpu", **changes: object) -> Any:
    """A small PPO or A2C population (the actor-critic ones share these tests)."""
    if agent == "ppo":
        return PopulationPPO(small_config(**changes), CARTPOLE, seeds, device)
    if agent == "reinforce":
        config = ReinforceConfig(**(REINFORCE_SMALL | changes))  # type: ignore[arg-type]
        return PopulationReinforce(config, CARTPOLE, seeds, device)
    return PopulationA2C(A2CConfig(**(A2C_SMALL | changes)), CARTPOLE, seeds, device)  # type: ignore[arg-type]


REINFORCE_SMALL = {"num_envs": 3, "hidden_sizes": (16, 16)}
ACTOR_CRITICS = ["ppo", "a2c", "reinforce"]


def weights(population: Any, seed: int) -> dict[str, torch.Tensor]:
    """A seed's checkpoint tensors but its generators' states (and, for REINFORCE, which restarts
    every env each batch, where its envs stood after its episodes ended)."""
    tensors, _ = population.seed_state_dict(seed, resume=True)
    skip = ("rng", "collector") if isinstance(population, PopulationReinforce) else ("rng",)
    return {k: v for k, v in tensors.items() if not k.startswith(skip)}


def assert_same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def learn(population: PopulationPPO, times: int) -> list[dict[int, LearnResult]]:
    return [population.learn() for _ in range(times)]


def same(a: LearnResult, b: LearnResult) -> bool:
    """Equal results, NaN metrics (no update yet) included."""
    return json.dumps(asdict(a)) == json.dumps(asdict(b))


# -- --seeds ----------------------------------------------------------------------------------------


def test_parse_seeds_ranges_and_lists():
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("3,5,8") == [3, 5, 8]
    assert parse_seeds(" 0-1, 7 ") == [0, 1, 7]


@pytest.mark.parametrize(
    "text", ["", " ", "5-3", "3,3", "0-3,2", "x", "1,,2", "-1", "1-", "2**40", "0-999999999", "4294967296"]
)
def test_parse_seeds_refuses_bad_input(text):
    with pytest.raises(InputError):
        parse_seeds(text)


# -- independence -----------------------------------------------------------------------------------


@pytest.mark.independence
@pytest.mark.parametrize("agent", ACTOR_CRITICS)
def test_a_seed_does_not_depend_on_its_neighbours(agent):
    with_5 = small_population(agent, [3, 5])
    with_7 = small_population(agent, [3, 7])
    results_5, results_7 = learn(with_5, 3), learn(with_7, 3)
    for a, b in zip(results_5, results_7, strict=True):
        assert same(a[3], b[3])  # env steps, episodes, every metric
    assert_same(weights(with_5, 3), weights(with_7, 3))
    assert not torch.equal(
        weights(with_5, 5)["model.policy_head.weight"], weights(with_7, 7)["model.policy_head.weight"]
    )


@pytest.mark.independence
@pytest.mark.parametrize("agent", ACTOR_CRITICS)
def test_with_two_threads_a_seed_still_does_not_depend_on_its_neighbours(agent):
    """``cartpole train --seeds`` uses every core; torch then splits the batched work between threads,
    and a seed must still get the same bits among 20 seeds as beside one other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        many = small_population(agent, list(range(3, 23)))
        few = small_population(agent, [3, 40])
        for a, b in zip(learn(many, 3), learn(few, 3), strict=True):
            assert same(a[3], b[3])
        assert_same(weights(many, 3), weights(few, 3))
    finally:
        torch.set_num_threads(threads)


@pytest.mark.independence
@pytest.mark.parametrize("agent", ACTOR_CRITICS)
def test_removing_a_stopped_seed_leaves_the_others_unchanged(agent):
    three = small_population(agent, [3, 5, 7])
    two = small_population(agent, [3, 7])
    learn(three, 2)
    learn(two, 2)
    three.remove([5])
    after_three, after_two = three.learn(), two.learn()
    assert same(after_three[3], after_two[3]) and same(after_three[7], after_two[7])
    assert_same(weights(three, 7), weights(two, 7))


# -- devices ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("agent", ACTOR_CRITICS)
def test_every_tensor_lives_on_the_population_device(agent):
    """What ``--device cuda`` needs, checked on a CPU: with torch's default device set to another one
    (meta), a tensor the population made without naming its device could not meet the others."""
    torch.set_default_device("meta")
    try:
        population = small_population(agent, [3, 5, 7], lr_schedule="linear", schedule_steps=10_000)
        learn(population, 2)
        population.remove([5])
        learn(population, 1)
        actions = population.greedy_actor([3, 7])(torch.zeros(6, 4, device="cpu").numpy(), np.arange(2))
        tensors, data = population.seed_state_dict(7, resume=True)
        population.load_seed_state_dict(7, tensors, data)
    finally:
        torch.set_default_device(None)
    assert actions.shape == (6,) and all(t.device.type == "cpu" for t in tensors.values())


@pytest.mark.parametrize("agent", ["ppo", "dqn"])
def test_building_a_population_imports_no_symbolic_shapes(agent):
    """On torch's default (CPU) device the seeds' networks are built without a ``torch.device``
    context, whose torch-function mode imports sympy on first use (a quarter second of every start)."""
    code = (
        "import sys\n"
        "from cartpole.agents.registry import build_population, get_agent\n"
        "from cartpole.envs import env_info\n"
        "from cartpole.training.config import resolve_config\n"
        f"spec = get_agent({agent!r})\n"
        "config, _ = resolve_config(spec.name, spec.config_cls, 'default')\n"
        "build_population(spec, config, env_info('CartPole-v1'), [0, 1], 'cpu')\n"
        "print('sympy' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("agent", ACTOR_CRITICS)
def test_a_population_trains_on_cuda_and_its_checkpoints_load_on_the_cpu(agent, tmp_path):
    population = small_population(agent, [3, 5], device="cuda")
    assert population.model.flat.device.type == "cuda"
    results = learn(population, 3)
    assert all(r[3].env_steps > 0 for r in results)
    tensors, data = population.seed_state_dict(3, resume=True)
    assert all(t.device.type == "cpu" for t in tensors.values())
    on_cpu = small_population(agent, [3, 5])
    on_cpu.load_seed_state_dict(3, tensors, data)
    assert_same(weights(on_cpu, 3), {k: v for k, v in tensors.items() if k in weights(on_cpu, 3)})


def test_seeds_start_from_their_own_network_and_envs():
    """A seed's initial network is its seeded actor-critic, and its envs start where they start
    for the seed alone."""
    config = small_config()
    population = PopulationPPO(config, CARTPOLE, [4, 9])
    tensors, _ = population.seed_state_dict(9, resume=False)
    for name, value in seeded_actor_critic(config, CARTPOLE, 9).state_dict().items():
        assert torch.equal(tensors[f"model.{name}"], value), name
    alone = PopulationPPO(config, CARTPOLE, [9])
    assert (population.episodes.observations[config.num_envs :] == alone.episodes.observations).all()
    assert not (population.episodes.observations[: config.num_envs] == alone.episodes.observations).all()


SETTINGS = {
    "ppo": [
        {"n_epochs": 1},
        {"clip_range": 0.001},
        {"ent_coef": 0.5},
        {"target_kl": 1e-6},
        {"lr": 1e-4},
        {"max_grad_norm": 0.001},
        {"normalize_advantages": False},
        {"vf_coef": 0.0},
    ],
    "a2c": [
        {"optimizer": "adam"},
        {"rms_alpha": 0.5},
        {"optimizer_eps": 1.0},
        {"lr": 1e-4},
        {"ent_coef": 0.5},
        {"max_grad_norm": 0.001},
        {"normalize_advantages": True},
        {"gae_lambda": 0.5},
    ],
    "reinforce": [
        {"baseline": False},
        {"normalize_returns": False},
        {"gamma": 0.5},
        {"lr": 1e-4},
        {"ent_coef": 0.5},
        {"max_grad_norm": 0.001},
        {"num_envs": 2},
    ],
}


@pytest.mark.parametrize(("agent", "change"), [(a, c) for a, changes in SETTINGS.items() for c in changes])
def test_settings_reach_the_batched_update(agent, change):
    """Each setting changes a seed's run."""

    def trained(**change: object) -> torch.Tensor:
        population = small_population(agent, [1], **change)
        learn(population, 2)
        return weights(population, 1)["model.actor_trunk.0.weight"]

    assert not torch.equal(trained(**change), trained())


BY_HAND_CASES = [
    ("ppo", {}),
    ("ppo", {"activation": "relu", "ent_coef": 0.01, "clip_range_vf": 0.2, "shared_trunk": True}),
    ("ppo", {"minibatch_size": 64, "normalize_advantages": True}),
    ("a2c", {"normalize_advantages": True, "ent_coef": 0.01}),
    ("a2c", {"shared_trunk": True, "activation": "relu"}),
    ("reinforce", {}),
    ("reinforce", {"baseline": False, "ent_coef": 0.01}),
]


@pytest.mark.parametrize(("agent", "change"), BY_HAND_CASES)
def test_gradients_by_hand_train_as_autograd_does(agent, change):
    """An MLP's update differentiates by hand: the weights come out as autograd's, bit for bit, for
    each loss, activation, shared trunk and batch shape."""
    by_hand, autograd = small_population(agent, [2, 7], **change), small_population(agent, [2, 7], **change)
    assert by_hand.model.by_hand
    autograd.model.by_hand = False
    by_hand.closed_form = False  # PPO's loss by autograd here too: the networks' gradients alone by hand
    learn(by_hand, 4)
    learn(autograd, 4)
    for seed in (2, 7):
        assert_same(weights(by_hand, seed), weights(autograd, seed))
    assert not torch.equal(by_hand.model.flat, small_population(agent, [2, 7], **change).model.flat)


CLOSED_FORM_CASES = [
    {},
    {"ent_coef": 0.02, "activation": "relu", "shared_trunk": True},
    {"minibatch_size": 64, "lr": 0.05},  # shuffled minibatches; ratios far enough from 1 to clip
    {"target_kl": 0.002, "lr": 0.05},  # seeds that stop their epochs early
    {"normalize_advantages": False},
]


@pytest.mark.parametrize("change", CLOSED_FORM_CASES)
def test_ppos_loss_differentiated_in_closed_form_trains_as_autograd_does(change):
    """PPO's loss gradients in closed form (ppo_loss_gradients): the weights and every metric come out
    as with autograd's, to within float32 rounding, for each loss term, activation, shared trunk,
    minibatch shape and early stop."""
    closed, autograd = small_population("ppo", [2, 7], **change), small_population("ppo", [2, 7], **change)
    assert closed.differentiates_in_closed_form
    autograd.closed_form = False
    for closed_results, autograd_results in zip(learn(closed, 2), learn(autograd, 2), strict=True):
        for seed in (2, 7):
            a, b = closed_results[seed].scalars, autograd_results[seed].scalars
            assert a.keys() == b.keys()
            for key in a:
                assert a[key] == pytest.approx(b[key], rel=1e-4, abs=1e-6, nan_ok=True), key
    for seed in (2, 7):
        a, b = weights(closed, seed), weights(autograd, seed)
        for key in a:
            if a[key].is_floating_point():
                assert torch.allclose(a[key], b[key], rtol=1e-4, atol=1e-6), key
    assert not torch.equal(closed.model.flat, small_population("ppo", [2, 7], **change).model.flat)


def test_ppos_loss_goes_to_autograd_where_the_closed_form_does_not_apply():
    """Value clipping (not in the closed form) and networks without a backward pass by hand."""
    assert not small_population("ppo", [1], clip_range_vf=0.2).differentiates_in_closed_form
    assert not small_population("ppo", [1], activation="elu").differentiates_in_closed_form


def test_networks_that_autograd_differentiates():
    """ELU and convolutional networks take autograd's backward pass (none is written by hand)."""
    assert not small_population("ppo", [1], activation="elu").model.by_hand


@pytest.mark.independence
def test_reinforce_batches_start_where_the_seed_alone_starts_them():
    config = ReinforceConfig(**REINFORCE_SMALL)  # type: ignore[arg-type]
    population, alone = small_population("reinforce", [2, 5]), small_population("reinforce", [5])
    row = population.seeds.index(5)
    envs = slice(row * config.num_envs, (row + 1) * config.num_envs)
    starts = []
    for _ in range(3):
        population.restart()
        alone.restart()
        assert (population.episodes.observations[envs] == alone.episodes.observations).all()
        starts.append(alone.episodes.observations.copy())
    assert not (starts[0] == starts[1]).all()  # each batch starts fresh episodes


def test_reinforce_batches_are_one_whole_episode_per_env():
    population = small_population("reinforce", [2, 5])
    for results in learn(population, 3):
        for result in results.values():
            assert len(result.episode_lengths) == REINFORCE_SMALL["num_envs"]
            assert result.env_steps == sum(result.episode_lengths)


@pytest.mark.parametrize(
    ("agent", "change"),
    [
        ("ppo", {}),
        ("a2c", {}),
        ("a2c", {"optimizer": "adam"}),
        ("reinforce", {}),
        ("reinforce", {"baseline": False}),
    ],
)
def test_resume_of_a_seed_continues_exactly(agent, change):
    straight = small_population(agent, [2, 6], **change)
    learn(straight, 2)
    tensors, data = straight.seed_state_dict(6, resume=True)
    resumed = small_population(agent, [6], **change)
    resumed.load_seed_state_dict(6, tensors, json.loads(json.dumps(data)))
    assert same(straight.learn()[6], resumed.learn()[6])
    assert_same(weights(straight, 6), weights(resumed, 6))


# -- the session ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def population_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[int, Path]]:
    root = tmp_path_factory.mktemp("population")
    found = {}
    for name, seeds in (("a", [3, 5]), ("b", [3, 7])):
        outcome = train_population(
            "ppo", seeds, overrides=SMALL | {"eval_every": 200}, budget="600", runs_dir=root / name
        )
        found[name] = {seed: run.path for seed, run in outcome.runs.items()}
    return found


def metric_rows(run: Path) -> list[dict[str, object]]:
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in row.items() if k not in ("time", "time/sps")} for row in rows]


def test_each_seed_leaves_an_ordinary_run_folder(population_runs):
    run = population_runs["a"][5]
    names = {p.name for p in run.iterdir()} | {p.name for p in (run / "checkpoints").iterdir()}
    assert {"config.json", "status.json", "metrics.jsonl", "eval.json", "latest.pt", "best.pt"} <= names
    config = json.loads((run / "config.json").read_text())
    assert config["seed"] == 5 and config["agent"] == "ppo" and config["population"]["seeds"] == [3, 5]
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "finished" and status["env_steps"] >= 600
    assert load_policy(run).act(torch.zeros(3, 4).numpy()).shape == (3,)


@pytest.mark.independence
def test_seed_3_has_the_same_run_beside_5_or_7(population_runs):
    a, b = population_runs["a"][3], population_runs["b"][3]
    assert metric_rows(a) == metric_rows(b)
    latest_a = torch.load(a / "checkpoints" / "latest.pt", weights_only=True)["tensors"]
    latest_b = torch.load(b / "checkpoints" / "latest.pt", weights_only=True)["tensors"]
    assert_same(latest_a, latest_b)


def test_batched_verdict_is_the_single_evaluation(population_runs):
    run = population_runs["a"][5]
    verdict = json.loads((run / "eval.json").read_text())
    single = evaluate(load_policy(run), "CartPole-v1", 100, seed=final_eval_seed(5))
    assert verdict["returns"] == single.returns and verdict["seeds"] == single.seeds
    assert verdict["simulator"] == "gymnasium"


def test_tensorboard_gives_each_seed_its_own_events(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    outcome = train_population(
        "ppo", [3, 5], overrides=SMALL, budget="100", runs_dir=tmp_path, tensorboard=True
    )
    for seed, run in outcome.runs.items():
        rows = [r for r in metric_rows(run.path) if "train/policy_loss" in r]
        events = EventAccumulator(str(run.path / "tensorboard"))
        events.Reload()
        logged = [(e.step, e.value) for e in events.Scalars("train/policy_loss")]
        assert logged == [(r["step"], pytest.approx(r["train/policy_loss"])) for r in rows], seed
        assert rows and json.loads((run.path / "config.json").read_text())["tensorboard"] is True


# -- evaluations played together --------------------------------------------------------------------


@pytest.mark.independence
def test_evaluations_played_together_are_each_seeds_own():
    """The due seeds' screens (and full evaluations where the screen passes) played in one batch give
    each seed the report its own screened evaluation gives."""
    population = PopulationPPO(small_config(), CARTPOLE, [3, 5, 8])
    learn(population, 3)
    for settings, env in itertools.product(
        (
            TrainSettings(eval_screen_episodes=4, eval_episodes=6),
            TrainSettings(eval_screen_episodes=4, eval_episodes=6, confirm_solves=True),
        ),
        (CARTPOLE, replace(CARTPOLE, reward_threshold=5.0)),  # the second passes every screen
    ):
        reports = PopulationEvaluations(population, env, settings).screened([(3, 0), (8, 4)])
        assert sorted(reports) == [3, 8]
        for seed, index in ((3, 0), (8, 4)):
            alone = screened_evaluation(population.seed_policy(seed), env, seed, index, settings)
            ours = reports[seed]
            assert (ours.returns, ours.lengths, ours.seeds) == (alone.returns, alone.lengths, alone.seeds)
            assert ours.simulator == alone.simulator
        assert reports[3].simulator == ("fast" if env is CARTPOLE else "gymnasium")


# -- linear searches: a batch of populations ----------------------------------------------------------


@pytest.mark.parametrize("agent", ["random-search", "hill-climbing", "cem"])
def test_a_linear_search_seed_is_the_seed_alone(agent):
    spec = get_agent(agent)
    config = spec.config_cls(population=6, episodes_per_candidate=2)
    population = build_population(spec, config, CARTPOLE, [3, 5])
    alone = build_population(spec, config, CARTPOLE, [3])
    for _ in range(4):
        assert same(population.learn()[3], alone.learn()[3])
    assert_same(population.seed_state_dict(3, resume=True)[0], alone.seed_state_dict(3, resume=True)[0])


def test_resume_of_a_linear_search_seed_continues_exactly():
    config = get_agent("hill-climbing").config_cls(population=6, episodes_per_candidate=2)
    straight = build_population(get_agent("hill-climbing"), config, CARTPOLE, [2, 6])
    learn(straight, 2)
    tensors, data = straight.seed_state_dict(6, resume=True)
    resumed = build_population(get_agent("hill-climbing"), config, CARTPOLE, [6])
    resumed.load_seed_state_dict(6, tensors, json.loads(json.dumps(data)))
    assert same(straight.learn()[6], resumed.learn()[6])
    assert_same(straight.seed_state_dict(6, resume=True)[0], resumed.seed_state_dict(6, resume=True)[0])


def test_a_linear_population_run_is_the_single_runs(tmp_path):
    """Metric rows (evaluations included: cem evaluates every generation) and verdict of a seed
    trained beside another are those of its single run."""
    outcome = train_population("cem", [3, 4], budget="4gen", runs_dir=tmp_path / "population")
    single = train("cem", seed=3, budget="4gen", runs_dir=tmp_path / "single")
    assert metric_rows(outcome.runs[3].path) == metric_rows(single.run.path)
    assert single.report is not None and outcome.reports[3].returns == single.report.returns


# -- the command --------------------------------------------------------------------------------------


def run_cli(*args: str, **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cartpole", *args], capture_output=True, text=True, timeout=300, **kwargs
    )


@pytest.mark.parametrize(
    "args",
    [
        ["ppo", "--seeds", "5-3"],
        ["ppo", "--seeds", "1,1"],
        ["ppo", "--seeds", ""],
        ["ppo", "--seeds", "a-b"],
        ["ppo", "--seeds", "0-4000", "--set", "hidden_sizes=2048,2048"],
        ["dqn", "--seeds", "0-3000", "--set", "buffer_size=2000000"],
        pytest.param(
            ["ppo", "--seeds", "0-3", "--device", "cuda"],
            marks=pytest.mark.skipif(torch.cuda.is_available(), reason="a GPU is here: it would train"),
        ),
    ],
)
def test_bad_population_input_is_one_line_exit_2_and_no_folder(tmp_path, capsys, args):
    assert main(["train", *args, "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "error:" in err
    assert not (tmp_path / "runs").exists()


def test_a_population_too_big_for_memory_says_how_many_seeds_fit(tmp_path, capsys):
    args = ["train", "dqn", "--seeds", "0-3000", "--set", "buffer_size=2000000"]
    assert main([*args, "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert re.search(r"3001 seeds of dqn would take about [\d,.]+ [GT]iB of memory but", err), err
    assert re.search(r"use fewer seeds \(about [\d,]+ fit\) or smaller settings$", err.strip()), err


def test_bad_population_input_through_the_command(tmp_path):
    done = run_cli("train", "ppo", "--seeds", "9-0", "--runs-dir", str(tmp_path / "runs"))
    assert done.returncode == 2 and "reversed" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "runs").exists()


RARE_EVALUATIONS = ["--set", "eval_every=1000000"]
"""No evaluations while training (what a kill must not lose is the training state): once solved, an
agent's 100-episode evaluations would cost more than its training."""


@stop_signal_to_a_process
def test_sigint_saves_every_seed_and_resume_continues_them_all(tmp_path):
    runs_dir = tmp_path / "runs"
    # Long enough to be training still when each seed's status first shows steps (every 5 s): 60k took
    # 4.8 s on a fast CPU, and a SIGINT after training (during interpreter exit) is not what is tested.
    args = ["train", "ppo", "--seeds", "0-2", "--budget", "200k", "--no-stop-when-solved", "--quiet"]
    args += ["--runs-dir", str(runs_dir), *RARE_EVALUATIONS]
    process = subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        statuses = list(runs_dir.glob("*/status.json")) if runs_dir.exists() else []
        if len(statuses) == 3 and all(json.loads(p.read_text()).get("env_steps", 0) > 0 for p in statuses):
            break
        time.sleep(0.2)
    os.kill(process.pid, signal.SIGINT)
    process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGINT
    runs = sorted(runs_dir.iterdir())
    assert len(runs) == 3
    for run in runs:
        assert json.loads((run / "status.json").read_text())["state"] == "interrupted"
        assert (run / "checkpoints" / "latest.pt").exists()
    done = run_cli("train", "--resume", str(runs[1]), "--quiet")
    assert done.returncode == 0, done.stderr
    for run in runs:
        assert json.loads((run / "status.json").read_text())["state"] == "finished"
        assert (run / "eval.json").exists()


SMALL_DQN = ["--set", "hidden_sizes=16,16", "--set", "batch_size=32"]
"""A DQN whose gradient steps cost little: what these tests check is the crash safety, not learning."""


@kill_9
@pytest.mark.parametrize(
    ("agent", "budget", "rollout", "settings"), [("ppo", 200_000, 8 * 16, []), ("dqn", 60_000, 8, SMALL_DQN)]
)
def test_kill_9_loses_at_most_one_checkpoint_interval_and_resume_finishes_every_seed(
    agent, budget, rollout, settings, tmp_path
):
    """Budgets that keep the population training when its rows first show (5 s); ``rollout``: the
    env steps of one learning step, by which a save can land past its interval."""
    runs_dir = tmp_path / "runs"
    args = ["train", agent, "--seeds", "0-2", "--budget", str(budget), "--no-stop-when-solved", *settings]
    args += RARE_EVALUATIONS
    process = subprocess.Popen(
        [sys.executable, "-m", "cartpole", *args, "--runs-dir", str(runs_dir), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    def logged_steps(run: Path) -> int:
        return max((row["step"] for row in RunDir(run).metrics()), default=0)

    def saved_steps(run: Path) -> int:
        return load_checkpoint(run / "checkpoints" / "latest.pt").meta["loop"]["env_steps"]

    def past_a_quarter(runs: list[Path]) -> bool:
        saved = len(runs) == 3 and all((r / "checkpoints" / "latest.pt").exists() for r in runs)
        return saved and min(logged_steps(r) for r in runs) > budget // 4

    deadline = time.monotonic() + 300
    runs: list[Path] = []
    while time.monotonic() < deadline and process.poll() is None:
        runs = sorted(runs_dir.iterdir()) if runs_dir.exists() else []
        if past_a_quarter(runs):
            break
        time.sleep(0.1)
    assert process.poll() is None, "the population ended before the test could kill it"
    os.kill(process.pid, signal.SIGKILL)
    process.communicate(timeout=60)

    interval = budget // 10  # latest.pt at least every 10% of the budget (the default is 5%)
    for run in runs:
        assert summarize_run(run).state == RunState.CRASHED
        assert logged_steps(run) - saved_steps(run) <= interval + rollout
    done = run_cli("train", "--resume", str(runs[0]), "--quiet")
    assert done.returncode == 0, done.stderr
    for run in runs:
        assert summarize_run(run).state == RunState.FINISHED
        assert json.loads((run / "eval.json").read_text())["episodes"] >= 100
        steps = [row["step"] for row in RunDir(run).metrics() if "train/episode_return" in row]
        assert steps == sorted(steps)  # the lost steps were replayed, not logged twice
        assert saved_steps(run) >= budget


def test_resume_of_a_population_with_one_corrupt_checkpoint_names_it_and_loses_nothing(tmp_path, capsys):
    outcome = train_population("cem", [1, 2], budget="3gen", runs_dir=tmp_path, stop_when_solved=False)
    for run in outcome.runs.values():  # as if interrupted: both would resume
        status = json.loads((run.path / "status.json").read_text())
        (run.path / "status.json").write_text(json.dumps(status | {"state": "interrupted"}))
    broken = outcome.runs[2].checkpoint_path("latest")
    broken.write_bytes(b"not a checkpoint")
    kept = outcome.runs[1].checkpoint_path("latest").read_bytes()
    metrics = (outcome.runs[1].path / "metrics.jsonl").read_text()
    assert main(["train", "--resume", str(outcome.runs[1].path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(broken) in err
    assert outcome.runs[1].checkpoint_path("latest").read_bytes() == kept
    assert (outcome.runs[1].path / "metrics.jsonl").read_text() == metrics


def test_a_population_shows_its_progress_and_its_verdicts_in_lines(tmp_path, monkeypatch):
    """Not quiet: a line every few seconds (every step here) with seeds solved, seeds training and
    the slowest seed's steps, and a last line with the verified verdicts."""
    monkeypatch.setattr(engine.PopulationProgress, "SECONDS", 0.0)
    stream = io.StringIO()
    outcome = train_population(
        "cem", [1, 2], budget="3gen", runs_dir=tmp_path, quiet=False, stream=stream, stop_when_solved=False
    )
    lines = stream.getvalue().splitlines()
    progress = [line for line in lines if "training," in line and "done:" not in line]
    assert len(progress) >= 2
    assert all("seeds, " in line and "slowest seed " in line and "steps/s" in line for line in progress)
    assert re.search(r"solved [0-2]/2 seeds, 2 training, slowest seed [\d,]+ steps", progress[0])
    verified = sum(report.solved for report in outcome.reports.values())
    assert f"done: {verified}/2 seeds verified solved on fresh episodes; " in lines[-1]
    assert ", 0 training, " in lines[-1]


def test_resume_of_a_population_says_where_its_seeds_go_on_from_and_passes_over_other_folders(tmp_path):
    outcome = train_population("cem", [1, 2], budget="3gen", runs_dir=tmp_path, stop_when_solved=False)
    for run in outcome.runs.values():  # as if interrupted: both resume
        status = json.loads((run.path / "status.json").read_text())
        (run.path / "status.json").write_text(json.dumps(status | {"state": "interrupted"}))
    (tmp_path / "notes").mkdir()  # not a run folder: passed over when looking for the members
    (tmp_path / "notes" / "todo.txt").write_text("plot the seeds")
    steps = {seed: state.env_steps for seed, state in outcome.states.items()}
    stream = io.StringIO()
    resumed = resume_population(outcome.runs[1].path, quiet=False, stream=stream)
    assert sorted(resumed.runs) == [1, 2]
    low, high = min(steps.values()), max(steps.values())
    where = f"{low:,}" if low == high else f"{low:,} to {high:,}"
    first = stream.getvalue().splitlines()[0]
    assert (
        first
        == f"resuming 2 seed(s) of the population from env step {where} (each seed's checkpoints/latest.pt)"
    )


def test_a_new_run_hands_its_agent_down_instead_of_rebuilding_it(monkeypatch, tmp_path):
    """The session builds the agent (spec, config) once: the population trains with it and every
    seed's callbacks get it, not a copy rebuilt from the config.json just written (a resume builds it
    from there)."""

    def rebuilt(cls: type[RunSetup], run: RunDir, record: dict[str, Any]) -> RunSetup:
        raise AssertionError(f"{run.name} rebuilt its agent from the record it had just written")

    monkeypatch.setattr(RunSetup, "from_record", classmethod(rebuilt))
    outcome = train_population("cem", [1, 2], budget="1gen", runs_dir=tmp_path, overrides={"population": 8})
    assert sorted(outcome.reports) == [1, 2]
    assert json.loads((outcome.runs[1].path / "config.json").read_text())["config"]["population"] == 8
