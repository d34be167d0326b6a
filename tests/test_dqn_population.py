"""DQN for a population of seeds (``PopulationDQN``, a single run being a population of one): seeds
independent bit for bit, every setting, resume, checkpoints, devices, and learning."""

from __future__ import annotations

import functools
import json
from dataclasses import asdict
from typing import Any

import numpy as np
import pytest
import torch

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.dqn import PopulationDQN, epsilon_at, td_gradient
from cartpole.agents.dqn.population import dqn_bytes_per_seed, policy_from_checkpoint, seeded_q_network
from cartpole.agents.dqn.q_network import q_network_parameters
from cartpole.agents.dqn.replay import Minibatch
from cartpole.agents.learner import LearnResult
from cartpole.core.config import config_to_dict
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.evaluation import evaluate, play_greedy_blocks
from cartpole.runs import Checkpoint
from cartpole.runs.checkpoint import load_checkpoint, save_checkpoint

CARTPOLE = env_info("CartPole-v1")
SMALL: dict[str, Any] = {
    "hidden_sizes": (16, 16),
    "buffer_size": 2000,
    "batch_size": 32,
    "learning_starts": 64,
    "num_envs": 4,
}


def small_config(**changes: Any) -> DQNConfig:
    return DQNConfig(**(SMALL | changes))


def small_population(seeds: list[int], device: str = "cpu", **changes: Any) -> PopulationDQN:
    return PopulationDQN(small_config(**changes), CARTPOLE, seeds, device)


def learn(population: PopulationDQN, times: int) -> list[dict[int, LearnResult]]:
    return [population.learn() for _ in range(times)]


def same(a: LearnResult, b: LearnResult) -> bool:
    """Equal results, every metric to the bit."""
    return json.dumps(asdict(a)) == json.dumps(asdict(b))


def assert_same_results(a: list[dict[int, LearnResult]], b: list[dict[int, LearnResult]], seed: int) -> None:
    assert len(a) == len(b)
    for call, (x, y) in enumerate(zip(a, b, strict=True)):
        assert same(x[seed], y[seed]), f"call {call}: {x[seed]} != {y[seed]}"


def assert_same_state(a: PopulationDQN, b: PopulationDQN, seed: int) -> None:
    """Everything a resume of ``seed`` would restore is equal: weights, target, Adam, replay rows,
    generators, counters and envs."""
    tensors_a, data_a = a.seed_state_dict(seed, resume=True)
    tensors_b, data_b = b.seed_state_dict(seed, resume=True)
    assert tensors_a.keys() == tensors_b.keys()
    for key in tensors_a:
        assert torch.equal(tensors_a[key], tensors_b[key]), key
    assert json.dumps(data_a, sort_keys=True) == json.dumps(data_b, sort_keys=True)


def head_weight(population: PopulationDQN, seed: int) -> torch.Tensor:
    return population.seed_state_dict(seed, resume=False)[0]["q_net.head.weight"]


# -- seed independence, bit for bit -----------------------------------------------------------------

INDEPENDENCE = [
    {},
    {"double_dqn": False},
    {"dueling": True},
    {"dropout": 0.2},
    {"loss": "mse"},
    {"max_grad_norm": 0.5},
    {"target_network": False, "epsilon_schedule": "multiplicative"},
    {"activation": "tanh", "tau": 1.0, "target_update_interval": 3},
    {"activation": "gelu", "train_freq": 2, "gradient_steps": 3},
    {"n_step": 3},
    # batch and env counts that are no multiple of anything: every per-seed block is padded (see the
    # module docstring); widths that are multiples of 4 (other widths: see the module docstring)
    {"activation": "elu", "batch_size": 20, "num_envs": 3, "hidden_sizes": (12, 20), "buffer_size": 50},
]


