"""DQN for a population of seeds in one process: S independent training runs, batched.

Every seed is the single-run DQN of :mod:`cartpole.agents.dqn.algorithm` with the same config: its own
Q-network (initialized as the single run initializes it), target network, Adam state and replay
memory, its own ``num_envs`` CartPoles seeded as the single run seeds them, and its own random
streams (exploration from ``derived_seed(seed, "explore")``, replay sampling from ``"replay"``,
dropout masks from ``"dropout"``), drawn as the single run draws them. What is shared is only the
arithmetic, along a leading seed axis:

- ``StackedQNetwork``: the online parameters of all S Q-networks in one flat ``[S, P]`` tensor (each
  parameter a ``[S, *shape]`` view of it, each linear layer one ``torch.baddbmm`` for all seeds, see
  :func:`~cartpole.agents.nn.stacked_linear.stacked_linear`), their gradients in another; the
  target networks are the rows above the online ones in one ``[2S, P]`` tensor: a Polyak update is
  one ``lerp``, and double DQN values the next states with both in one pass.
- ``StackedReplay``: the replay memories as one ``[S, capacity, 2 * obs_dim + 3]`` table (the row
  layout: obs | next_obs | action | reward | terminated) with a write position and a fill count per
  seed; the minibatches of a training round's gradient steps, every seed's, are one
  ``index_select``. Image observations are kept apart, as uint8 pixels in one ``[2, S, capacity, C,
  H, W]`` store (obs and next obs; a float32 row would take four times the memory), beside a ``[S,
  capacity, 3]`` table of action | reward | terminated.
- :func:`~cartpole.envs.seed_envs.make_seed_envs` gives each seed its own ``num_envs`` envs (on
  CartPole's fast simulator all S x ``num_envs`` step in one call), and
  :class:`~cartpole.agents.nn.population_optimizers.PopulationAdam` steps every seed's Adam in one pass.
- ``PopulationDQN``: one ``learn()`` = one batched env step of every seed (one forward pass for all
  seeds' greedy actions) and, for the seeds whose training round is due, ``gradient_steps`` batched
  gradient steps (one forward, one backward and one Adam step for all of them).

Why a seed's run stays bit for bit the same whoever shares its batch: every operation is either per
seed (a batched matmul multiplies each seed's slice on its own; reductions run over a seed's own row:
the loss, the Q mean, the gradient norm for clipping) or elementwise, and nothing is ever reduced
over the seed axis (the summed loss that is backpropagated has the gradient 1 or 0 per seed). Shapes
never depend on the other seeds: a minibatch has ``batch_size`` rows for every seed, and a seed
whose memory still holds fewer rows masks the rest out, dividing by its own count; a seed that has
not reached ``learning_starts`` (or whose training round is not due) sits the step out through the
Adam ``active`` mask and keeps its generators untouched. Two details keep the bits equal where
torch's kernels would otherwise betray a seed's position in the batch:

- Elementwise CPU kernels run vectorized over the whole tensor and finish its last few elements
  with scalar code, whose transcendental functions (tanh, elu, gelu, lerp's fused multiply-add) may
  round differently. So every per-seed block is a multiple of :data:`ALIGN` elements (the flat
  parameters are padded, minibatches and acting batches have a multiple of :data:`ALIGN` rows): no
  seed's elements ever fall into the scalar tail.
- A value head (one output) multiplies in the orientation whose bits do not depend on the number
  of seeds (:func:`~cartpole.agents.nn.stacked_linear.linear_forward`), so a lone seed needs no company
  (but on several torch threads, where every product of a lone seed runs as a batch of two: see
  :mod:`~cartpole.agents.nn.stacked_linear`).

Image networks (:class:`~cartpole.agents.dqn.q_network.QNetwork` with a convolutional trunk)
run their convolutions one ``conv2d`` per seed
(:func:`~cartpole.agents.nn.stacked_conv.stacked_conv2d`, for the same reason) and take their
gradients from autograd; they act through torch (no NumPy twin).

Torch's batched products give every seed the same bits wherever it sits in the batch when the
layer widths are multiples of 4 (every preset's are; ``tests/test_one_engine.py``); for other widths
(7, 10, 33, ...) a seed's floats can depend on its position in the last bit.

Only the floats of the network arithmetic differ from the single CPU run's (batched kernels, a
masked mean over padded rows): its episodes, random draws and replay rows are the single run's, and
its weights and losses agree with it to float rounding (``tests/test_dqn_population.py``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from cartpole.agents.dqn.algorithm import (
    DQNConfig,
    epsilon_at,
    policy_from_checkpoint,
    shaped_rewards,
    td_targets,
)
from cartpole.agents.dqn.n_step import NStepWindows
from cartpole.agents.dqn.q_network import (
    ACTIVATIONS,
    QNetwork,
    QNetworkPolicy,
    network_input_shape,
    q_values_from,
)
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.conv import (
    LastFrameDifference,
    conv_activations,
    conv_output_size,
    conv_parameters,
    last_frame_difference,
    scale_pixels,
)
from cartpole.agents.nn.flat_parameters import FlatParameters, on_the_cpu
from cartpole.agents.nn.numpy_mlp import NUMPY_ACTIVATIONS, StackedNumpyMLP, Step, stacked_block_actor
from cartpole.agents.nn.population_optimizers import population_optimizer
from cartpole.agents.nn.stacked_conv import channels_last, stacked_conv2d
from cartpole.agents.nn.stacked_linear import (
    TORCH_ACTIVATIONS,
    linear_forward,
    mlp_gradients,
    relu_gradient_in_place,
    stacked_linear,
)
from cartpole.agents.population import Finished, SeedEpisodes, SeedRows, require_training_state
from cartpole.agents.registry import AgentSpec
from cartpole.core.errors import ConfigError
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo
from cartpole.evaluation import BlockActor

ALIGN = 32
"""Every seed's block of an elementwise operation is a multiple of this many float32 elements: two
AVX-512 vectors, the widest step of torch's vectorized CPU loops (see the module docstring)."""


class Round(NamedTuple):
    """What every gradient step of one training round shares, on the device: the minibatch row mask
    [S, B], each seed's row count [S], who trains [S], the learning rates [S], and each row's weight
    in its seed's mean loss [S, B] (``active / count`` on its rows, 0 on padding)."""

    mask: torch.Tensor
    row_counts: torch.Tensor
    active: torch.Tensor
    lr: torch.Tensor
    row_weights: torch.Tensor


