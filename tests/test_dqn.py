"""DQN: targets, collection, determinism, checkpoints, presets, config errors, and that it learns."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from one_seed import one_seed

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.dqn import td_gradient, td_targets
from cartpole.agents.dqn.q_network import QNetwork
from cartpole.agents.dqn.replay import Minibatch
from cartpole.agents.registry import get_agent
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.evaluation import ScoredPolicy
from cartpole.runs import Checkpoint, load_checkpoint, save_checkpoint
from cartpole.training.config import resolve_config

CARTPOLE = env_info("CartPole-v1")
PRESETS = ("default", "tutorial-keras", "tutorial-pytorch")
DQN = get_agent("dqn")


def small_config(**changes: object) -> DQNConfig:
    """A tiny, quick config for mechanics tests."""
    base = DQNConfig(hidden_sizes=(16, 16), num_envs=3, learning_starts=20, batch_size=8, buffer_size=500)
    return dataclasses.replace(base, **changes)


def make_learner(config: DQNConfig, seed: int, env: object = CARTPOLE) -> Any:
    """A DQN learner through the registry, as the training loop builds one."""
    return one_seed(DQN, config, env, seed, "cpu")


def flat_params(learner: Any) -> torch.Tensor:
    """The greedy policy's parameters (the tensors of a policy-only state dict), flattened."""
    tensors, _ = learner.state_dict(resume=False)
    return torch.cat([tensors[k].detach().flatten() for k in sorted(tensors)])


# ----------------------------------------------------------------------------------------------
# The Q-network: numpy greedy path against the torch forward
# ----------------------------------------------------------------------------------------------


def torch_q(net: QNetwork, observations: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.from_numpy(observations)).numpy()


@pytest.mark.parametrize("activation", ["relu", "tanh", "elu", "gelu"])
@pytest.mark.parametrize(("dueling", "dropout"), [(False, 0.0), (True, 0.0), (False, 0.3), (True, 0.5)])
def test_numpy_q_values_equal_the_torch_forward(activation: str, dueling: bool, dropout: float) -> None:
    torch.manual_seed(0)
    config = DQNConfig(hidden_sizes=(32, 16), activation=activation, dueling=dueling, dropout=dropout)
    net = QNetwork(4, 3, config).eval()
    for p in net.parameters():  # weights of a trained net's scale, so differences would show
        p.data.normal_(0.0, 0.5)
    rng = np.random.default_rng(0)
    for n in (1, 4, 100, 5000):  # small batches (numpy on CPU) and a big one (torch)
        observations = rng.normal(scale=2.0, size=(n, 4)).astype(np.float32)
        q = net.q_values(observations)
        assert q.shape == (n, 3) and q.dtype == np.float32
        np.testing.assert_allclose(q, torch_q(net, observations), rtol=1e-5, atol=1e-5)


def test_numpy_q_values_follow_in_place_updates_and_replaced_tensors() -> None:
    torch.manual_seed(0)
    net = QNetwork(4, 2, DQNConfig(hidden_sizes=(16, 16))).eval()
    observations = np.random.default_rng(1).normal(size=(5, 4)).astype(np.float32)
    before = net.q_values(observations)
    with torch.no_grad():
        for p in net.parameters():  # as an optimizer step does: in place
            p.add_(0.1 * torch.randn_like(p))
    after = net.q_values(observations)
    assert not np.array_equal(before, after)
    np.testing.assert_allclose(after, torch_q(net, observations), rtol=1e-5, atol=1e-5)
    fresh = QNetwork(4, 2, DQNConfig(hidden_sizes=(16, 16)))
    fresh.load_state_dict(net.state_dict(), assign=True)  # new tensors
    np.testing.assert_allclose(fresh.eval().q_values(observations), after, rtol=1e-6, atol=1e-6)