@pytest.mark.independence
@pytest.mark.parametrize("changes", INDEPENDENCE, ids=lambda c: ",".join(c) or "default")
def test_a_seed_trains_bit_for_bit_the_same_alone_and_among_others(changes):
    alone = small_population([3], **changes)
    first = small_population([3, 5], **changes)
    last = small_population([5, 8, 3], **changes)
    results = [learn(p, 300) for p in (alone, first, last)]
    assert any("train/loss" in r[3].scalars for r in results[0])  # it did train
    for other, population in zip(results[1:], (first, last), strict=True):
        assert_same_results(results[0], other, 3)
        assert_same_state(alone, population, 3)
    assert not torch.equal(head_weight(first, 5), head_weight(first, 3))  # seeds are not copies


@pytest.mark.independence
def test_a_lone_seed_is_the_same_whether_alone_from_the_start_or_left_alone():
    """Removing all but one seed gives it a ghost twin: it goes on as if it had always been alone."""
    alone, pair = small_population([3]), small_population([3, 5])
    before = learn(alone, 100), learn(pair, 100)
    pair.remove([5])
    assert pair.active_seeds == [3]
    after = learn(alone, 100), learn(pair, 100)
    assert_same_results(before[0] + after[0], before[1] + after[1], 3)
    assert_same_state(alone, pair, 3)


def test_removing_a_seed_leaves_the_others_unchanged():
    three, two = small_population([3, 5, 7]), small_population([3, 7])
    before = learn(three, 120), learn(two, 120)
    three.remove([5])
    assert three.active_seeds == [3, 7]
    after = learn(three, 120), learn(two, 120)
    for seed in (3, 7):
        assert_same_results(before[0] + after[0], before[1] + after[1], seed)
        assert_same_state(three, two, seed)
    assert set(after[0][-1]) == {3, 7}


@functools.cache
def trained_head(**changes: Any) -> torch.Tensor:
    population = small_population([3, 5], **changes)
    learn(population, 100)
    return head_weight(population, 3)


# (settings of the baseline, settings changed): the head's weights after 100 calls must differ.
SETTING_CHANGES: list[tuple[dict[str, Any], dict[str, Any]]] = [
    ({}, {"hidden_sizes": (16, 12)}),
    ({}, {"activation": "tanh"}),
    ({}, {"activation": "elu"}),
    ({}, {"activation": "gelu"}),
    ({}, {"dropout": 0.2}),
    ({}, {"dueling": True}),
    ({}, {"lr": 1e-2}),
    ({}, {"gamma": 0.5}),
    ({}, {"loss": "mse"}),
    ({}, {"max_grad_norm": 0.01}),
    ({}, {"double_dqn": False}),
    ({}, {"target_network": False}),
    ({}, {"target_update_interval": 5}),
    ({}, {"tau": 1.0}),
    ({}, {"buffer_size": 100}),
    ({}, {"batch_size": 8}),
    ({}, {"learning_starts": 200}),
    ({}, {"num_envs": 2}),
    ({}, {"train_freq": 3}),
    ({}, {"gradient_steps": 3}),
    ({}, {"n_step": 3}),
    ({"n_step": 3}, {"gamma": 0.9}),
    ({"epsilon_decay_steps": 100}, {"epsilon_schedule": "exponential"}),
    ({}, {"epsilon_schedule": "multiplicative"}),
    ({}, {"epsilon_start": 0.5}),
    ({}, {"epsilon_end": 0.5, "epsilon_decay_steps": 100}),
    ({}, {"epsilon_decay_steps": 100}),
    ({"epsilon_schedule": "multiplicative"}, {"epsilon_decay_rate": 0.9}),
    ({}, {"termination_reward": -10.0}),
    ({}, {"short_episode_reward": -1.0, "short_episode_length": 100}),
    ({"short_episode_reward": -1.0, "short_episode_length": 100}, {"short_episode_length": 15}),
]