class Minibatch(NamedTuple):
    """One gradient step's transitions of every seed: observations and next observations [S, B,
    obs_dim] (image networks: uint8 [S, B, C, H, W]), actions [S, B, 1] (int64), rewards and
    terminated flags [S, B]."""

    observations: torch.Tensor
    next_observations: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor


def padded(n: int, multiple: int = ALIGN) -> int:
    """``n`` rounded up to a multiple of ``multiple``."""
    return -(-n // multiple) * multiple


def to_device(tensor: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A CPU tensor copied to ``device`` without waiting for the device (no sync): only the read-back
    at the end of ``learn()`` waits for it."""
    return tensor.to(device, non_blocking=True)


def seeded_q_network(config: DQNConfig, env: EnvInfo, seed: int) -> QNetwork:
    """Seed ``seed``'s initial Q-network on the CPU, from its own ``init`` generator."""
    with on_the_cpu():
        generator = torch.Generator(device="cpu").manual_seed(derived_seed(seed, "init"))
        return QNetwork(env.obs_shape, env.n_actions, config, generator).eval()


# ----------------------------------------------------------------------------------------------
# The stacked networks
# ----------------------------------------------------------------------------------------------


class StackedQNetwork(FlatParameters[QNetwork]):
    """The online and target Q-networks of S seeds: the online parameters as
    :class:`~cartpole.agents.nn.flat_parameters.FlatParameters` (rows padded to a multiple of
    :data:`ALIGN`), the targets in ``target``, laid out alike."""

    def __init__(self, models: list[QNetwork], target_network: bool, device: torch.device):
        self.target: torch.Tensor | None = None  # bound by bind(), which the base's __init__ calls
        super().__init__(models, device, align=ALIGN)
        template = self.template
        if target_network:
            self.target = self.flat.clone()
            self.bind()
        self.buffers: dict[str, torch.Tensor] = {}
        """:meth:`buffer`'s tensors, by name."""
        self.hidden: list[tuple[str, str]] = []
        """(weight, bias) of each hidden layer, in order; an activation (and dropout) follows each."""
        for index, layer in enumerate(template.body):
            if isinstance(layer, torch.nn.Linear):
                self.hidden.append((f"body.{index}.weight", f"body.{index}.bias"))
        self.convs: list[tuple[str, str, int]] = []
        """(weight, bias, stride) of each convolutional layer of an image network, in order; a ReLU
        follows each (none for flat observations)."""
        conv: list[torch.nn.Module] = list(template.conv) if template.conv is not None else []
        for index, layer in enumerate(conv):
            if isinstance(layer, torch.nn.Conv2d):
                self.convs.append((f"conv.{index}.weight", f"conv.{index}.bias", int(layer.stride[0])))
        self.frame_difference = any(isinstance(layer, LastFrameDifference) for layer in conv)
        self.dueling = template.value is not None
        dropouts = template.dropout_layers()
        self.dropout = dropouts[0].p if dropouts else 0.0
        activations = {type(layer) for layer in template.body if not isinstance(layer, torch.nn.Linear)}
        self.plain_relu = activations == {torch.nn.ReLU} and not self.dueling and not self.convs
        """Whether this is a plain ReLU MLP (no dropout, no dueling head, no convolutions), whose
        gradients :meth:`backward_by_hand` computes."""

    def bind(self) -> None:
        if self.target is not None:
            seeds = self.flat.shape[0]
            self.pair = torch.cat([self.target, self.flat])
            """The targets, then the online networks: rows of one [2S, P] tensor, so that double DQN
            values next states with both in one pass."""
            self.target, self.flat = self.pair[:seeds], self.pair[seeds:]
            self.pair_params = self.views(self.pair)
        super().bind()
        self.target_params = self.views(self.target) if self.target is not None else self.params

    def forward(
        self,
        params: dict[str, torch.Tensor],
        x: torch.Tensor,
        activation: Callable[[torch.Tensor], torch.Tensor],
        keeps: list[torch.Tensor] | None = None,
        inputs: list[torch.Tensor] | None = None,
        buffers: str | None = None,
    ) -> torch.Tensor:
        """Q-values ``[S, B, n_actions]`` of observations ``x`` [S, B, obs_dim] (images: [S, B, C, H,
        W] pixels), as ``QNetwork.forward``; ``keeps`` (one bool mask ``[S, B, width]`` per hidden
        layer) applies dropout as :class:`~cartpole.agents.dqn.q_network.GeneratorDropout` does.
        ``inputs``, when given, receives each linear layer's input, in order (for
        :meth:`backward_by_hand`). ``buffers`` names the hidden layers' outputs of a plain ReLU MLP
        without autograd: they are written into tensors kept under that name (:meth:`buffer`),
        valid until the next pass under the same name."""
        if self.convs:
            x = self.conv_features(params, x)
        reuse = buffers is not None and self.plain_relu and not torch.is_grad_enabled()
        for index, (weight, bias) in enumerate(self.hidden):
            if inputs is not None:
                inputs.append(x)
            if reuse:
                out = self.buffer(f"{buffers}.{index}", (*x.shape[:2], params[bias].shape[1]))
                x = linear_forward(x, params[weight], params[bias], out).relu_()
                continue
            x = activation(stacked_linear(x, params[weight], params[bias]))
            if keeps is not None:
                x = x * keeps[index] / (1.0 - self.dropout)
        if inputs is not None:
            inputs.append(x)
        q = stacked_linear(x, params["head.weight"], params["head.bias"])
        if self.dueling:  # the head gives advantages
            q = (
                stacked_linear(x, params["value.weight"], params["value.bias"])
                + q
                - q.mean(dim=2, keepdim=True)
            )
        return q

    def buffer(self, name: str, shape: tuple[int, ...]) -> torch.Tensor:
        """The float tensor kept under ``name``, (re)made when ``shape`` differs from its own: a
        gradient step's large activations reuse the same memory instead of new allocations each
        step, which glibc's heap does not give back between steps."""
        kept = self.buffers.get(name)
        if kept is None or tuple(kept.shape) != shape:
            kept = self.buffers[name] = torch.empty(shape, device=self.flat.device)
        return kept

    def conv_features(self, params: dict[str, torch.Tensor], pixels: torch.Tensor) -> torch.Tensor:
        """The convolutional trunk's flattened features [S, B, F] of pixels [S, B, C, H, W], as
        ``QNetwork.conv``: scaled, (their last frames' difference,) one conv2d per seed and layer."""
        x = scale_pixels(channels_last(pixels))  # laid out while uint8: a quarter of the bytes
        if self.frame_difference:
            x = last_frame_difference(x)
        for weight, bias, stride in self.convs:
            x = torch.relu(stacked_conv2d(x, params[weight], params[bias], stride))
        return x.flatten(2)

    @torch.no_grad()
    def backward_by_hand(self, inputs: list[torch.Tensor], grad: torch.Tensor) -> None:
        """Write into ``grad`` (the online networks' gradients) the gradient of a loss whose gradient
        with respect to the Q-values is ``grad`` [S, B, n_actions], for a plain ReLU MLP whose layers
        had the ``inputs`` of :meth:`forward` (:func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`)."""
        layers = [(self.params[w], self.params[b]) for w, b in [*self.hidden, ("head.weight", "head.bias")]]
        for (weight, bias), (weight_grad, bias_grad) in zip(
            layers, mlp_gradients(layers, inputs, grad, relu_gradient_in_place, self.buffer), strict=True
        ):
            weight.grad.copy_(weight_grad)  # type: ignore[union-attr]
            bias.grad.copy_(bias_grad)  # type: ignore[union-attr]

    def keep(self, rows: torch.Tensor) -> None:
        if self.target is not None:
            self.target = self.target[rows]
        super().keep(rows)

    @torch.no_grad()
    def update_target(self, rows: np.ndarray, tau: float) -> None:
        """Polyak update of the targets of ``rows``: target <- target + tau * (online - target); a copy
        when tau is 1."""
        if self.target is None or not rows.any():
            return
        if rows.all():
            if tau >= 1.0:
                self.target.copy_(self.flat)
            else:
                self.target.lerp_(self.flat, tau)
            return
        index = to_device(torch.from_numpy(np.flatnonzero(rows)), self.flat.device)
        online = self.flat.index_select(0, index)
        moved = online if tau >= 1.0 else self.target.index_select(0, index).lerp_(online, tau)
        self.target.index_copy_(0, index, moved)


# ----------------------------------------------------------------------------------------------
# The stacked replay memories
# ----------------------------------------------------------------------------------------------


class StackedReplay:
    """S ring buffers of transitions in one ``[S, capacity, 2 * obs_dim + 3]`` table, each row laid
    out as obs | next_obs | action | reward | terminated; each seed has its own write position and
    fill count.

    Image observations (``obs_shape`` [C, H, W]) stay uint8 in their own store, ``images`` [2, S,
    capacity, C, H, W] (obs, then next obs), and the table's rows hold only action | reward |
    terminated (``obs_dim`` is then 0: no observation floats in a row)."""

    def __init__(self, seeds: int, capacity: int, obs_shape: int | tuple[int, ...], device: torch.device):
        shape = (obs_shape,) if isinstance(obs_shape, int) else tuple(obs_shape)
        self.capacity = capacity
        self.obs_dim = shape[0] if len(shape) == 1 else 0
        """Observation floats in a table row (0 for images, which live in ``images``)."""
        # Uninitialized, not zeros: ``torch.zeros`` writes every page of the table at once, so a
        # population's whole capacity would be resident from the start; here a page costs memory when
        # it is first written. No row at or past a seed's fill count is ever read (minibatches draw
        # below it), except row 0, the padding slot of a seed with no rows yet: zeroed.
        self.table = torch.empty(seeds, capacity, 2 * self.obs_dim + 3, device=device)
        self.table[:, 0] = 0.0
        self.images: torch.Tensor | None = None
        """Image observations: uint8 [2, S, capacity, C, H, W], obs then next obs (None: flat ones)."""
        if len(shape) == 3:
            self.images = torch.empty(2, seeds, capacity, *shape, dtype=torch.uint8, device=device)
            self.images[:, :, 0] = 0
        self.pos = np.zeros(seeds, dtype=np.int64)
        self.size = np.zeros(seeds, dtype=np.int64)
        self.host_view()

    @property
    def nbytes(self) -> int:
        """Bytes of the stores (allocated; a page is resident once written)."""
        images = 0 if self.images is None else self.images.nbytes
        return self.table.nbytes + images

    def host_view(self) -> None:
        """On the CPU rows are written through a numpy view of the table (cheaper for a few rows)."""
        self.host = self.table.numpy() if self.table.device.type == "cpu" else None
        on_cpu = self.images is not None and self.images.device.type == "cpu"
        self.host_images = self.images.numpy() if on_cpu and self.images is not None else None

    def add(self, valid: np.ndarray, fields: list[np.ndarray]) -> None:
        """Append the transitions of the envs where ``valid`` [S, N] is True to their seeds' buffers,
        in env order, overwriting the oldest rows when full. ``fields`` are obs [S * N, obs_dim],
        actions, rewards, next obs and terminated (each [S * N])."""
        d = self.obs_dim
        counts = valid.sum(axis=1)
        offsets = np.cumsum(valid, axis=1) - 1
        # A seed with more new rows than capacity keeps its newest `capacity` (a ring buffer's overwrite).
        kept = valid & (offsets >= (counts - self.capacity)[:, None])
        seed_rows, env_columns = np.nonzero(kept)
        if len(seed_rows):
            slots = (self.pos[seed_rows] + offsets[seed_rows, env_columns]) % self.capacity
            envs = seed_rows * valid.shape[1] + env_columns
            observations, actions, rewards, next_observations, terminated = fields
            rows = np.empty((len(envs), 2 * d + 3), dtype=np.float32)
            if self.images is None:
                rows[:, :d] = observations[envs]
                rows[:, d : 2 * d] = next_observations[envs]
            rows[:, 2 * d] = actions[envs]
            rows[:, 2 * d + 1] = rewards[envs]
            rows[:, 2 * d + 2] = terminated[envs]
            if self.host is not None:
                self.host[seed_rows, slots] = rows
            else:
                device = self.table.device
                index = (
                    to_device(torch.from_numpy(seed_rows), device),
                    to_device(torch.from_numpy(slots), device),
                )
                self.table[index] = to_device(torch.from_numpy(rows), device)
            if self.images is not None:
                self.add_images(seed_rows, slots, observations[envs], next_observations[envs])
        self.pos = (self.pos + counts) % self.capacity
        self.size = np.minimum(self.size + counts, self.capacity)

    def add_images(
        self,
        seed_rows: np.ndarray,
        slots: np.ndarray,
        observations: np.ndarray,
        next_observations: np.ndarray,
    ) -> None:
        """Write the pixels of new transitions (uint8 [k, C, H, W] each) at ``slots`` of ``seed_rows``."""
        if self.host_images is not None:
            self.host_images[0, seed_rows, slots] = observations
            self.host_images[1, seed_rows, slots] = next_observations
            return
        assert self.images is not None
        device = self.images.device
        index = (to_device(torch.from_numpy(seed_rows), device), to_device(torch.from_numpy(slots), device))
        self.images[0][index] = to_device(torch.from_numpy(np.ascontiguousarray(observations)), device)
        self.images[1][index] = to_device(torch.from_numpy(np.ascontiguousarray(next_observations)), device)

    def gather_images(self, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The uint8 observations and next observations [S, B, C, H, W] of the rows ``index`` [S, B]."""
        assert self.images is not None
        _, seeds, capacity, *shape = self.images.shape
        base = torch.arange(seeds, device=index.device).unsqueeze(1) * capacity
        both = self.images.view(2, seeds * capacity, *shape).index_select(1, (index + base).view(-1))
        both = both.view(2, seeds, index.shape[1], *shape)
        return both[0], both[1]

    def gather(self, index: torch.Tensor) -> torch.Tensor:
        """The rows ``index`` [S, B] (slot numbers within each seed's buffer): [S, B, 2 * obs_dim + 3]."""
        seeds, capacity = self.table.shape[:2]
        base = torch.arange(seeds, device=index.device).unsqueeze(1) * capacity
        flat = self.table.view(seeds * capacity, -1).index_select(0, (index + base).view(-1))
        return flat.view(seeds, index.shape[1], -1)

    def keep(self, rows_np: np.ndarray) -> None:
        """Keep only the seeds at ``rows_np`` (rising), moving each one's filled rows down in place.

        Not ``table[rows]``: that copy would make every page of a new ``[S, capacity, ...]`` table
        resident at once (the table's unwritten pages cost nothing until then), doubling the replay's
        memory at the moment a seed stops. Rows past a seed's fill count are never read."""
        for new, old in enumerate(rows_np.tolist()):
            if new != old:
                filled = int(self.size[old])
                self.table[new, :filled] = self.table[old, :filled]
                if self.images is not None:
                    self.images[:, new, :filled] = self.images[:, old, :filled]
        self.table = self.table[: len(rows_np)]
        if self.images is not None:
            self.images = self.images[:, : len(rows_np)]
        self.pos, self.size = self.pos[rows_np], self.size[rows_np]
        self.host_view()

    def row_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``row``'s buffer: the rows it holds, oldest first, and its write position."""
        d, size = self.obs_dim, int(self.size[row])
        written = self.table[row, :size].to("cpu", copy=True)
        tensors = {
            "observations": written[:, :d].clone(),
            "actions": written[:, 2 * d].long(),
            "rewards": written[:, 2 * d + 1].clone(),
            "next_observations": written[:, d : 2 * d].clone(),
            "terminated": written[:, 2 * d + 2].clone(),
        }
        if self.images is not None:  # uint8 pixels
            tensors["observations"] = self.images[0, row, :size].to("cpu", copy=True)
            tensors["next_observations"] = self.images[1, row, :size].to("cpu", copy=True)
        return tensors, {"capacity": self.capacity, "pos": int(self.pos[row]), "size": size}

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        if int(data["capacity"]) != self.capacity:
            raise ConfigError(f"replay capacity {data['capacity']} in the checkpoint, {self.capacity} here")
        d, size = self.obs_dim, int(data["size"])
        rows = torch.zeros(self.capacity, 2 * d + 3, device="cpu")
        if self.images is not None:  # in place, as the table
            self.images[0, row, :size] = tensors["observations"].to(self.images.device)
            self.images[1, row, :size] = tensors["next_observations"].to(self.images.device)
        else:
            rows[:size, :d] = tensors["observations"]
            rows[:size, d : 2 * d] = tensors["next_observations"]
        rows[:size, 2 * d] = tensors["actions"].to(torch.float32)
        rows[:size, 2 * d + 1] = tensors["rewards"]
        rows[:size, 2 * d + 2] = tensors["terminated"]
        self.table[row] = rows.to(self.table.device)  # in place: the host view stays valid
        self.pos[row], self.size[row] = int(data["pos"]), size


# ----------------------------------------------------------------------------------------------
# The population
# ----------------------------------------------------------------------------------------------


class PopulationDQN(SeedRows):
    """DQN for seeds ``seeds``, all with ``config``: one ``learn()`` = one batched env step of every
    seed and its due gradient steps. A single run (``--seed N``) is a population of one."""

    def __init__(self, config: DQNConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        config.validate()
        config.check_env(env)
        if not seeds:
            raise ConfigError("a population needs at least one seed")
        self.config, self.env_info = config, env
        self.device = torch.device(device)
        """Where the networks, the replay memories and the updates live. The envs step on the CPU
        (numpy) and every random draw comes from a seed's own CPU generator, so a seed's draws are the
        same on any device."""
        self.seeds = list(seeds)
        self.activation = TORCH_ACTIVATIONS[ACTIVATIONS[config.activation]]
        self.net = StackedQNetwork(
            [seeded_q_network(config, env, s) for s in self.seeds], config.target_network, self.device
        )
        width = self.net.flat.shape[1]
        self.optimizer = population_optimizer(config.optimizer, len(self.seeds), width, self.device)
        self.replay = StackedReplay(len(self.seeds), config.buffer_size, env.obs_shape, self.device)
        self.explore_rngs = [np.random.default_rng(derived_seed(s, "explore")) for s in self.seeds]
        self.replay_generators = [self.cpu_generator(derived_seed(s, "replay")) for s in self.seeds]
        self.dropout_generators = [self.cpu_generator(derived_seed(s, "dropout")) for s in self.seeds]
        self.episodes = SeedEpisodes(env, config.simulator, self.seeds, config.num_envs)
        self.windows: NStepWindows | None = None
        """Each env's transitions not yet stored, with n-step returns (None: one-step rows)."""
        if config.n_step > 1:
            envs, dtype = len(self.seeds) * config.num_envs, self.episodes.observations.dtype
            self.windows = NStepWindows(
                envs, config.num_envs, config.n_step, config.gamma, env.obs_shape, dtype
            )
        rows = len(self.seeds)
        self.env_steps = np.zeros(rows, dtype=np.int64)
        self.calls = np.zeros(rows, dtype=np.int64)
        self.gradient_steps = np.zeros(rows, dtype=np.int64)
        self.epsilon_multiplied = np.full(rows, config.epsilon_start, dtype=np.float64)
        self.last_loss = np.full(rows, math.nan)
        self.last_q_mean = np.full(rows, math.nan)
        self.greedy: np.ndarray | None = None
        """The greedy actions [S, num_envs] for ``observations`` under the current weights, computed
        at the end of the last ``learn()`` (read back with its metrics: one device sync a call)."""
        self.batch_rows = padded(config.batch_size)
        self.acting_rows = padded(config.num_envs)
        self.rounds: dict[bytes, Round] = {}
        """The last training round's tensors (see :meth:`round_tensors`), by who trained and their rows."""
        self.acting_networks: list[StackedNumpyMLP] | None = None
        """:meth:`numpy_q_values`'s NumPy views of the online weights (which the updates change in
        place), made on first use and again after seeds leave."""

    @staticmethod
    def cpu_generator(seed: int) -> torch.Generator:
        return torch.Generator(device="cpu").manual_seed(seed)

    # -- which seeds --------------------------------------------------------------------------------

    def remove(self, seeds: list[int]) -> None:
        """Stop training ``seeds``: they leave every batch."""
        rows_np, envs = self.leave(seeds, self.config.num_envs)
        rows = torch.from_numpy(rows_np).to(self.device)
        self.net.keep(rows)
        self.acting_networks = None
        self.optimizer.keep(rows)
        self.replay.keep(rows_np)
        self.episodes.keep(rows_np, envs)
        if self.windows is not None:
            self.windows.keep(envs)
        self.explore_rngs = [self.explore_rngs[i] for i in rows_np]
        self.replay_generators = [self.replay_generators[i] for i in rows_np]
        self.dropout_generators = [self.dropout_generators[i] for i in rows_np]
        for name in (
            "env_steps",
            "calls",
            "gradient_steps",
            "epsilon_multiplied",
            "last_loss",
            "last_q_mean",
        ):
            setattr(self, name, getattr(self, name)[rows_np])
        if self.greedy is not None:
            self.greedy = self.greedy[rows_np]

    # -- one learn() call ---------------------------------------------------------------------------

    def learn(self) -> dict[int, LearnResult]:
        """One batched env step of every seed, then the gradient steps of the seeds whose training
        round is due; each active seed's result by seed."""
        config = self.config
        seeds, n = len(self.seeds), config.num_envs
        epsilons = [
            epsilon_at(config, int(steps), float(multiplied))
            for steps, multiplied in zip(self.env_steps, self.epsilon_multiplied, strict=True)
        ]
        actions = self.select_actions(epsilons)
        finished: Finished = [([], []) for _ in self.seeds]
        step = self.episodes.step(actions, finished)  # an autoreset step is no transition: dropped
        valid, terminated = step.valid, step.terminated
        stored_rewards = shaped_rewards(config, step.rewards, terminated & valid, step.ended, step.lengths)
        terminal = terminated.astype(np.float32)
        fields = [step.observations, actions, stored_rewards, step.next_observations, terminal]
        if self.windows is None:
            self.replay.add(valid.reshape(seeds, n), fields)
        else:
            rows = self.windows.step(
                valid,
                step.observations,
                actions,
                stored_rewards,
                step.next_observations,
                terminated,
                step.truncated,
            )
            for emitted, row_fields in rows:
                self.replay.add(emitted.reshape(seeds, n), row_fields)
        collected = valid.reshape(seeds, n).sum(axis=1)
        self.env_steps += collected

        self.calls += 1
        training = (self.calls % config.train_freq == 0) & (self.env_steps >= config.learning_starts)
        training &= (config.gradient_steps > 0) & (self.replay.size > 0)  # n-step rows come n steps late
        metrics = self.train(training) if training.any() else None
        self.read_back(metrics, training)
        return self.results(collected, finished, epsilons)

    def select_actions(self, epsilons: list[float]) -> np.ndarray:
        """Epsilon-greedy actions of all envs: each seed's exploration draws from its own generator
        (the single run's draws), the greedy actions from one forward pass for all seeds."""
        n, n_actions = self.config.num_envs, self.env_info.n_actions
        greedy = self.greedy if self.greedy is not None else self.greedy_actions()
        explore = np.empty((len(self.seeds), n), dtype=bool)
        random = np.empty((len(self.seeds), n), dtype=np.int64)
        for row, rng in enumerate(self.explore_rngs):
            explore[row] = rng.random(n) < epsilons[row]
            random[row] = rng.integers(0, n_actions, size=n)
        self.greedy = None
        return np.where(explore, random, greedy).reshape(-1)

    @torch.no_grad()
    def greedy_q_argmax(self) -> torch.Tensor:
        """The online networks' greedy actions [S, num_envs] for ``observations`` (on the device)."""
        seeds, n, obs_shape = len(self.seeds), self.config.num_envs, self.env_info.obs_shape
        dtype = torch.uint8 if self.env_info.is_image else torch.float32  # pixels stay uint8
        x = torch.zeros(seeds, self.acting_rows, *obs_shape, dtype=dtype, device="cpu")
        x[:, :n] = torch.from_numpy(self.episodes.observations).view(seeds, n, *obs_shape)
        q = self.net.forward(self.net.params, to_device(x, self.device), self.activation)
        return q[:, :n].argmax(dim=2)

    def greedy_actions(self) -> np.ndarray:
        """The online networks' greedy actions [S, num_envs] for ``observations``: on the CPU through
        NumPy views of the weights (:meth:`numpy_q_values`: cheaper than torch for a few rows); an
        image network through torch."""
        if self.device.type == "cpu" and not self.env_info.is_image:
            n, obs_dim = self.config.num_envs, self.env_info.obs_dim
            return self.numpy_q_values(self.episodes.observations.reshape(-1, n, obs_dim)).argmax(axis=2)
        return self.greedy_q_argmax().cpu().numpy()

    def numpy_q_values(self, x: np.ndarray) -> np.ndarray:
        """Q-values ``[S, B, n_actions]`` of ``x`` [S, B, obs_dim] as :meth:`StackedQNetwork.forward`
        computes them, in NumPy on views of the online weights (CPU only; no copies). ``np.matmul``
        multiplies each seed's slice on its own, so a seed's actions do not depend on its neighbours."""
        if self.acting_networks is None:
            self.acting_networks = self.numpy_networks(None, copy=False)
        return q_values_from(self.acting_networks, x)

    def numpy_networks(self, rows: list[int] | None, copy: bool) -> list[StackedNumpyMLP]:
        """The online networks of ``rows`` (None: all) as NumPy stacks: the body, the head and (dueling)
        the value head (:func:`~cartpole.agents.dqn.q_network.q_values_from`); views of the weights
        (CPU, ``rows`` None) unless ``copy``."""
        net = self.net
        activation = NUMPY_ACTIVATIONS[ACTIVATIONS[self.config.activation]]
        body: list[Step] = []
        for weight, bias in net.hidden:
            body += [net.numpy_linear(weight, bias, rows, copy), activation]
        heads = ["head", "value"] if net.dueling else ["head"]
        linear = [net.numpy_linear(f"{head}.weight", f"{head}.bias", rows, copy) for head in heads]
        return [StackedNumpyMLP(body)] + [StackedNumpyMLP([step]) for step in linear]

    def read_back(self, metrics: torch.Tensor | None, training: np.ndarray) -> None:
        """This call's metrics ([S, 2]: loss, Q mean) and, off the CPU, the next call's greedy
        actions, fetched from the device together (one sync a call)."""
        parts, greedy = [], None
        if self.device.type != "cpu":
            greedy = self.greedy_q_argmax()
            parts.append(greedy.view(-1).to(torch.float64))
        if metrics is not None:
            parts.append(metrics.view(-1).to(torch.float64))
        if not parts:
            return
        values = torch.cat(parts).cpu().numpy()
        if greedy is not None:
            self.greedy = values[: greedy.numel()].astype(np.int64).reshape(greedy.shape)
            values = values[greedy.numel() :]
        if metrics is not None:
            losses, q_means = values.reshape(-1, 2).T
            self.last_loss = np.where(training, losses, self.last_loss)
            self.last_q_mean = np.where(training, q_means, self.last_q_mean)

    def results(
        self, collected: np.ndarray, finished: list[tuple[list[float], list[int]]], epsilons: list[float]
    ) -> dict[int, LearnResult]:
        results = {}
        for row, seed in enumerate(self.seeds):
            returns, lengths = finished[row]
            result = LearnResult(
                env_steps=int(collected[row]), episode_returns=returns, episode_lengths=lengths
            )
            steps = int(self.gradient_steps[row])
            result.scalars = {"train/epsilon": epsilons[row], "train/gradient_steps": float(steps)}
            if steps:  # no loss before the first update (and metrics hold no NaN)
                result.scalars |= {
                    "train/loss": float(self.last_loss[row]),
                    "train/q_mean": float(self.last_q_mean[row]),
                }
            results[seed] = result
        return results

    # -- the gradient steps -------------------------------------------------------------------------

    def train(self, training: np.ndarray) -> torch.Tensor:
        """``gradient_steps`` batched updates in which the seeds where ``training`` [S] is True take
        part (the others sit out); the last step's loss and Q mean per seed [S, 2] (on the device)."""
        config, device = self.config, self.device
        counts = np.where(training, np.minimum(config.batch_size, self.replay.size), 0)
        shared = self.round_tensors(training, counts)
        metrics = torch.zeros(len(self.seeds), 2, device=device)
        for step, minibatch in enumerate(self.minibatches(self.sample_slots(training, counts))):
            keeps = self.dropout_keeps(training, counts) if self.net.dropout > 0 else None
            last = step == config.gradient_steps - 1
            measured = self.gradient_step(minibatch, keeps, shared, metrics=last)
            metrics = metrics if measured is None else measured
            self.after_step(training)
        return metrics

    def round_tensors(self, training: np.ndarray, counts: np.ndarray) -> Round:
        """A training round's shared tensors (:class:`Round`); made again only when who trains or how
        many rows they have changes."""
        key = training.tobytes() + counts.tobytes()
        if key not in self.rounds:
            device = self.device
            rows = (np.arange(self.batch_rows) < counts[:, None]).astype(np.float32)
            mask = to_device(torch.from_numpy(rows), device)
            count = to_device(torch.from_numpy(np.maximum(counts, 1).astype(np.float32)), device)
            active = to_device(torch.from_numpy(training.copy()), device)
            lr = torch.full((len(self.seeds),), self.config.lr, dtype=torch.float64, device=device)
            row_weights = (active.to(mask.dtype) / count).unsqueeze(1) * mask
            self.rounds = {key: Round(mask, count, active, lr, row_weights)}
        return self.rounds[key]

    def minibatches(self, slots: torch.Tensor) -> list[Minibatch]:
        """Every gradient step's :class:`Minibatch` of a round, from its rows ``slots`` [S, steps, B].
        The buffers do not change within a round, so the rows of all its steps come in one
        ``index_select`` and each field is laid out [steps, S, B, ...] in one copy; image networks'
        pixels are gathered a step at a time."""
        seeds, steps, rows = slots.shape
        d = self.replay.obs_dim
        table = self.replay.gather(slots.view(seeds, steps * rows))
        table = table.view(seeds, steps, rows, -1).transpose(0, 1)  # [steps, S, B, row width]
        actions = table[..., 2 * d].long().unsqueeze(3)
        rewards, terminated = table[..., 2 * d + 1].contiguous(), table[..., 2 * d + 2].contiguous()
        if self.replay.images is None:
            observations = table[..., :d].contiguous()
            next_observations = table[..., d : 2 * d].contiguous()
            pixels = list(zip(observations, next_observations, strict=True))
        else:
            pixels = [self.replay.gather_images(slots[:, step]) for step in range(steps)]
        return [
            Minibatch(obs, next_obs, actions[step], rewards[step], terminated[step])
            for step, (obs, next_obs) in enumerate(pixels)
        ]

    def sample_slots(self, training: np.ndarray, counts: np.ndarray) -> torch.Tensor:
        """Each training seed's minibatch rows for every gradient step of this round, drawn uniformly
        (with replacement) from the rows its buffer holds, from its own replay generator;
        [S, gradient_steps, batch rows] (padding: slot 0)."""
        steps = self.config.gradient_steps
        slots = torch.zeros(len(self.seeds), steps, self.batch_rows, dtype=torch.int64, device="cpu")
        for row in np.flatnonzero(training):
            size, count = int(self.replay.size[row]), int(counts[row])
            generator = self.replay_generators[row]
            slots[row, :, :count] = torch.randint(0, size, (steps, count), generator=generator, device="cpu")
        return to_device(slots, self.device)

    def dropout_keeps(self, training: np.ndarray, counts: np.ndarray) -> list[torch.Tensor]:
        """Each hidden layer's dropout keep-mask [S, batch rows, width] for one gradient step: each
        training seed's from its own dropout generator, layer by layer as ``GeneratorDropout`` draws."""
        p, rows = self.net.dropout, self.batch_rows
        widths = self.config.hidden_sizes
        uniforms = [torch.zeros(len(self.seeds), rows, w, device="cpu") for w in widths]
        for row in np.flatnonzero(training):
            count, generator = int(counts[row]), self.dropout_generators[row]
            for layer, width in zip(uniforms, widths, strict=True):
                layer[row, :count] = torch.rand(count, width, generator=generator, device="cpu")
        return [to_device(u >= p, self.device) for u in uniforms]

    def gradient_step(
        self,
        minibatch: Minibatch,
        keeps: list[torch.Tensor] | None,
        shared: Round,
        metrics: bool = True,
    ) -> torch.Tensor | None:
        """One update of the online networks of the active seeds on ``minibatch`` (its rows where the
        round's mask is 0 are padding); with ``metrics``, each seed's loss and Q mean [S, 2]
        (detached; a round reports its last step's, and a gradient by hand needs no loss)."""
        config, net = self.config, self.net
        mask, count, active = shared.mask, shared.row_counts, shared.active
        by_hand = net.plain_relu and keeps is None
        inputs: list[torch.Tensor] = []
        with torch.set_grad_enabled(not by_hand):
            q_all = net.forward(
                net.params,
                minibatch.observations,
                self.activation,
                keeps,
                inputs if by_hand else None,
                buffers="online",
            )
            targets = self.targets(minibatch.next_observations, minibatch.rewards, minibatch.terminated)
            q = q_all.gather(2, minibatch.actions).squeeze(2)
            losses = self.losses(q, targets, mask, count) if metrics or not by_hand else None
        if by_hand:
            grad = self.q_gradient(q, targets, minibatch.actions, shared.row_weights, q_all)
            net.backward_by_hand(inputs, grad)
        else:
            assert losses is not None
            net.grad.zero_()
            net.backward((losses * active.to(losses.dtype)).sum())
        if config.max_grad_value is not None:  # every value on its own, as clip_grad_value_
            net.grad.clamp_(-config.max_grad_value, config.max_grad_value)
        if config.max_grad_norm is not None:
            net.clip_grad_norms(config.max_grad_norm)
        self.optimizer.step(net.flat, net.grad, shared.lr, active)
        if not metrics or losses is None:
            return None
        with torch.no_grad():
            q_means = (q.detach() * mask).sum(dim=1) / count
            return torch.stack([losses.detach(), q_means], dim=1)

    def losses(
        self, q: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor, count: torch.Tensor
    ) -> torch.Tensor:
        """Each seed's mean TD loss [S] over its own rows (where ``mask`` is 1) of ``q`` against
        ``targets`` [S, B]."""
        if self.config.loss == "huber":
            elementwise = F.smooth_l1_loss(q, targets, reduction="none")
        else:
            elementwise = F.mse_loss(q, targets, reduction="none")
        return (elementwise * mask).sum(dim=1) / count

    def q_gradient(
        self,
        q: torch.Tensor,
        targets: torch.Tensor,
        actions: torch.Tensor,
        row_weights: torch.Tensor,
        q_all: torch.Tensor,
    ) -> torch.Tensor:
        """The gradient of the summed loss of :meth:`gradient_step` with respect to every Q-value
        ``[S, B, n_actions]``: each active seed's mean loss over its own rows (``row_weights``, see
        :class:`Round`), through the taken actions' Q-values ``q`` [S, B] (Huber's derivative is the
        error clipped to [-1, 1])."""
        error = q - targets
        slope = error.clamp(-1.0, 1.0) if self.config.loss == "huber" else 2.0 * error
        return torch.zeros_like(q_all).scatter_(2, actions, (slope * row_weights).unsqueeze(2))

    @torch.no_grad()
    def targets(
        self, next_observations: torch.Tensor, rewards: torch.Tensor, terminated: torch.Tensor
    ) -> torch.Tensor:
        """The Bellman targets [S, B] (:func:`~cartpole.agents.dqn.algorithm.td_targets`, per row). Without a
        target network the online nets (without dropout) value s', as the single run does."""
        config, net = self.config, self.net
        next_q_online = None
        if config.double_dqn and net.target is not None:  # both networks in one pass
            twice = torch.cat([next_observations, next_observations])  # a fifth of repeat()'s time
            q = net.forward(net.pair_params, twice, self.activation, buffers="next")
            next_q_target, next_q_online = q.chunk(2)
        else:
            next_q_target = net.forward(net.target_params, next_observations, self.activation, buffers="next")
            if config.double_dqn:  # no target network: the online nets choose and value
                next_q_online = next_q_target
        seeds, rows, n_actions = next_q_target.shape
        targets = td_targets(
            rewards.reshape(-1),
            terminated.reshape(-1),
            next_q_target.reshape(-1, n_actions),
            None if next_q_online is None else next_q_online.reshape(-1, n_actions),
            config.gamma**config.n_step,
        )
        return targets.view(seeds, rows)

    def after_step(self, training: np.ndarray) -> None:
        """Count the gradient step of the ``training`` seeds; their due target updates and their
        multiplicative epsilon decay."""
        config = self.config
        self.gradient_steps += training
        due = training & (self.gradient_steps % config.target_update_interval == 0)
        self.net.update_target(due, config.tau)
        if config.epsilon_schedule == "multiplicative":
            m = self.epsilon_multiplied
            decays = training & (m > config.epsilon_end)
            self.epsilon_multiplied = np.where(
                decays, np.maximum(config.epsilon_end, m * config.epsilon_decay_rate), m
            )

    # -- one seed, as a single run sees it ----------------------------------------------------------

    def seed_policy(self, seed: int) -> QNetworkPolicy:
        """Seed ``seed``'s greedy policy (a frozen copy)."""
        return QNetworkPolicy(self.net.unstack(self.row(seed)))

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The greedy policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor` (block i
        holds seed i's rows): one stacked NumPy forward pass per call, as
        :class:`~cartpole.agents.dqn.q_network.QNetworkPolicy` acts alone (through torch for image
        networks)."""
        if self.env_info.is_image:
            return self.torch_block_actor([self.row(seed) for seed in seeds])
        networks = self.numpy_networks([self.row(seed) for seed in seeds], copy=True)
        return stacked_block_actor(networks, self.env_info.obs_dim, q_values_from)

    def torch_block_actor(self, rows: list[int]) -> BlockActor:
        """The greedy actions of the online networks of ``rows`` as one :data:`BlockActor`, through
        torch: for image networks (no NumPy twin)."""
        return self.net.block_actor(
            rows, self.env_info.obs_shape, lambda params, x: self.net.forward(params, x, self.activation)
        )

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``seed``'s checkpoint: ``q_net.*`` (what
        :func:`~cartpole.agents.dqn.algorithm.policy_from_checkpoint` reads) and, with ``resume``, everything
        to continue exactly: target, Adam, replay rows, generators, counters and envs."""
        row = self.row(seed)
        tensors = self.network_tensors("q_net.", self.net.flat, row)
        data: dict[str, Any] = {"obs_dim": self.env_info.obs_dim, "n_actions": self.env_info.n_actions}
        if self.env_info.is_image:
            data["obs_shape"] = list(self.env_info.obs_shape)
        if not resume:
            return tensors, data
        if self.net.target is not None:
            tensors |= self.network_tensors("target_net.", self.net.target, row)
        size = self.net.size
        optim_tensors, optim_data = self.optimizer.row_state(row)
        tensors |= {k: v[:size].clone() for k, v in optim_tensors.items()}
        replay_tensors, replay_data = self.replay.row_state(row)
        tensors |= {f"replay.{k}": v for k, v in replay_tensors.items()}
        tensors["rng.dropout"] = self.dropout_generators[row].get_state()
        tensors["rng.replay"] = self.replay_generators[row].get_state()
        env_tensors, env_data = self.episodes.seed_state(row)
        tensors |= env_tensors
        if self.windows is not None:
            window_tensors, window_data = self.windows.seed_state(row)
            tensors |= window_tensors
            data |= window_data
        data |= env_data | {
            "population": True,
            **optim_data,
            "replay": replay_data,
            "rng_numpy": self.explore_rngs[row].bit_generator.state,
            "env_steps": int(self.env_steps[row]),
            "calls": int(self.calls[row]),
            "gradient_steps": int(self.gradient_steps[row]),
            "epsilon_multiplied": float(self.epsilon_multiplied[row]),
            "last_loss": none_if_nan(float(self.last_loss[row])),
            "last_q_mean": none_if_nan(float(self.last_q_mean[row])),
        }
        return tensors, data

    def network_tensors(self, prefix: str, flat: torch.Tensor, row: int) -> dict[str, torch.Tensor]:
        """Row ``row`` of ``flat`` as a QNetwork state dict, keys prefixed (CPU copies)."""
        model = self.net.unstack(row, flat)
        return {prefix + k: v.detach().clone() for k, v in model.state_dict().items()}

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``seed_state_dict(seed, resume=True)`` gave."""
        require_training_state(data)
        row = self.row(seed)

        def unprefixed(prefix: str) -> dict[str, torch.Tensor]:
            return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}

        self.net.load_row(row, unprefixed("q_net."))
        if self.net.target is not None:
            self.net.load_row(row, unprefixed("target_net."), self.net.target)
        width = self.net.flat.shape[1]
        optim = {k: torch.cat([v, v.new_zeros(width - len(v))]) for k, v in unprefixed("optim.").items()}
        self.optimizer.load_row_state(row, {f"optim.{k}": v for k, v in optim.items()}, data)
        self.replay.load_row_state(row, unprefixed("replay."), data["replay"])
        self.dropout_generators[row].set_state(tensors["rng.dropout"])
        self.replay_generators[row].set_state(tensors["rng.replay"])
        self.explore_rngs[row].bit_generator.state = data["rng_numpy"]
        self.env_steps[row], self.calls[row] = int(data["env_steps"]), int(data["calls"])
        self.gradient_steps[row] = int(data["gradient_steps"])
        self.epsilon_multiplied[row] = float(data["epsilon_multiplied"])
        self.last_loss[row] = nan_if_none(data.get("last_loss"))
        self.last_q_mean[row] = nan_if_none(data.get("last_q_mean"))
        self.episodes.load_seed_state(row, tensors, data)
        if self.windows is not None:
            self.windows.load_seed_state(row, tensors, data)
        self.greedy = None  # the row's weights and observations changed


def none_if_nan(value: float) -> float | None:
    """JSON metadata holds no NaN (checkpoints are written with ``allow_nan=False``)."""
    return None if math.isnan(value) else value


def nan_if_none(value: float | None) -> float:
    return math.nan if value is None else float(value)


def q_network_parameters(config: DQNConfig, env: EnvInfo) -> int:
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


def replay_bytes(config: DQNConfig, env: EnvInfo) -> int:
    """The bytes of one seed's replay memory: float32 rows, or for images uint8 pixels (obs and next
    obs) beside a float32 action | reward | terminated."""
    if env.is_image:
        return config.buffer_size * (2 * env.obs_dim + 3 * 4)
    return config.buffer_size * (2 * env.obs_dim + 3) * 4


def n_step_window_bytes(config: DQNConfig, env: EnvInfo) -> int:
    """The bytes of one seed's n-step windows (none for one-step rows): each env's last ``n_step``
    observations (uint8 pixels or float32 states), int64 actions and float32 rewards, and how many
    it holds (int64)."""
    if config.n_step == 1:
        return 0
    observation = env.obs_dim * (1 if env.is_image else 4)
    return config.num_envs * (config.n_step * (observation + 8 + 4) + 8)


def dqn_bytes_per_seed(config: DQNConfig, env: EnvInfo) -> int:
    """What one seed of a DQN population holds, roughly: its replay rows and n-step windows, its
    parameters five times (online, target, gradient, Adam's two moments), a minibatch's activations
    (the online pass with its gradients, the target and online passes over the next states, dropout
    masks) and the per-seed bookkeeping (run folder, callbacks). Image networks' activations include
    the scaled pixels and every convolutional layer's output."""
    config.check_env(env)  # settings that cannot fit the env's images: one line, not an estimate
    parameters = padded(q_network_parameters(config, env)) * 4 * 5
    rows = padded(config.batch_size)
    inputs = 2 * env.obs_dim
    if env.is_image:
        shown = network_input_shape(env.obs_shape, config.frame_difference)
        inputs = env.obs_dim + math.prod(shown) + conv_activations(shown, config.conv_layers)
    activations = rows * (sum(config.hidden_sizes) + env.n_actions + inputs + 8) * 4 * 8
    bookkeeping = 2 * 1024**2
    held = replay_bytes(config, env) + n_step_window_bytes(config, env)
    return held + parameters + activations + bookkeeping


AGENT = AgentSpec(
    name="dqn",
    summary="Deep Q-Network (PyTorch): double DQN, replay, target network, vectorized collection",
    config_cls=DQNConfig,
    policy_from_checkpoint=policy_from_checkpoint,
    bytes_per_seed=dqn_bytes_per_seed,
    make_population=PopulationDQN,
    iteration="step",
    score_label="Q-values",
    image_observations=True,
)
"""DQN: its settings (dqn.py) and its learner, batched over seeds (above)."""


__all__ = [
    "ALIGN",
    "PopulationDQN",
    "StackedQNetwork",
    "StackedReplay",
    "dqn_bytes_per_seed",
    "n_step_window_bytes",
    "q_network_parameters",
    "replay_bytes",
]