def test_dropout_keeps_a_share_1_minus_p_scaled_up_while_training_and_is_off_in_eval_mode() -> None:
    """One hidden layer of 2000 units that all output 1, summed by the head: the training forward
    gives (kept units) / (1 - p), about 2000 on average; the eval forward gives exactly 2000."""
    p, width = 0.3, 2000
    net = QNetwork(4, 1, DQNConfig(hidden_sizes=(width,), dropout=p))
    first, head = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    with torch.no_grad():
        first.weight.zero_(), first.bias.fill_(1.0), head.weight.fill_(1.0), head.bias.zero_()
    observations = torch.zeros(400, 4)
    torch.manual_seed(0)
    with torch.no_grad():
        kept = net.train()(observations).squeeze(1) * (1 - p)  # units kept per row
        assert torch.allclose(kept, kept.round(), atol=1e-2)  # each kept unit scaled by 1/(1-p)
        assert abs(float(kept.mean()) / width - (1 - p)) < 0.005
        torch.testing.assert_close(net.eval()(observations), torch.full((400, 1), float(width)))


def test_the_optimizer_is_adam_with_the_configured_learning_rate() -> None:
    """Adam's first step moves each parameter by lr * g / (|g| + eps): about lr wherever g != 0."""
    for lr in (1e-3, 3e-2):
        learner = make_learner(small_config(learning_starts=0, gradient_steps=1, lr=lr), seed=5)
        before = flat_params(learner)
        assert learner.learn().scalars["train/gradient_steps"] == 1
        moved = (flat_params(learner) - before).abs()
        assert float(moved.max()) <= lr * (1 + 1e-4)
        assert float(moved[moved > 0].median()) == pytest.approx(lr, rel=1e-2)


def test_a_linear_lr_schedule_decays_each_step_to_nothing_at_schedule_steps() -> None:
    """Adam's first step moves a parameter by about the learning rate: 3 envs, 12 schedule steps,
    the first round (at 3 env steps) runs at 3/4 of lr; from 12 env steps on, nothing moves."""
    lr = 3e-2
    config = small_config(learning_starts=0, gradient_steps=1, lr=lr, lr_schedule="linear", schedule_steps=12)
    learner = make_learner(config, seed=5)
    before = flat_params(learner)
    env_steps = learner.learn().env_steps
    assert env_steps == 3
    moved = (flat_params(learner) - before).abs()
    assert float(moved[moved > 0].median()) == pytest.approx(0.75 * lr, rel=1e-2)
    while env_steps < 12:
        env_steps += learner.learn().env_steps
    settled = flat_params(learner)
    assert learner.learn().scalars["train/gradient_steps"] > 0
    assert torch.equal(flat_params(learner), settled)


# ----------------------------------------------------------------------------------------------
# The Bellman target
# ----------------------------------------------------------------------------------------------


def test_target_bootstraps_at_truncation_but_not_at_termination() -> None:
    rewards = torch.tensor([1.0, 1.0, 1.0])
    terminated = torch.tensor([0.0, 1.0, 0.0])  # row 0: truncated at the time limit; row 2: mid-episode
    next_q = torch.tensor([[10.0, 20.0], [10.0, 20.0], [3.0, 1.0]])
    targets = td_targets(rewards, terminated, next_q, None, gamma=0.5)
    torch.testing.assert_close(targets, torch.tensor([1.0 + 0.5 * 20.0, 1.0, 1.0 + 0.5 * 3.0]))


def test_double_dqn_target_lets_the_online_net_choose_the_action() -> None:
    rewards, terminated = torch.zeros(2), torch.zeros(2)
    next_q_target = torch.tensor([[1.0, 5.0], [7.0, 2.0]])
    next_q_online = torch.tensor([[9.0, 0.0], [0.0, 9.0]])  # picks action 0, then action 1
    targets = td_targets(rewards, terminated, next_q_target, next_q_online, gamma=1.0)
    torch.testing.assert_close(targets, torch.tensor([1.0, 2.0]))