@pytest.mark.parametrize(("base", "changes"), SETTING_CHANGES, ids=lambda c: ",".join(c) or "default")
def test_every_setting_changes_the_training(base, changes):
    assert not torch.equal(trained_head(**(base | changes)), trained_head(**base))


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"epsilon_schedule": "exponential", "epsilon_decay_steps": 200, "epsilon_start": 0.9},
        {"epsilon_schedule": "multiplicative", "epsilon_decay_rate": 0.95, "epsilon_end": 0.3},
    ],
    ids=["linear", "exponential", "multiplicative"],
)
def test_epsilon_follows_its_schedule(changes):
    """Linear and exponential schedules follow the seed's own env steps; the multiplicative one its
    own gradient steps (down to epsilon_end)."""
    config = small_config(**({"epsilon_decay_steps": 300} | changes))
    population = PopulationDQN(config, CARTPOLE, [3, 5])
    env_steps, multiplied, gradient_steps = 0, config.epsilon_start, 0
    seen = []
    for _ in range(150):
        result = population.learn()[3]
        multiplicative = config.epsilon_schedule == "multiplicative"
        expected = multiplied if multiplicative else epsilon_at(config, env_steps, multiplied)
        assert result.scalars["train/epsilon"] == expected
        seen.append(expected)
        env_steps += result.env_steps
        for _ in range(int(result.scalars["train/gradient_steps"]) - gradient_steps):
            if multiplied > config.epsilon_end:
                multiplied = max(config.epsilon_end, multiplied * config.epsilon_decay_rate)
        gradient_steps = int(result.scalars["train/gradient_steps"])
    assert seen[0] == config.epsilon_start and seen[-1] < seen[0]
    if config.epsilon_schedule == "multiplicative":
        assert seen[-1] == config.epsilon_end


def test_no_gradient_step_before_learning_starts_counted_in_the_seeds_own_env_steps():
    """A seed starts training once its own env steps reach learning_starts; then every train_freq
    calls it takes gradient_steps steps. Before that it reports no loss."""
    population = small_population([3, 5], learning_starts=100, train_freq=2, gradient_steps=3)
    env_steps, steps = 0, 0
    for call in range(1, 120):
        result = population.learn()[3]
        env_steps += result.env_steps
        if env_steps >= 100 and call % 2 == 0:
            steps += 3
        assert result.scalars["train/gradient_steps"] == steps
        assert ("train/loss" in result.scalars) == (steps > 0)
        assert ("train/q_mean" in result.scalars) == (steps > 0)
    assert steps > 0


def test_with_n_step_rows_a_seed_trains_once_its_replay_holds_rows():
    """3-step rows reach the replay from the third step on: no gradient step before, even from step 0."""
    population = small_population([1], n_step=3, learning_starts=0)
    steps = [r[1].scalars["train/gradient_steps"] for r in learn(population, 4)]
    assert steps == [0.0, 0.0, 4.0, 8.0]
    assert population.replay.size[0] == 2 * 4


def test_a_seed_behind_the_others_sits_the_gradient_steps_out():
    """A seed resumed at an earlier point than its neighbours trains on its own schedule: until it
    reaches learning_starts it takes no step while they do."""
    late = small_population([9])
    tensors, data = late.seed_state_dict(9, resume=True)
    mixed = small_population([3, 9])
    learn(mixed, 40)  # past learning_starts (64 env steps)
    mixed.load_seed_state_dict(9, tensors, data)  # seed 9 back at its start
    result = mixed.learn()
    assert result[9].scalars["train/gradient_steps"] == 0 and result[3].scalars["train/gradient_steps"] > 0
    alone = small_population([9])
    assert_same_results(learn(alone, 60), [result, *learn(mixed, 59)], 9)


