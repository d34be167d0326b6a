"""Policy-gradient agents (REINFORCE, A2C, PPO): the shared parts, the losses, every setting, checkpoints,
exact resume, bad settings, and that they learn."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from one_seed import OneSeed, one_seed

from cartpole.agents.actor_critic.a2c import A2CConfig
from cartpole.agents.actor_critic.network import (
    ActorCritic,
    CategoricalPolicy,
    stacked_greedy_actor,
)
from cartpole.agents.actor_critic.ppo import PPOConfig, clipped_surrogate_loss, clipped_value_loss
from cartpole.agents.actor_critic.reinforce import ReinforceConfig
from cartpole.agents.actor_critic.rollout import generalized_advantages
from cartpole.agents.nn.masked import masked_normalize
from cartpole.agents.nn.schedules import schedule_value
from cartpole.agents.presets import preset_names
from cartpole.agents.registry import get_agent, load_policy
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.evaluation import ScoredPolicy
from cartpole.runs import Checkpoint, load_checkpoint, save_checkpoint
from cartpole.training import train
from cartpole.training.config import resolve_config

CARTPOLE = env_info("CartPole-v1")
AGENTS = ("reinforce", "a2c", "ppo")


def small_ppo(**changes: Any) -> PPOConfig:
    base = PPOConfig(hidden_sizes=(16, 16), num_envs=4, n_steps=16, minibatch_size=16, n_epochs=2)
    return dataclasses.replace(base, **changes)


def small_a2c(**changes: Any) -> A2CConfig:
    return dataclasses.replace(A2CConfig(hidden_sizes=(16, 16), num_envs=4, n_steps=8), **changes)


def small_reinforce(**changes: Any) -> ReinforceConfig:
    return dataclasses.replace(ReinforceConfig(hidden_sizes=(16, 16), num_envs=2), **changes)


SMALL = {"ppo": small_ppo, "a2c": small_a2c, "reinforce": small_reinforce}


def make(agent: str, seed: int = 0, env: Any = CARTPOLE, **changes: Any) -> OneSeed:
    """The learner of ``cartpole train AGENT --seed SEED`` with small settings: a population of one."""
    return one_seed(agent, SMALL[agent](**changes), env, seed)


def model_tensors(learner: OneSeed) -> dict[str, torch.Tensor]:
    """The actor-critic's tensors (``model.*`` of its checkpoint), names unprefixed."""
    tensors, _ = learner.state_dict(resume=False)
    return {k.removeprefix("model."): v for k, v in tensors.items() if k.startswith("model.")}


def flat_params(learner: OneSeed) -> torch.Tensor:
    tensors = model_tensors(learner)
    return torch.cat([tensors[k].flatten() for k in sorted(tensors)])


def run(learner: OneSeed, calls: int) -> list[dict[str, float]]:
    return [learner.learn().scalars for _ in range(calls)]


# ----------------------------------------------------------------------------------------------
# Shared parts: GAE, normalization, schedules, the network
# ----------------------------------------------------------------------------------------------