@pytest.mark.parametrize("loss", ["huber", "mse"])
@pytest.mark.parametrize("double", [True, False])
def test_the_td_gradients_numba_pass_gives_torchs_bits(loss: str, double: bool) -> None:
    """On the CPU the Q-values' gradient and the Bellman targets come from one numba pass; it gives
    the bits of the torch operations it replaces (``kernel=False``), over 3 seeds with padding rows
    (weight 0), terminations, ties between the next actions' values and NaNs (a diverged network:
    torch's argmax takes the first NaN, and NaN errors stay NaN)."""
    generator = torch.Generator().manual_seed(0)
    seeds, rows, n_actions = 3, 64, 3
    q_all = torch.randn(seeds, rows, n_actions, generator=generator) * 3
    next_q = torch.randn(2, seeds, rows, n_actions, generator=generator) * 3
    next_q[:, :, :8] = next_q[:, :, :8].round()  # ties
    next_q[1, 0, 8, 1] = next_q[0, 1, 9, 2] = math.nan
    q_all[2, 10, :] = math.nan
    actions = torch.randint(0, n_actions, (seeds, rows, 1), generator=generator)
    minibatch = Minibatch(
        torch.zeros(seeds, rows, 4),
        torch.zeros(seeds, rows, 4),
        actions,
        torch.rand(seeds, rows, generator=generator),
        (torch.rand(seeds, rows, generator=generator) < 0.2).float(),
    )
    row_weights = torch.full((seeds, rows), 1 / 48)
    row_weights[:, 48:] = 0.0
    chooser = next_q[1] if double else next_q[0]
    got = td_gradient(q_all, minibatch, next_q[0], chooser, row_weights, 0.985**3, loss)
    expected = td_gradient(q_all, minibatch, next_q[0], chooser, row_weights, 0.985**3, loss, kernel=False)
    for kernels, torchs in zip(got, expected, strict=True):
        assert torch.equal(kernels.nan_to_num(7.0), torchs.nan_to_num(7.0))
        assert torch.equal(kernels.isnan(), torchs.isnan())
    assert got[0].isnan().any() and (got[0] != 0).sum() > 100


def test_collection_stores_transitions_only_never_the_autoreset_step() -> None:
    """With next-step autoreset the step after an episode's end only resets its env: it is no
    transition, so no stored row starts from a final state; terminations are marked, every step
    counted once, and the episodes reported with their raw returns."""
    learner = make_learner(small_config(num_envs=2, learning_starts=10_000), seed=0)
    results = [learner.learn() for _ in range(200)]
    tensors, data = learner.state_dict(resume=True)
    rows = {k.removeprefix("replay."): v.numpy() for k, v in tensors.items() if k.startswith("replay.")}
    observations, terminated = rows["observations"], rows["terminated"] == 1.0
    angle = 12 * 2 * math.pi / 360  # CartPole ends at |x| > 2.4 or |theta| > 12 degrees
    assert np.all(np.abs(observations[:, 0]) <= 2.4) and np.all(np.abs(observations[:, 2]) <= angle)
    after = rows["next_observations"]
    np.testing.assert_array_equal(terminated, (np.abs(after[:, 0]) > 2.4) | (np.abs(after[:, 2]) > angle))
    lengths = [length for r in results for length in r.episode_lengths]
    assert len(lengths) == int(terminated.sum()) > 5
    assert [r for res in results for r in res.episode_returns] == [float(n) for n in lengths]
    assert sum(r.env_steps for r in results) == len(observations) == data["env_steps"]
    assert 400 - len(lengths) <= len(observations) <= 400 - len(lengths) + 2  # an autoreset per episode


# ----------------------------------------------------------------------------------------------
# Determinism, checkpoints, resume
# ----------------------------------------------------------------------------------------------


def test_same_seed_same_result_on_cpu() -> None:
    a = make_learner(small_config(), seed=7)
    b = make_learner(small_config(), seed=7)
    results_a = [a.learn() for _ in range(150)]
    results_b = [b.learn() for _ in range(150)]
    assert [r.episode_returns for r in results_a] == [r.episode_returns for r in results_b]
    assert [r.scalars for r in results_a] == [r.scalars for r in results_b]
    assert results_a[-1].scalars["train/gradient_steps"] > 0
    assert torch.equal(flat_params(a), flat_params(b))
    c = make_learner(small_config(), seed=8)
    for _ in range(150):
        c.learn()
    assert not torch.equal(flat_params(a), flat_params(c))