def replay_rows(population: PopulationDQN, seed: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    tensors, data = population.seed_state_dict(seed, resume=True)
    return {k.removeprefix("replay."): v for k, v in tensors.items() if k.startswith("replay.")}, data


def test_termination_reward_replaces_the_reward_of_terminating_transitions():
    population = small_population([3, 5], termination_reward=-10.0, learning_starts=10_000)
    results = learn(population, 200)
    rows, _ = replay_rows(population, 3)
    terminated = rows["terminated"] == 1.0
    assert terminated.any()
    assert (rows["rewards"][terminated] == -10.0).all() and (rows["rewards"][~terminated] == 1.0).all()
    assert all(r == int(r) and r > 0 for res in results for r in res[3].episode_returns)  # raw returns


def test_short_episode_reward_marks_the_last_transition_of_short_episodes():
    population = small_population(
        [3, 5], short_episode_reward=-1.0, short_episode_length=1000, learning_starts=10_000
    )
    results = learn(population, 200)
    rows, _ = replay_rows(population, 3)
    episodes = sum(len(r[3].episode_lengths) for r in results)
    assert episodes > 0 and int((rows["rewards"] == -1.0).sum()) == episodes
    assert int((rows["rewards"] == 1.0).sum()) == len(rows["rewards"]) - episodes


def test_the_replay_memory_keeps_the_newest_buffer_size_rows():
    population = small_population([3, 5], buffer_size=50, learning_starts=10_000)
    results = learn(population, 30)
    rows, data = replay_rows(population, 3)
    collected = sum(r[3].env_steps for r in results)
    assert collected > 50 and data["replay"] == {"capacity": 50, "pos": collected % 50, "size": 50}
    assert len(rows["observations"]) == 50


def test_the_replay_writes_the_same_rows_without_its_host_view():
    """On a GPU the rows are written with ``index_put_`` instead of through the numpy view: the same
    rows in the same slots (the memory wraps around here)."""
    host, device_path = small_population([3, 5], buffer_size=50), small_population([3, 5], buffer_size=50)
    device_path.replay.host = None
    assert_same_results(learn(host, 80), learn(device_path, 80), 3)
    assert_same_state(host, device_path, 3)


# -- resume -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"dropout": 0.2, "epsilon_schedule": "multiplicative", "train_freq": 3, "target_update_interval": 2},
        {"n_step": 4},
    ],
    ids=["default", "dropout,multiplicative,train_freq", "n_step"],
)
def test_resume_continues_exactly(changes, tmp_path):
    """K calls, a checkpoint (written to disk and read back), K more calls in a fresh population ==
    2K calls without a break."""
    straight = small_population([3, 5], **changes)
    results = learn(straight, 150)
    tensors, data = straight.seed_state_dict(3, resume=True)
    path = tmp_path / "latest.pt"
    meta = {
        "agent": "dqn",
        "env_id": "CartPole-v1",
        "config": config_to_dict(straight.config),
        "learner": data,
    }
    save_checkpoint(path, Checkpoint(meta=meta, tensors=tensors))
    checkpoint = load_checkpoint(path)
    resumed = small_population([3, 11], **changes)
    resumed.load_seed_state_dict(3, checkpoint.tensors, checkpoint.meta["learner"])
    assert_same_results(learn(straight, 150), learn(resumed, 150), 3)
    assert_same_state(straight, resumed, 3)
    assert any("train/loss" in r[3].scalars for r in results)


def test_resume_into_a_lone_seed():
    straight = small_population([3, 5])
    learn(straight, 100)
    tensors, data = straight.seed_state_dict(5, resume=True)
    resumed = small_population([5])
    resumed.load_seed_state_dict(5, tensors, data)
    assert_same_results(learn(straight, 100), learn(resumed, 100), 5)
    assert_same_state(straight, resumed, 5)


def test_a_policy_only_checkpoint_is_refused_for_resume():
    population = small_population([3, 5])
    tensors, data = population.seed_state_dict(3, resume=False)
    with pytest.raises(ConfigError):
        population.load_seed_state_dict(3, tensors, data)