def test_gae_by_hand_with_one_termination_and_one_truncation() -> None:
    """Env 0 terminates at t=1 (no bootstrap; t=2 is its autoreset row); env 1 is truncated at t=2
    (bootstraps from V of its final observation, row 3; t=3 is its autoreset row)."""
    gamma, lam = 0.9, 0.5
    rewards = torch.tensor([[1.0, 1.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    terminated = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    truncated = torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    valid = torch.tensor([[True, True], [True, True], [False, True], [True, False]])
    values = torch.tensor([[1.0, 0.5], [2.0, 0.5], [3.0, 0.5], [4.0, 2.0], [5.0, 1.0]])
    advantages = generalized_advantages(rewards, values, terminated, truncated, valid, gamma, lam)
    # env 0: A1 = 1 - 2 (terminated: no V(next)); A0 = (1 + .9*2 - 1) + .45*A1; A3 = 1 + .9*5 - 4
    # env 1: A2 = 1 + .9*2 - .5 (truncated: V(final obs) = 2); A1 = .95 + .45*A2; A0 = .95 + .45*A1
    a1_env1 = 0.95 + 0.45 * 2.3
    expected = torch.tensor([[1.8 - 0.45, 0.95 + 0.45 * a1_env1], [-1.0, a1_env1], [0.0, 2.3], [1.5, 0.0]])
    torch.testing.assert_close(advantages, expected)


def test_gae_lambda_one_is_the_discounted_return_minus_value_and_zero_is_td() -> None:
    rewards = torch.ones(3, 1)
    zeros = torch.zeros(3, 1)
    values = torch.tensor([[0.5], [0.25], [0.125], [0.0]])
    valid = torch.ones(3, 1, dtype=torch.bool)
    terminated = torch.tensor([[0.0], [0.0], [1.0]])
    mc = generalized_advantages(rewards, values, terminated, zeros, valid, 0.5, 1.0)
    torch.testing.assert_close(mc[:, 0], torch.tensor([1.75 - 0.5, 1.5 - 0.25, 1.0 - 0.125]))
    td = generalized_advantages(rewards, values, terminated, zeros, valid, 0.5, 0.0)
    torch.testing.assert_close(td[:, 0], torch.tensor([1 + 0.125 - 0.5, 1 + 0.0625 - 0.25, 1 - 0.125]))


def test_masked_normalize_per_seed_over_its_own_rows() -> None:
    x = torch.tensor([[1.0, 2.0, 3.0, 6.0], [5.0, 7.0, 100.0, 100.0]])
    mask = torch.tensor([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 0.0, 0.0]])
    y = masked_normalize(x, mask, mask.sum(dim=1))
    assert abs(float(y[0].mean())) < 1e-6 and abs(float(y[0].std()) - 1.0) < 1e-4
    # seed 1: mean 6, sample std sqrt(2) over its two rows; masked rows are zero
    torch.testing.assert_close(y[1], torch.tensor([-1.0, 1.0, 0.0, 0.0]) / math.sqrt(2), rtol=1e-4, atol=1e-6)
    one_row = torch.tensor([[4.0, 9.0]]), torch.tensor([[1.0, 0.0]])
    torch.testing.assert_close(masked_normalize(*one_row, torch.tensor([1.0])), torch.tensor([[0.0, 0.0]]))


# ----------------------------------------------------------------------------------------------
# PPO's losses by hand, per seed over its own rows
# ----------------------------------------------------------------------------------------------


def test_clipped_surrogate_loss_by_hand() -> None:
    # seed 0 clips at 0.2, seed 1 at 0.5 and has a fourth row that is masked out
    ratio = torch.tensor([[1.5, 0.5, 1.1, 1.0], [1.2, 0.4, 1.0, 9.0]], requires_grad=True)
    advantages = torch.tensor([[1.0, 1.0, -2.0, 0.0], [1.0, -1.0, 3.0, 5.0]])
    clip = torch.tensor([[0.2], [0.5]])
    mask = torch.tensor([[1.0, 1.0, 1.0, 0.0], [1.0, 1.0, 1.0, 0.0]])
    loss = clipped_surrogate_loss(ratio, advantages, clip, mask, mask.sum(dim=1))
    # per row max(-A r, -A clip(r)): seed 0: max(-1.5, -1.2), max(-0.5, -0.8), max(2.2, 2.2);
    # seed 1 (clip 0.5): max(-1.2, -1.2), max(0.4, 0.5), max(-3, -3)
    torch.testing.assert_close(loss, torch.tensor([(-1.2 - 0.5 + 2.2) / 3, (-1.2 + 0.5 - 3.0) / 3]))
    loss.sum().backward()
    # clipped rows (seed 0 row 0, seed 1 row 1) and masked rows get no gradient; others -A / 3
    assert ratio.grad is not None
    torch.testing.assert_close(
        ratio.grad, torch.tensor([[0.0, -1 / 3, 2 / 3, 0.0], [-1 / 3, 0.0, -1.0, 0.0]])
    )


def test_value_loss_by_hand_with_and_without_clipping() -> None:
    mask = torch.ones(1, 2)
    count = mask.sum(dim=1)

    def loss(values: list[float], old: list[float], clip: float | None) -> float:
        returns = torch.tensor([[1.0, 1.0]])
        return float(
            clipped_value_loss(torch.tensor([values]), torch.tensor([old]), returns, clip, mask, count)
        )

    assert loss([2.0, 0.0], [1.0, 0.0], None) == pytest.approx(0.5 * (1.0 + 1.0) / 2)
    # clipped to old +- 0.5: row 0 -> 1.5 (loss .25 < 1: keep 1), row 1 -> 0 (loss 1 = 1)
    assert loss([2.0, 0.0], [1.0, 0.0], 0.5) == pytest.approx(0.5 * (1.0 + 1.0) / 2)
    # clipped to 1.1: (1.1 - 1)^2 = .01 < .04, keep .04
    assert loss([1.2, 0.0], [1.0, 0.0], 0.1) == pytest.approx(0.5 * (0.04 + 1.0) / 2)
    # old 3, V = 0 clipped to 2.9: (1.9)^2 = 3.61 > 1, the clipped error counts
    assert loss([0.0, 0.0], [3.0, 0.0], 0.1) == pytest.approx(0.5 * (3.61 + 1.0) / 2)
    # a masked row counts for nothing
    masked = clipped_value_loss(
        torch.tensor([[0.0, 50.0]]),
        torch.zeros(1, 2),
        torch.ones(1, 2),
        None,
        torch.tensor([[1.0, 0.0]]),
        count / 2,
    )
    assert float(masked) == pytest.approx(0.5)


def test_schedules() -> None:
    assert schedule_value(0.2, "constant", 50, 100) == 0.2
    assert schedule_value(0.2, "linear", 0, 100) == 0.2
    assert schedule_value(0.2, "linear", 25, 100) == pytest.approx(0.15)
    assert schedule_value(0.2, "linear", 150, 100) == 0.0


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("activation", ["tanh", "relu", "elu"])
def test_actor_critic_shapes_trunks_and_numpy_policy(shared: bool, activation: str) -> None:
    model = ActorCritic(
        4, 2, (8, 6), activation, shared_trunk=shared, generator=torch.Generator().manual_seed(0)
    )
    hidden = [m for m in model.modules() if isinstance(m, torch.nn.Linear)]
    assert len(hidden) == (2 if shared else 4) + 2  # a shared trunk exists once
    assert [m.out_features for m in model.actor_trunk if isinstance(m, torch.nn.Linear)] == [8, 6]
    observations = torch.randn(5, 4, generator=torch.Generator().manual_seed(1))
    logits, values = model(observations)
    assert logits.shape == (5, 2) and values.shape == (5,)
    policy = CategoricalPolicy(model)
    with torch.no_grad():
        expected = torch.softmax(model.logits(observations), dim=-1).numpy()
    np.testing.assert_allclose(policy.scores(observations.numpy()), expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(policy.act(observations.numpy()), expected.argmax(axis=1))


@pytest.mark.independence
@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_stacked_greedy_actor_acts_as_each_policy_alone(activation: str) -> None:
    """A population's verdicts play every seed's policy in one stacked forward pass: seed i's block
    of rows gets exactly the actions its own policy gives them."""
    policies: list[object] = [
        CategoricalPolicy(
            ActorCritic(4, 2, (16, 16), activation, generator=torch.Generator().manual_seed(seed))
        )
        for seed in range(3)
    ]
    observations = np.random.default_rng(0).normal(size=(3 * 7, 4)).astype(np.float32)
    act = stacked_greedy_actor(policies, obs_dim=4)
    assert act is not None
    alone = [p.act(block) for p, block in zip(policies, np.split(observations, 3), strict=True)]  # type: ignore[attr-defined]
    np.testing.assert_array_equal(act(observations, np.arange(3)), np.concatenate(alone))
    some = np.array([0, 2])  # the blocks still playing late in an evaluation: each still its own
    np.testing.assert_array_equal(act(observations[np.r_[0:7, 14:21]], some), np.concatenate(alone[::2]))
    np.testing.assert_array_equal(act(observations[7:14], np.array([1])), alone[1])
    other_shape = CategoricalPolicy(ActorCritic(4, 2, (8,), activation))
    assert stacked_greedy_actor([*policies, other_shape], obs_dim=4) is None
    assert stacked_greedy_actor([*policies, object()], obs_dim=4) is None


def test_orthogonal_init_gains_and_seeded_init() -> None:
    def build(seed: int, orthogonal: bool = True) -> ActorCritic:
        return ActorCritic(
            4, 2, (64, 64), orthogonal_init=orthogonal, generator=torch.Generator().manual_seed(seed)
        )

    model = build(0)
    weight = model.actor_trunk[2].weight.detach()
    torch.testing.assert_close(weight @ weight.T, 2.0 * torch.eye(64), atol=1e-4, rtol=0)  # gain sqrt(2)
    assert float(model.policy_head.weight.detach().norm(dim=1).max()) == pytest.approx(0.01, rel=1e-4)
    assert float(model.actor_trunk[0].bias.detach().abs().max()) == 0.0
    default = build(0, orthogonal=False)
    assert float(default.actor_trunk[0].bias.detach().abs().max()) > 0.0  # torch's own init has random biases
    assert torch.equal(build(0).policy_head.weight, build(0).policy_head.weight)
    assert not torch.equal(build(0).actor_trunk[0].weight, build(1).actor_trunk[0].weight)


def test_building_a_learner_changes_no_global_state() -> None:
    torch_state, threads = torch.get_rng_state(), torch.get_num_threads()
    numpy_state = np.random.get_state()[1].copy()  # type: ignore[index]
    for agent in AGENTS:
        run(make(agent), 2)
    assert torch.equal(torch.get_rng_state(), torch_state)
    assert torch.get_num_threads() == threads
    assert np.array_equal(np.random.get_state()[1], numpy_state)  # type: ignore[index]


# ----------------------------------------------------------------------------------------------
# Collection
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("agent", AGENTS)
def test_env_steps_are_transitions_and_episode_lengths_add_up(agent: str) -> None:
    learner = make(agent, seed=4)
    steps, lengths = 0, []
    for _ in range(6):
        result = learner.learn()
        steps += result.env_steps
        lengths += result.episode_lengths
        assert all(r == float(n) for r, n in zip(result.episode_returns, result.episode_lengths, strict=True))
    _, data = learner.state_dict(resume=True)
    assert data["env_steps"] == steps
    assert lengths and sum(lengths) <= steps  # autoreset rows are not counted as env steps
    in_progress = sum(data["collector"]["episode_lengths"])
    assert sum(lengths) + in_progress == steps or agent == "reinforce"  # reinforce restarts each batch


def test_reinforce_collects_whole_episodes() -> None:
    learner = make("reinforce", seed=1)
    result = learner.learn()
    assert len(result.episode_returns) == 2  # one whole episode from each env
    assert result.env_steps == sum(result.episode_lengths)


# ----------------------------------------------------------------------------------------------
# Determinism, checkpoints, exact resume
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("agent", AGENTS)
def test_same_seed_same_result(agent: str) -> None:
    a, b, c = make(agent, seed=7), make(agent, seed=7), make(agent, seed=8)
    assert run(a, 4) == run(b, 4)
    assert torch.equal(flat_params(a), flat_params(b))
    run(c, 4)
    assert not torch.equal(flat_params(a), flat_params(c))


@pytest.mark.parametrize("agent", AGENTS)
@pytest.mark.parametrize("simulator", ["fast", "gymnasium"])
def test_resume_continues_exactly(agent: str, simulator: str) -> None:
    a = make(agent, seed=3, simulator=simulator)
    run(a, 3)
    tensors, data = a.state_dict(resume=True)
    b = make(agent, seed=999, simulator=simulator)  # another seed: everything must come from the state
    b.load_state_dict({k: v.clone() for k, v in tensors.items()}, data)
    results_a = [a.learn() for _ in range(3)]
    results_b = [b.learn() for _ in range(3)]
    assert [r.episode_returns for r in results_a] == [r.episode_returns for r in results_b]
    assert [r.scalars for r in results_a] == [r.scalars for r in results_b]
    assert torch.equal(flat_params(a), flat_params(b))
    assert torch.equal(a.state_dict(True)[0]["rng.torch"], b.state_dict(True)[0]["rng.torch"])


@pytest.mark.parametrize("agent", AGENTS)
def test_resume_on_another_env_continues_its_episodes_exactly(agent: str) -> None:
    """Acrobot's envs are put back mid-episode too (envs/resumable_envs.py), not restarted."""
    acrobot = env_info("Acrobot-v1")
    a = make(agent, seed=3, env=acrobot)
    run(a, 2)
    tensors, data = a.state_dict(resume=True)
    b = make(agent, seed=999, env=acrobot)
    b.load_state_dict({k: v.clone() for k, v in tensors.items()}, data)
    results_a = [a.learn() for _ in range(2)]
    results_b = [b.learn() for _ in range(2)]
    assert [r.episode_returns for r in results_a] == [r.episode_returns for r in results_b]
    assert torch.equal(flat_params(a), flat_params(b))


@pytest.mark.parametrize("agent", AGENTS)
def test_save_load_gives_the_same_action_probabilities(agent: str, tmp_path: Path) -> None:
    config = SMALL[agent](shared_trunk=agent == "a2c", activation="relu")
    learner = one_seed(agent, config, CARTPOLE, 1)
    run(learner, 2)
    tensors, data = learner.state_dict(resume=False)
    meta = {
        "agent": agent,
        "env_id": "CartPole-v1",
        "config": dataclasses.asdict(config),
        "learner": data,
    }
    save_checkpoint(tmp_path / "best.pt", Checkpoint(meta=meta, tensors=tensors))
    policy = get_agent(agent).policy_from_checkpoint(load_checkpoint(tmp_path / "best.pt"))
    assert isinstance(policy, ScoredPolicy)
    observations = np.random.default_rng(0).normal(size=(32, 4)).astype(np.float32)
    np.testing.assert_array_equal(policy.scores(observations), learner.policy().scores(observations))
    np.testing.assert_array_equal(policy.act(observations), learner.policy().act(observations))


def test_policy_is_a_frozen_snapshot() -> None:
    learner = make("ppo", seed=2)
    policy = learner.policy()
    observations = np.random.default_rng(1).normal(size=(16, 4)).astype(np.float32)
    before = policy.scores(observations).copy()
    run(learner, 2)
    np.testing.assert_array_equal(policy.scores(observations), before)
    assert not np.array_equal(learner.policy().scores(observations), before)


# ----------------------------------------------------------------------------------------------
# Registry, presets and bad settings
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("agent", AGENTS)
def test_registered_with_probability_scores(agent: str) -> None:
    spec = get_agent(agent)
    assert spec.name == agent and "probabilit" in spec.score_label


def test_presets() -> None:
    assert set(preset_names("ppo")) >= {"default", "rl-zoo", "cleanrl"}
    assert set(preset_names("a2c")) >= {"default", "rl-zoo"}
    assert "default" in preset_names("reinforce")
    zoo, settings = resolve_config("ppo", PPOConfig, "rl-zoo")
    assert (zoo.num_envs, zoo.n_steps, zoo.minibatch_size, zoo.n_epochs) == (8, 32, 256, 20)
    assert (zoo.gamma, zoo.gae_lambda, zoo.ent_coef, zoo.lr, zoo.clip_range) == (0.98, 0.8, 0.0, 1e-3, 0.2)
    assert (zoo.lr_schedule, zoo.clip_schedule, zoo.schedule_steps, settings.budget) == (
        "linear",
        "linear",
        100_000,
        "100k",
    )
    clean, settings = resolve_config("ppo", PPOConfig, "cleanrl")
    assert (
        clean.num_envs,
        clean.n_steps,
        clean.n_epochs,
        clean.num_envs * clean.n_steps // clean.minibatch_size,
    ) == (
        4,
        128,
        4,
        4,
    )
    assert (clean.lr, clean.lr_schedule, clean.gamma, clean.gae_lambda, clean.clip_range) == (
        2.5e-4,
        "linear",
        0.99,
        0.95,
        0.2,
    )
    assert (clean.ent_coef, clean.vf_coef, clean.max_grad_norm, settings.budget) == (0.01, 0.5, 0.5, "500k")
    a2c_zoo, settings = resolve_config("a2c", A2CConfig, "rl-zoo")
    assert (a2c_zoo.num_envs, a2c_zoo.ent_coef, settings.budget) == (8, 0.0, "500k")


PRESET_ENVS = {"mountaincar": "MountainCar-v0", "acrobot": "Acrobot-v1"}


@pytest.mark.parametrize("agent", AGENTS)
def test_each_preset_runs_a_few_steps(agent: str) -> None:
    """Each preset on its env: the mountaincar presets' standardization fits MountainCar's two numbers."""
    spec = get_agent(agent)
    for preset in preset_names(agent):
        config, _ = resolve_config(agent, spec.config_cls, preset)
        env = env_info(PRESET_ENVS[preset]) if preset in PRESET_ENVS else CARTPOLE
        assert one_seed(spec, config, env, 0).learn().env_steps > 0


@pytest.mark.parametrize(
    ("agent", "overrides", "message"),
    [
        ("ppo", {"num_envs": "0"}, "num_envs must be >= 1"),
        ("a2c", {"num_envs": "0"}, "num_envs must be >= 1"),
        ("reinforce", {"num_envs": "0"}, "num_envs must be >= 1"),
        ("ppo", {"clip_range": "0"}, "clip_range must be > 0"),
        ("ppo", {"clip_range": "-0.1"}, "clip_range must be > 0"),
        ("ppo", {"gae_lambda": "1.5"}, "gae_lambda must be in"),
        ("a2c", {"gae_lambda": "-0.1"}, "gae_lambda must be in"),
        ("ppo", {"lr": "nan"}, "lr.*finite"),
        ("ppo", {"gamma": "inf"}, "gamma.*finite"),
        ("a2c", {"ent_coef": "nan"}, "ent_coef.*finite"),
        ("ppo", {"target_kl": "inf"}, "target_kl.*finite"),
        ("ppo", {"n_epochs": "0"}, "n_epochs must be >= 1"),
        ("ppo", {"minibatch_size": "0"}, "minibatch_size must be >= 1"),
        ("ppo", {"lr_schedule": "cosine"}, "lr_schedule must be one of"),
        ("ppo", {"clip_schedule": "cosine"}, "clip_schedule must be one of"),
        ("a2c", {"optimizer": "sgd"}, "optimizer must be one of"),
        ("ppo", {"activation": "sigmoid"}, "activation must be one of"),
        ("ppo", {"hidden_sizes": "64,0"}, "hidden_sizes must all be >= 1"),
        ("reinforce", {"gamma": "1.5"}, "gamma must be in"),
    ],
)
def test_bad_settings_are_rejected_with_one_line(agent: str, overrides: dict[str, str], message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        resolve_config(agent, get_agent(agent).config_cls, "default", overrides)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("setting", ["num_envs=0", "clip_range=0", "gae_lambda=2", "lr=nan", "vf_coef=inf"])
def test_cli_refuses_bad_settings_before_a_run_folder_exists(setting: str, tmp_path: Path, capsys) -> None:
    from cartpole.cli.main import main

    runs = tmp_path / "runs"
    assert main(["train", "ppo", "--set", setting, "--runs-dir", str(runs), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not runs.exists() or not any(runs.iterdir())


# ----------------------------------------------------------------------------------------------
# Through the shared loop: run folder, metrics, load_policy
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("agent", AGENTS)
def test_train_writes_metrics_rows_and_a_loadable_checkpoint(agent: str, tmp_path: Path) -> None:
    overrides = {"hidden_sizes": "16,16", "eval_every": "1000", "eval_screen_episodes": "2"}
    outcome = train(agent, seed=0, overrides=overrides, budget="2k", runs_dir=tmp_path, device="cpu")
    rows = [r for r in outcome.run.metrics() if "train/policy_loss" in r]
    assert rows
    expected = {"train/policy_loss", "train/entropy", "train/learning_rate"}
    if agent != "reinforce" or outcome.run.config()["config"]["baseline"]:
        expected |= {"train/value_loss", "train/explained_variance"}
    if agent == "ppo":
        expected |= {"train/approx_kl", "train/clip_fraction", "train/clip_range"}
    assert expected <= set(rows[-1])
    policy = load_policy(outcome.run.path)
    assert isinstance(policy, ScoredPolicy)
    scores = policy.scores(np.zeros((3, 4), dtype=np.float32))
    np.testing.assert_allclose(scores.sum(axis=1), 1.0, rtol=1e-6)


# ----------------------------------------------------------------------------------------------
# What the update settings mean (test_settings_matter.py checks that each one changes something)
# ----------------------------------------------------------------------------------------------


def optimizer_steps(learner: OneSeed) -> int:
    _, data = learner.state_dict(resume=True)
    return int(data["optim_steps"])


@pytest.mark.parametrize(("n_epochs", "minibatch_size"), [(1, 1000), (3, 1000), (2, 16), (4, 20)])
def test_ppo_takes_epochs_times_minibatches_gradient_steps(n_epochs: int, minibatch_size: int) -> None:
    learner = make("ppo", seed=5, n_epochs=n_epochs, minibatch_size=minibatch_size)
    rows = learner.learn().env_steps
    assert optimizer_steps(learner) == n_epochs * math.ceil(rows / minibatch_size)


def test_ppo_target_kl_stops_the_epochs_early() -> None:
    free = make("ppo", seed=5, n_epochs=8, lr=1e-2)
    free.learn()
    capped = make("ppo", seed=5, n_epochs=8, lr=1e-2, target_kl=1e-4)
    scalars = capped.learn().scalars
    assert scalars["train/stopped_early"] == 1.0
    assert 1 <= optimizer_steps(capped) < optimizer_steps(free)


def test_ppo_clip_range_bounds_the_ratio_that_gets_gradient() -> None:
    """With a tiny clip range most rows leave the trust region within the epochs; with a wide one none."""
    tight = make("ppo", seed=5, n_epochs=8, lr=1e-2, clip_range=1e-3).learn().scalars
    wide = make("ppo", seed=5, n_epochs=8, lr=1e-2, clip_range=10.0).learn().scalars
    assert tight["train/clip_fraction"] > 0.3 and wide["train/clip_fraction"] == 0.0


@pytest.mark.parametrize("agent", ["ppo", "a2c", "reinforce"])
def test_linear_learning_rate_schedule_decays_to_zero(agent: str) -> None:
    learner = make(agent, seed=1, lr_schedule="linear", schedule_steps=300, lr=1e-3)
    seen, steps_before = [], 0
    for _ in range(6):
        result = learner.learn()
        seen.append((steps_before, result.scalars["train/learning_rate"]))
        steps_before += result.env_steps
    for steps, lr in seen:
        assert lr == pytest.approx(1e-3 * max(0.0, 1.0 - steps / 300))
    assert seen[-1][1] == 0.0 or steps_before < 300
    constant = make(agent, seed=1, lr=1e-3)
    assert {run(constant, 3)[i]["train/learning_rate"] for i in range(3)} == {1e-3}


def test_ppo_linear_clip_schedule() -> None:
    learner = make("ppo", seed=1, clip_schedule="linear", schedule_steps=200, clip_range=0.2)
    steps_before = 0
    for _ in range(4):
        result = learner.learn()
        assert result.scalars["train/clip_range"] == pytest.approx(0.2 * max(0.0, 1 - steps_before / 200))
        steps_before += result.env_steps


def test_ppo_value_clipping_limits_the_value_step() -> None:
    """A value clipped to old +- 1e-6 gets no gradient once it has left that range (after its first
    step): over 10 epochs the critic moves far less than unclipped."""

    def critic_change(clip_range_vf: float | None) -> float:
        learner = make("ppo", seed=2, clip_range_vf=clip_range_vf, n_epochs=10, max_grad_norm=None)
        before = {k: v for k, v in model_tensors(learner).items() if "critic" in k or "value" in k}
        learner.learn()
        after = model_tensors(learner)
        return sum(float((after[k] - v).abs().max()) for k, v in before.items())

    assert critic_change(1e-6) < 0.5 * critic_change(None)


def test_advantage_normalization_makes_the_policy_step_scale_free() -> None:
    """Scaling every reward by 100 scales the raw advantages by 100; normalized, the actor's first step
    barely changes, unnormalized it grows (a critic-free check through the policy loss metric)."""
    loss_normalized = make("ppo", seed=3, normalize_advantages=True).learn().scalars["train/policy_loss"]
    loss_raw = make("ppo", seed=3, normalize_advantages=False).learn().scalars["train/policy_loss"]
    assert abs(loss_normalized) < 1.0 < abs(loss_raw)


def test_reinforce_baseline_trains_a_critic_and_reports_it() -> None:
    with_baseline = make("reinforce", seed=1, baseline=True).learn().scalars
    without = make("reinforce", seed=1, baseline=False).learn().scalars
    assert "train/value_loss" in with_baseline and "train/value_loss" not in without


@pytest.mark.parametrize("agent", AGENTS)
def test_resumed_run_writes_the_rows_of_an_uninterrupted_one(agent: str, tmp_path: Path) -> None:
    """Train to 1.5k env steps, resume to 3k: the same metrics rows as one run to 3k (bit for bit)."""
    from cartpole.training import resume

    settings = {"hidden_sizes": "16,16", "eval_every": "1000", "eval_screen_episodes": "2"}
    whole = train(agent, seed=3, overrides=settings, budget="3k", runs_dir=tmp_path / "a", device="cpu")
    part = train(agent, seed=3, overrides=settings, budget="1500", runs_dir=tmp_path / "b", device="cpu")
    run = part.run
    config = run.config()
    config["budget"] = whole.run.config()["budget"]  # as if the 3k run had been interrupted at 1.5k
    run.write_config(config)
    run.write_status(run.status() | {"state": "interrupted"})
    finished = resume(run.path, device="cpu")

    def rows(metrics: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [
            {k: v for k, v in r.items() if k not in ("time", "time/sps")}
            for r in metrics
            if "eval/mean_return" not in r
        ]

    assert rows(run.metrics()) == rows(whole.run.metrics())
    assert finished.state.env_steps == whole.state.env_steps
