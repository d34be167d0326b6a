"""The Q-network of DQN: an MLP from observations to one Q-value per action, and its greedy policy.
For image observations ``[channels, height, width]`` a small convolutional network comes first
(pixels scaled as darkness, optionally only the last two frames' difference, then ``conv_layers``),
its flattened output feeding the MLP.

Every random draw of a network comes from a ``torch.Generator`` its owner passes in (weight
initialization, dropout masks), never from torch's process-wide generator: building or training a
network changes nothing global, and two networks built from equal generators are equal whatever else
the process does.

Public torch only. The hand-written dropout is there because ``nn.Dropout`` cannot draw from an owned
generator.

This is the network's ``nn.Module`` form: what each seed is initialized as and what a checkpoint
holds (``q_net.*``). A population trains the stacked form
(:class:`~cartpole.agents.dqn.stacked.StackedQNetwork`); the greedy policy (:class:`QNetworkPolicy`)
acts through a NumPy twin of the weights, as the population does (why: :mod:`cartpole.agents.nn`). A
convolutional network has no NumPy twin: its policy is a frozen torch copy.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
import torch
from torch import nn

from cartpole.agents.nn.conv import LastFrameDifference, ScalePixels, conv_output_size, conv_parameters
from cartpole.agents.nn.greedy_play import CompiledMLP
from cartpole.agents.nn.numpy_mlp import KERNEL_ACTIVATIONS, NumpyMLP
from cartpole.envs import EnvInfo
from cartpole.envs.params import CartPoleParams

ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU, "gelu": nn.GELU}


class NetworkShape(Protocol):
    """The settings a Q-network is built from (``DQNConfig`` has them)."""

    hidden_sizes: tuple[int, ...]
    activation: str
    dropout: float
    dueling: bool
    conv_layers: tuple[tuple[int, int, int], ...]
    frame_difference: bool


class GeneratorDropout(nn.Module):
    """``nn.Dropout`` whose masks come from ``generator`` (``nn.Dropout`` only draws from torch's
    process-wide generator): in training mode each unit is zeroed with probability ``p`` and the others
    are scaled by ``1/(1-p)``; in eval mode it is the identity."""

    def __init__(self, p: float, generator: torch.Generator):
        super().__init__()
        if not 0.0 <= p < 1.0:
            raise ValueError(f"dropout probability must be in [0, 1), got {p}")
        self.p = p
        self.generator = generator

    def forward(self, input: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0.0:
            return input
        keep = torch.rand(input.shape, generator=self.generator, device=input.device, dtype=input.dtype)
        return input * (keep >= self.p) / (1.0 - self.p)

    def extra_repr(self) -> str:
        return f"p={self.p}"


def seeded_linear(in_features: int, out_features: int, generator: torch.Generator) -> nn.Linear:
    """``nn.Linear`` with its default initialization (Kaiming-uniform weights, uniform bias in
    ``+-1/sqrt(in_features)``) drawn from ``generator`` instead of torch's global generator."""
    with torch.random.fork_rng(devices=[]):  # its own draws from the global generator are undone
        layer = nn.Linear(in_features, out_features)
    nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
    bound = 1.0 / math.sqrt(in_features)
    nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
    return layer


def seeded_conv2d(
    in_channels: int, out_channels: int, kernel: int, stride: int, generator: torch.Generator
) -> nn.Conv2d:
    """``nn.Conv2d`` (no padding) with its default initialization drawn from ``generator``, as
    :func:`seeded_linear` (fan-in: ``in_channels x kernel x kernel``)."""
    with torch.random.fork_rng(devices=[]):
        layer = nn.Conv2d(in_channels, out_channels, kernel, stride)
    nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
    bound = 1.0 / math.sqrt(in_channels * kernel * kernel)
    assert layer.bias is not None
    nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
    return layer


def network_input_shape(obs_shape: Sequence[int], frame_difference: bool) -> tuple[int, ...]:
    """What the first layer sees of an observation: the image, or its last frames' difference (one
    channel)."""
    shape = tuple(obs_shape)
    return (1, *shape[1:]) if frame_difference and len(shape) == 3 else shape


def conv_trunk(obs_shape: Sequence[int], shape: NetworkShape, generator: torch.Generator) -> nn.Sequential:
    """Scaled pixels (their last frames' difference with ``frame_difference``) through
    ``conv_layers`` (ReLU each), flattened."""
    layers: list[nn.Module] = [ScalePixels()]
    if shape.frame_difference:
        layers.append(LastFrameDifference())
    channels = network_input_shape(obs_shape, shape.frame_difference)[0]
    for filters, kernel, stride in shape.conv_layers:
        layers += [seeded_conv2d(channels, filters, kernel, stride, generator), nn.ReLU()]
        channels = filters
    return nn.Sequential(*layers, nn.Flatten())