# -- checkpoints and policies ---------------------------------------------------------------------


@pytest.mark.parametrize("changes", [{}, {"dueling": True, "dropout": 0.2, "activation": "tanh"}])
def test_a_seed_checkpoint_holds_its_network_and_loads_as_its_policy(changes):
    config = small_config(**changes)
    population = PopulationDQN(config, CARTPOLE, [3, 5, 7])
    learn(population, 100)
    tensors, data = population.seed_state_dict(5, resume=False)
    network = seeded_q_network(config, CARTPOLE, 5).state_dict()
    assert tensors.keys() == {f"q_net.{k}" for k in network}
    assert data == {"obs_dim": 4, "n_actions": 2}
    resume_tensors, resume_data = population.seed_state_dict(5, resume=True)
    assert {k for k in resume_tensors if k.startswith("target_net.")} == {f"target_net.{k}" for k in network}
    assert {"replay.observations", "rng.dropout", "rng.replay"} <= resume_tensors.keys()
    shared = {"env_steps", "calls", "gradient_steps", "epsilon_multiplied", "replay", "rng_numpy"}
    assert shared <= resume_data.keys()

    meta = {"agent": "dqn", "env_id": "CartPole-v1", "config": config_to_dict(config), "learner": data}
    policy = policy_from_checkpoint(Checkpoint(meta=meta, tensors=tensors))
    mine = population.seed_policy(5)
    observations = np.random.default_rng(0).normal(size=(64, 4)).astype(np.float32)
    assert np.array_equal(policy.scores(observations), mine.scores(observations))
    assert np.array_equal(policy.act(observations), mine.act(observations))

    actor = population.greedy_actor([7, 5, 3])
    policies = [population.seed_policy(s) for s in (7, 5, 3)]
    blocks = observations[:48].reshape(3, 16, 4)
    expected = np.concatenate([p.act(b) for p, b in zip(policies, blocks, strict=True)])
    assert np.array_equal(actor(observations[:48], np.arange(3)), expected)
    outer = np.concatenate([blocks[0], blocks[2]])
    assert np.array_equal(actor(outer, np.array([0, 2])), expected[np.r_[0:16, 32:48]])
    assert np.array_equal(actor(blocks[1], np.array([1])), expected[16:32])


def test_the_greedy_actor_plays_the_policies_episodes():
    population = small_population([3, 5])
    learn(population, 100)
    seeds = list(range(100, 106))
    returns, _ = play_greedy_blocks(population.greedy_actor([3, 5]), "CartPole-v1", seeds, "fast", 3)
    for block, seed in enumerate((3, 5)):
        report = evaluate(population.seed_policy(seed), "CartPole-v1", 3, 100 + 3 * block, simulator="fast")
        assert list(returns[3 * block : 3 * block + 3]) == list(report.returns)


def test_seeds_start_from_their_own_network_and_envs():
    config = small_config()
    population = PopulationDQN(config, CARTPOLE, [4, 9])
    tensors, _ = population.seed_state_dict(9, resume=False)
    for name, value in seeded_q_network(config, CARTPOLE, 9).state_dict().items():
        assert torch.equal(tensors[f"q_net.{name}"], value), name
    alone = PopulationDQN(config, CARTPOLE, [9])
    together, apart = population.episodes.observations, alone.episodes.observations
    assert np.array_equal(together[config.num_envs :], apart)
    assert not np.array_equal(together[: config.num_envs], apart)


def test_bytes_per_seed_counts_the_replay_and_the_networks():
    config = DQNConfig()
    estimate = dqn_bytes_per_seed(config, CARTPOLE)
    replay = config.buffer_size * (2 * 4 + 3) * 4
    assert replay + q_network_parameters(config, CARTPOLE) * 4 * 5 < estimate < replay + 16 * 1024**2
    assert dqn_bytes_per_seed(DQNConfig(buffer_size=100_000), CARTPOLE) - estimate == replay
    assert q_network_parameters(config, CARTPOLE) == sum(
        p.numel() for p in seeded_q_network(config, CARTPOLE, 0).parameters()
    )