@pytest.mark.parametrize("activation", ["relu", "tanh", "elu", "gelu"])
@pytest.mark.parametrize("dueling", [False, True], ids=["plain", "dueling"])
def test_greedy_policy_gives_the_networks_q_values_without_dropout(activation: str, dueling: bool) -> None:
    """The policy is a numpy snapshot of the network: its scores are the network's own Q-values in eval
    mode (no dropout), and training the network afterwards does not change them."""
    config = small_config(activation=activation, dueling=dueling, dropout=0.3)
    learner = make_learner(config, seed=2)
    for _ in range(40):
        learner.learn()
    policy = learner.policy()
    observations = np.random.default_rng(1).normal(size=(64, 4)).astype(np.float32)
    net = QNetwork(4, 2, config)
    net.load_state_dict({k.removeprefix("q_net."): v for k, v in learner.state_dict(False)[0].items()})
    expected = net.eval().q_values(observations)
    np.testing.assert_allclose(policy.scores(observations), expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(policy.act(observations), policy.scores(observations).argmax(axis=1))
    for _ in range(40):
        learner.learn()
    np.testing.assert_allclose(policy.scores(observations), expected, rtol=1e-5, atol=1e-5)


def test_save_load_gives_the_same_q_values(tmp_path: Path) -> None:
    config = small_config(dueling=True)
    learner = make_learner(config, seed=1)
    for _ in range(60):
        learner.learn()
    tensors, data = learner.state_dict(resume=False)
    meta = {"agent": "dqn", "env_id": "CartPole-v1", "config": dataclasses.asdict(config), "learner": data}
    save_checkpoint(tmp_path / "best.pt", Checkpoint(meta=meta, tensors=tensors))
    policy = DQN.policy_from_checkpoint(load_checkpoint(tmp_path / "best.pt"))
    assert isinstance(policy, ScoredPolicy)
    observations = np.random.default_rng(0).normal(size=(32, 4)).astype(np.float32)
    np.testing.assert_array_equal(policy.scores(observations), learner.policy().scores(observations))
    np.testing.assert_array_equal(policy.act(observations), learner.policy().act(observations))


def test_resume_continues_exactly() -> None:
    config = small_config()
    a = make_learner(config, seed=3)
    for _ in range(80):
        a.learn()
    tensors, data = a.state_dict(resume=True)
    b = make_learner(config, seed=999)  # another seed: everything must be restored
    b.load_state_dict({k: v.clone() for k, v in tensors.items()}, data)
    results_a = [a.learn() for _ in range(80)]
    results_b = [b.learn() for _ in range(80)]
    assert [r.episode_returns for r in results_a] == [r.episode_returns for r in results_b]
    assert [r.scalars for r in results_a] == [r.scalars for r in results_b]
    assert torch.equal(flat_params(a), flat_params(b))


def test_policy_is_a_frozen_snapshot() -> None:
    learner = make_learner(small_config(learning_starts=0), seed=2)
    policy = learner.policy()
    observations = np.zeros((4, 4), dtype=np.float32)
    before = policy.scores(observations)
    for _ in range(30):
        learner.learn()
    np.testing.assert_array_equal(policy.scores(observations), before)


# ----------------------------------------------------------------------------------------------
# Presets and config errors
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS)
def test_each_preset_loads_and_runs_a_few_steps(preset: str) -> None:
    config, _ = resolve_config("dqn", DQNConfig, preset)
    config = dataclasses.replace(config, learning_starts=min(config.learning_starts, 10))
    learner = make_learner(config, seed=0)
    for _ in range(40):
        result = learner.learn()
    assert result.scalars["train/gradient_steps"] > 0
    assert np.isfinite(result.scalars["train/loss"])
    assert 0.0 <= result.scalars["train/epsilon"] <= 1.0


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"lr": "-0.001"}, "lr must be > 0"),
        ({"batch_size": "0"}, "batch_size must be >= 1"),
        ({"gamma": "1.5"}, "gamma must be in"),
        ({"loss": "l3"}, "loss must be one of"),
        ({"epsilon_schedule": "cosine"}, "epsilon_schedule must be one of"),
        ({"lr_schedule": "cosine"}, "lr_schedule must be one of"),
        ({"schedule_steps": "0"}, "schedule_steps must be >= 1"),
        ({"hidden_sizes": "64,0"}, "hidden_sizes must all be >= 1"),
        ({"no_such_knob": "1"}, "unknown setting 'no_such_knob'"),
        ({"lr": "fast"}, "lr='fast' is not a valid"),
    ],
)
def test_bad_config_values_are_rejected_with_one_line(overrides: dict[str, str], message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        resolve_config("dqn", DQNConfig, "default", overrides)
    assert "\n" not in str(info.value)


def test_unknown_preset_is_rejected_with_one_line() -> None:
    with pytest.raises(ConfigError, match="unknown preset 'nope'") as info:
        resolve_config("dqn", DQNConfig, "nope")
    assert "\n" not in str(info.value)
