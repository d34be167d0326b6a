"""Whole greedy episodes in one compiled loop (cartpole.agents.nn.greedy_play): an evaluation on our
simulator lets a small MLP policy play its episodes itself, and they are the episodes Gymnasium's own
env gives the same policy, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_evaluation import reference_returns
from torch import nn

from cartpole import evaluate
from cartpole.agents.nn.greedy_play import CompiledMLP
from cartpole.agents.nn.numpy_mlp import KERNEL_ACTIVATIONS, NumpyMLP, StackedGreedyActor, StackedNumpyMLP
from cartpole.evaluation import CartPolePlayer, play_greedy_blocks


def drifting_layers(activation: type[nn.Module], scale: float = 1.0, width: int = 16) -> list[nn.Module]:
    """A network that balances the pole while its cart drifts (Drifting, test_evaluation.py, through
    two hidden layers): episodes end anywhere from a few hundred steps to the time limit, so one
    action taken otherwise shows in the returns. Its other units carry small random weights."""
    generator = torch.Generator().manual_seed(int(scale * 1000) + width)
    first, second, head = nn.Linear(4, width), nn.Linear(width, width), nn.Linear(width, 2)
    with torch.no_grad():
        for layer in (first, second, head):
            layer.weight.copy_(torch.randn(layer.weight.shape, generator=generator) * 1e-3)
            layer.bias.zero_()
        first.weight[0] = torch.tensor([-0.05, 0.0, 1.0, 0.15]) * scale
        second.weight[0, 0] = 1.0
        head.weight[0, 0], head.weight[1, 0] = -1.0, 1.0
    return [first, activation(), second, activation(), head]


class Stepped:
    """A greedy MLP policy that can only act (the vector env steps its episodes)."""

    def __init__(self, network: NumpyMLP):
        self.network = network
        self.acted = 0

    def act(self, observations: np.ndarray) -> np.ndarray:
        self.acted += 1
        return self.network(observations).argmax(axis=1)


class Player(Stepped):
    """The same policy, which can also play whole episodes itself (a CartPolePlayer)."""

    def play_cartpole(self, states, params, max_episode_steps, block_size):
        return self.network.play_cartpole(states, params, max_episode_steps, block_size)


@pytest.mark.parametrize("activation", [nn.Tanh, nn.ReLU])
@pytest.mark.parametrize("env_id", ["CartPole-v1", "CartPole-v0"])
def test_a_network_playing_its_own_episodes_plays_gymnasiums_episodes_bit_for_bit(activation, env_id):
    network = NumpyMLP(drifting_layers(activation))
    player, stepped = Player(network), Stepped(network)
    assert isinstance(player, CartPolePlayer)
    report = evaluate(player, env_id, episodes=40, seed=11, simulator="fast")
    assert player.acted == 0  # played in one compiled call, not stepped
    assert report.returns == evaluate(stepped, env_id, episodes=40, seed=11, simulator="fast").returns
    assert report.returns == reference_returns(stepped, env_id, report.seeds)
    assert report.lengths == [int(r) for r in report.returns]
    limit = 500 if env_id == "CartPole-v1" else 200
    assert max(report.returns) == limit and min(report.returns) < 400  # long episodes, some short


def test_on_gymnasiums_env_a_player_is_stepped_like_any_policy():
    player = Player(NumpyMLP(drifting_layers(nn.Tanh)))
    report = evaluate(player, "CartPole-v1", episodes=10, seed=3, simulator="gymnasium")
    assert player.acted > 0
    assert report.returns == evaluate(player, "CartPole-v1", episodes=10, seed=3, simulator="fast").returns


def test_a_stack_of_networks_plays_each_networks_own_episodes():
    """A population's evaluation: network b plays block b, as it does alone."""
    networks = [NumpyMLP(drifting_layers(nn.Tanh, scale)) for scale in (0.5, 1.0, 2.0)]
    stack = StackedNumpyMLP.stack(networks)
    assert stack is not None
    actor = StackedGreedyActor([stack], 4, lambda stacks, x: stacks[0](x), argmax_of=stack)
    seeds = list(range(100, 130))
    returns, lengths = play_greedy_blocks(actor, "CartPole-v1", seeds, "fast", block_size=10)
    for b, network in enumerate(networks):
        alone = evaluate(Stepped(network), "CartPole-v1", episodes=10, seed=100 + 10 * b, simulator="fast")
        assert returns[10 * b : 10 * (b + 1)].tolist() == alone.returns
        assert lengths[10 * b : 10 * (b + 1)].tolist() == alone.lengths
    # Called on observations, the stack acts as each network alone does.
    observations = np.random.default_rng(0).normal(0.0, 0.1, (30, 4)).astype(np.float32)
    actions = actor(observations, np.arange(3))
    alone_actions = [networks[i // 10](observations[i : i + 1]).argmax(axis=1)[0] for i in range(30)]
    assert actions.tolist() == alone_actions


def test_the_compiled_forward_pass_is_the_networks_own():
    torch_layers = drifting_layers(nn.Tanh, width=32)
    torch_layers[0].weight.data += torch.randn(32, 4) * 0.5  # outputs of every size
    network = NumpyMLP(torch_layers)
    x = np.random.default_rng(1).normal(0.0, 1.0, (64, 4)).astype(np.float32)
    with torch.no_grad():
        expected = nn.Sequential(*torch_layers)(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(network(x), expected, rtol=1e-5, atol=1e-5)


def test_a_network_the_kernels_cannot_compute_is_stepped_by_the_vector_env():
    """ELU (no compiled form): the policy acts through NumPy, and the episodes are still Gymnasium's."""
    network = NumpyMLP(drifting_layers(nn.ELU))
    assert network.compiled is None
    assert CompiledMLP.of(network.plan, KERNEL_ACTIVATIONS) is None
    player = Player(network)
    report = evaluate(player, "CartPole-v1", episodes=10, seed=5, simulator="fast")
    assert player.acted > 0
    assert report.returns == reference_returns(player, "CartPole-v1", report.seeds)