def test_bytes_per_seed_counts_the_n_step_windows():
    one_step, three_step = DQNConfig(n_step=1), DQNConfig(n_step=3)
    windows = PopulationDQN(three_step, CARTPOLE, [0, 1]).windows
    assert windows is not None and PopulationDQN(one_step, CARTPOLE, [0]).windows is None
    held = sum(a.nbytes for a in (windows.observations, windows.actions, windows.rewards, windows.count))
    assert dqn_bytes_per_seed(three_step, CARTPOLE) - dqn_bytes_per_seed(one_step, CARTPOLE) == held // 2


# -- devices and refusals -------------------------------------------------------------------------


def population_tensors(population: PopulationDQN) -> list[torch.Tensor]:
    net, optimizer = population.net, population.optimizer
    tensors = [net.flat, net.grad, optimizer.exp_avg, optimizer.exp_avg_sq, optimizer.steps]
    tensors += [population.replay.table, *net.params.values()]
    return tensors + ([net.target] if net.target is not None else [])


def test_every_tensor_lives_on_the_population_device():
    """What ``--device cuda`` needs, checked on a CPU: with torch's default device set to another one
    (meta), a tensor the population made without naming its device could not meet the others."""
    torch.set_default_device("meta")
    try:
        population = small_population([3, 5, 7], dropout=0.1, max_grad_norm=1.0, learning_starts=20)
        learn(population, 20)
        population.remove([5])
        learn(population, 2)
        actions = population.greedy_actor([3, 7])(np.zeros((6, 4), dtype=np.float32), np.arange(2))
        tensors, data = population.seed_state_dict(7, resume=True)
        population.load_seed_state_dict(7, tensors, data)
        learn(population, 1)
    finally:
        torch.set_default_device(None)
    assert actions.shape == (6,) and all(t.device.type == "cpu" for t in tensors.values())
    assert all(t.device.type == "cpu" for t in population_tensors(population))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_population_trains_on_cuda_and_its_checkpoints_load_on_the_cpu():
    settings: dict[str, Any] = {"dropout": 0.1, "max_grad_norm": 1.0}
    population = small_population([3, 5], device="cuda", **settings)
    assert all(t.device.type == "cuda" for t in population_tensors(population))
    results = learn(population, 100)
    assert all(r[3].env_steps > 0 for r in results) and "train/loss" in results[-1][3].scalars
    population.remove([5])
    learn(population, 5)
    assert all(t.device.type == "cuda" for t in population_tensors(population))
    tensors, data = population.seed_state_dict(3, resume=True)
    assert all(t.device.type == "cpu" for t in tensors.values())
    on_cpu = small_population([3, 5], **settings)
    on_cpu.load_seed_state_dict(3, tensors, data)
    assert torch.equal(
        on_cpu.seed_state_dict(3, resume=False)[0]["q_net.head.weight"], tensors["q_net.head.weight"]
    )
    learn(on_cpu, 5)
    population.seed_policy(3).act(np.zeros((2, 4), dtype=np.float32))


# -- learning -------------------------------------------------------------------------------------


def autograd_gradients(population: PopulationDQN, batch: torch.Tensor) -> torch.Tensor:
    """The online networks' gradients of the mean Huber (or MSE) loss on ``batch``, by autograd."""
    net, d = population.net, CARTPOLE.obs_dim
    for leaf in net.params.values():
        leaf.grad = None
    q_all = net.forward(net.params, batch[..., :d].contiguous(), population.activation)
    targets = population.targets(
        batch[..., d : 2 * d].contiguous(), batch[..., 2 * d + 1], batch[..., 2 * d + 2]
    )
    q = q_all.gather(2, batch[..., 2 * d].long().unsqueeze(2)).squeeze(2)
    loss_of = (
        torch.nn.functional.smooth_l1_loss
        if population.config.loss == "huber"
        else torch.nn.functional.mse_loss
    )
    loss_of(q, targets, reduction="none").mean(dim=1).sum().backward()
    return torch.cat([net.params[name].grad.reshape(len(population.seeds), -1) for name in net.params], dim=1)