class QNetwork(nn.Module):
    """MLP from observations to one Q-value per action (optional dropout, optional dueling head);
    for image observations, a convolutional trunk (``conv``) first.

    ``obs_shape`` is an observation's shape (an int: a flat observation of that size).
    ``generator`` draws the initial weights (on CPU; the convolutions' first) and the dropout masks.
    Without one, a generator seeded 0 is made: still nothing global.
    """

    def __init__(
        self,
        obs_shape: int | Sequence[int],
        n_actions: int,
        shape: NetworkShape,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        init = generator if generator is not None else torch.Generator().manual_seed(0)
        self.obs_shape = (obs_shape,) if isinstance(obs_shape, int) else tuple(int(n) for n in obs_shape)
        self.conv: nn.Sequential | None = None
        """The convolutional trunk of an image network (None for flat observations)."""
        layers: list[nn.Module] = []
        width = self.obs_shape[0]
        if len(self.obs_shape) == 3:
            self.conv = conv_trunk(self.obs_shape, shape, init)
            inputs = network_input_shape(self.obs_shape, shape.frame_difference)
            width = conv_output_size(inputs, shape.conv_layers)
        for hidden in shape.hidden_sizes:
            layers += [seeded_linear(width, hidden, init), ACTIVATIONS[shape.activation]()]
            if shape.dropout > 0:
                layers.append(GeneratorDropout(shape.dropout, init))
            width = hidden
        self.body = nn.Sequential(*layers)
        self.head = seeded_linear(width, n_actions, init)
        self.value = seeded_linear(width, 1, init) if shape.dueling else None

    @property
    def is_image(self) -> bool:
        """True when it starts with convolutional layers (image observations)."""
        return self.conv is not None

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        if self.conv is not None:
            observations = self.conv(observations)
        features = self.body(observations)
        q = self.head(features)
        if self.value is not None:  # dueling: the head gives advantages
            q = self.value(features) + q - q.mean(dim=1, keepdim=True)
        return q

    def dropout_layers(self) -> list[GeneratorDropout]:
        return [m for m in self.body if isinstance(m, GeneratorDropout)]

    def q_values(self, observations: np.ndarray) -> np.ndarray:
        """Q-values [N, n_actions] of numpy observations, without autograd (dropout as the mode says)."""
        device = self.head.weight.device
        with torch.inference_mode():
            if self.conv is not None:  # uint8 pixels (or their float values): the trunk scales them
                pixels = torch.as_tensor(np.asarray(observations), device=device)
                return self(pixels.reshape(-1, *self.obs_shape)).cpu().numpy()
            observations_t = torch.as_tensor(np.asarray(observations, dtype=np.float32), device=device)
            return self(observations_t).cpu().numpy()


def q_values_from(parts: Sequence[Callable[[np.ndarray], np.ndarray]], x: np.ndarray) -> np.ndarray:
    """Q-values ``[..., n_actions]`` of ``x`` through a Q-network's NumPy parts, as ``QNetwork.forward``
    without dropout: the body, then the head, and for a dueling network (a third part, the value
    head) ``value + advantages - mean(advantages)``."""
    body, head, *value = parts
    features = body(x)
    q = head(features)
    if value:  # dueling: the head gives advantages
        q = value[0](features) + q - q.mean(axis=-1, keepdims=True)
    return q


def q_network_parameters(config: NetworkShape, env: EnvInfo) -> int:
    """Parameters of one Q-network."""
    features, conv = env.obs_dim, 0
    if env.is_image:
        inputs = network_input_shape(env.obs_shape, config.frame_difference)
        conv = conv_parameters(inputs[0], config.conv_layers)
        features = conv_output_size(inputs, config.conv_layers)
    sizes = [features, *config.hidden_sizes]
    body = sum(n_in * n_out + n_out for n_in, n_out in itertools.pairwise(sizes))
    head = sizes[-1] * env.n_actions + env.n_actions
    value = sizes[-1] + 1 if config.dueling else 0
    return conv + body + head + value


class QNetworkPolicy:
    """Greedy policy of a Q-network: ``act`` = argmax of ``scores`` (the Q-values).

    A frozen snapshot: NumPy copies of the network's weights taken when it is built, run without
    dropout (:class:`~cartpole.agents.nn.numpy_mlp.NumpyMLP`). A convolutional network has no NumPy
    twin: its snapshot is a frozen torch copy (``torch_net``), run in eval mode.
    """

    def __init__(self, q_net: QNetwork):
        self.torch_net: QNetwork | None = None
        """The frozen torch copy of a convolutional network (None: the numpy snapshot acts)."""
        self.compiled: CompiledMLP | None = None
        """Body and head as one compiled network, which plays whole episodes (None when dueling or
        convolutional)."""
        if q_net.is_image:
            self.torch_net = copy.deepcopy(q_net).requires_grad_(False).eval()
            return
        value = [] if q_net.value is None else [NumpyMLP([q_net.value])]
        self.parts = [NumpyMLP(q_net.body), NumpyMLP([q_net.head]), *value]
        """The body, the head and (dueling) the value head (:func:`q_values_from`)."""
        body, head = self.parts[:2]
        if not value:
            self.compiled = CompiledMLP.of(body.plan + head.plan, KERNEL_ACTIVATIONS)

    def scores(self, observations: np.ndarray) -> np.ndarray:
        """Q-values, shape [N, n_actions] (as ``QNetwork.forward`` in eval mode)."""
        if self.torch_net is not None:
            return self.torch_net.q_values(observations)
        return q_values_from(self.parts, observations)

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        """Whole greedy episodes on our float64 CartPole in one compiled call
        (:class:`~cartpole.evaluation.CartPolePlayer`): a plain network's body and head as one;
        None for a dueling or convolutional one."""
        if self.compiled is None:
            return None
        return self.compiled.play_cartpole(states, params, max_episode_steps, len(states))