@pytest.mark.parametrize("changes", [{}, {"loss": "mse"}, {"double_dqn": False, "hidden_sizes": (12, 20, 8)}])
def test_a_plain_relu_networks_gradients_by_hand_are_autograds(changes):
    """The hand-written backward of a ReLU MLP (the default preset's path) gives autograd's gradients."""
    population = small_population([3, 5], **changes)
    learn(population, 40)
    assert population.net.plain_relu
    batch = population.replay.gather(
        torch.randint(0, 100, (2, 32), generator=torch.Generator().manual_seed(0))
    )
    expected = autograd_gradients(population, batch)
    net, d = population.net, CARTPOLE.obs_dim
    inputs: list[torch.Tensor] = []
    with torch.no_grad():
        q_all = net.forward(net.params, batch[..., :d].contiguous(), population.activation, inputs=inputs)
    next_observations = batch[..., d : 2 * d].contiguous()
    rewards, terminated = batch[..., 2 * d + 1], batch[..., 2 * d + 2]
    actions = batch[..., 2 * d].long().unsqueeze(2)
    minibatch = Minibatch(
        batch[..., :d].contiguous(), next_observations, actions, rewards.contiguous(), terminated.contiguous()
    )
    row_weights = torch.full((2, 32), 1 / 32)  # every row counts, each seed's mean over its 32
    loss = population.config.loss
    next_q = population.next_q_values(next_observations)
    grad, _ = td_gradient(q_all, minibatch, *next_q, row_weights, population.discount, loss)
    net.backward_by_hand(inputs, grad)
    by_hand = torch.cat([net.params[name].grad.reshape(2, -1) for name in net.params], dim=1)
    assert torch.allclose(by_hand, expected, rtol=1e-5, atol=1e-7)
    assert by_hand.abs().sum() > 0


def test_kept_activation_buffers_give_the_same_values_and_outlive_another_pass():
    """A plain ReLU MLP's passes without autograd write their hidden activations into kept tensors
    (one set per name): the same Q-values and layer inputs as fresh tensors, and a pass under
    another name (the next states') leaves the first pass's inputs, which the backward needs, intact."""
    population = small_population([3, 5])
    learn(population, 40)
    net, d = population.net, CARTPOLE.obs_dim
    batch = population.replay.gather(
        torch.randint(0, 100, (2, 32), generator=torch.Generator().manual_seed(0))
    )
    observations, next_observations = batch[..., :d].contiguous(), batch[..., d : 2 * d].contiguous()
    fresh_inputs: list[torch.Tensor] = []
    kept_inputs: list[torch.Tensor] = []
    with torch.no_grad():
        fresh = net.forward(net.params, observations, population.activation, inputs=fresh_inputs)
        kept = net.forward(net.params, observations, population.activation, inputs=kept_inputs, buffers="a")
        snapshot = [x.clone() for x in kept_inputs]
        other = net.forward(net.params, next_observations, population.activation, buffers="b")
    assert torch.equal(fresh, kept)
    assert all(torch.equal(f, k) for f, k in zip(fresh_inputs, kept_inputs, strict=True))
    assert all(torch.equal(s, k) for s, k in zip(snapshot, kept_inputs, strict=True))
    assert not torch.equal(other, kept)


@pytest.mark.parametrize("changes", [{"dropout": 0.2}, {"dueling": True}, {"activation": "tanh"}])
def test_other_networks_take_autograds_backward(changes):
    assert not small_population([3], **changes).net.plain_relu
