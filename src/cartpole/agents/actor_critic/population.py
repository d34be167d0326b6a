"""PPO, A2C and REINFORCE for a population of seeds in one process: S independent training runs, batched.

Every seed is the single-run PPO of :mod:`cartpole.agents.actor_critic.ppo` with the same config:
its own network (initialized as the single run initializes it), its own ``num_envs`` envs seeded as
the single run seeds them, its own action sampling, minibatch shuffling and Adam state. What is
shared is only the arithmetic:

- ``StackedActorCritic``: the parameters of all S actor-critics in one flat ``[S, P]`` tensor; each
  layer is a view ``[S, out, in]`` of it and runs as one ``torch.baddbmm`` over the seed axis
  (:func:`~cartpole.agents.nn.stacked_linear.stacked_linear`, whose backward picks the fast
  orientation of each product). Batched matmuls, not ``torch.func.vmap`` over ``functional_call``:
  on the CPU, vmap's per-call batching rules cost more than these small layers' arithmetic, while
  ``baddbmm`` is one kernel per layer; and it gives every seed the same bits whatever the batch
  holds (tested; for layer widths that are multiples of 4, as every preset's are), so a seed's run
  does not depend on which seeds share the process. The convolutional layers of an image trunk
  run per seed (:func:`~cartpole.agents.nn.stacked_conv.stacked_conv2d`), for the same reason. An
  update of MLPs differentiates by hand: autograd takes the loss only as far as the logits and
  values, and :func:`~cartpole.agents.nn.stacked_linear.mlp_gradients` makes autograd's own
  products from there, bit for bit, without its graph's per-node bookkeeping (PPO's default update
  a fifth cheaper; tested against autograd for every loss, activation and a shared trunk).
- The envs (:mod:`cartpole.envs.seed_envs`): on CartPole's fast simulator S x N envs stepped by one
  kernel call, each seed's start states drawn from its own generator in Gymnasium's order (those of
  the single run's vector env), drawn as frame stacks for the pixel envs; on any other env each
  seed's own Gymnasium vector env. The actors act through a frozen NumPy copy of their weights
  (``np.matmul`` per seed's slice), which costs less than torch for the few rows of one step; a
  convolutional actor acts through torch (its convolutions are torch's strength, and it has no
  NumPy twin). Pixel observations stay uint8 in the rollout; the network scales them.
- ``PopulationAdam`` (:mod:`cartpole.agents.nn.population_optimizers`): one Adam step for all seeds
  over the flat parameters, one numba pass per seed's row on the CPU. Adam is per element,
  so seeds stay independent; each seed has its own learning rate (schedules follow the seed's own
  env steps), step count, and can sit a step out (its last minibatch is empty, or it stopped on the
  target KL).
- ``PopulationPPO``: one ``learn()`` = one rollout and one PPO update for every active seed, with
  masked minibatches (seeds have different numbers of valid rows). ``remove`` drops seeds that have
  stopped (solved or out of budget), so they cost nothing more; ``seed_state_dict`` and
  ``seed_policy`` give one seed's checkpoint and greedy policy in the single run's format, so
  ``load_policy``, ``cartpole eval`` and the web app read them unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from cartpole.agents.actor_critic.a2c import A2CConfig
from cartpole.agents.actor_critic.network import (
    ActorCritic,
    CategoricalPolicy,
    ScalePixels,
    block_greedy_actor,
    conv_output_size,
    parameter_count,
    scale_pixels,
    schedule_value,
    stacked_greedy_actor,
)
from cartpole.agents.actor_critic.policy_gradient import (
    generalized_advantages,
    policy_loader,
    seeded_actor_critic,
)
from cartpole.agents.actor_critic.ppo import PPOConfig
from cartpole.agents.actor_critic.reinforce import ReinforceConfig
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.fast_tanh import tanh_gradient
from cartpole.agents.nn.flat_parameters import FlatParameters, on_the_cpu
from cartpole.agents.nn.numpy_mlp import NUMPY_ACTIVATIONS, StackedNumpyMLP, Step
from cartpole.agents.nn.population_optimizers import population_optimizer
from cartpole.agents.nn.stacked_conv import channels_last, stacked_conv2d
from cartpole.agents.nn.stacked_linear import (
    TORCH_ACTIVATIONS,
    ActivationGradient,
    mlp_gradients,
    relu_gradient,
    stacked_linear,
)
from cartpole.agents.nn.standardize import StandardizeObservations
from cartpole.agents.population import Finished, SeedEpisodes, SeedRows, require_training_state
from cartpole.agents.registry import AgentSpec
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import LONGEST_EPISODE_WITHOUT_TIME_LIMIT
from cartpole.evaluation import BlockActor


@dataclass(frozen=True)
class ConvStep:
    """A convolutional layer of a forward pass: its parameters' names and its stride."""

    weight: str
    bias: str
    stride: int


Layer = tuple[str, str] | ConvStep | StandardizeObservations | type[nn.Module]
"""A step of a forward pass: (weight name, bias name) of a linear layer, a convolutional layer, the
observations' standardization (its constants are the same for every seed), or a parameter-free
layer's type (an activation, ScalePixels, Flatten)."""


def forward_plan(model: ActorCritic, trunk_name: str, head_name: str) -> list[Layer]:
    """The steps from observation to one head's output, by parameter name."""
    plan: list[Layer] = list(model.input_layers())
    for index, layer in enumerate(getattr(model, trunk_name)):
        name = f"{trunk_name}.{index}"
        if isinstance(layer, nn.Linear):
            plan.append((f"{name}.weight", f"{name}.bias"))
        elif isinstance(layer, nn.Conv2d):
            if layer.padding != (0, 0) or layer.stride[0] != layer.stride[1]:
                raise ValueError(f"{name}: stacked convolutions take no padding and one stride")
            plan.append(ConvStep(f"{name}.weight", f"{name}.bias", layer.stride[0]))
        else:
            plan.append(type(layer))
    return [*plan, (f"{head_name}.weight", f"{head_name}.bias")]


def flatten_images(x: torch.Tensor) -> torch.Tensor:
    """[S, B, C, H, W] -> [S, B, C * H * W], as nn.Flatten flattens each row."""
    return x.flatten(2)


def scale_stacked_pixels(x: torch.Tensor) -> torch.Tensor:
    """:func:`scale_pixels` of [S, B, C, H, W] pixels laid out channels-last first (while uint8:
    a quarter of the bytes), as :func:`stacked_conv2d` takes them."""
    return scale_pixels(channels_last(x))


ACTIVATION_GRADIENTS: dict[type[nn.Module], ActivationGradient] = {
    nn.Tanh: tanh_gradient,
    nn.ReLU: relu_gradient,
}
"""The activations of the networks whose gradients an update computes by hand."""


@dataclass(frozen=True)
class HandBackward:
    """How one head's gradients are computed by hand: its linear layers' (weight, bias) names, in
    order, and the gradient of the activation between them."""

    layers: list[tuple[str, str]]
    activation: ActivationGradient

    @classmethod
    def of(cls, plan: list[Layer]) -> HandBackward | None:
        """For an MLP ``plan`` (linear layers and activations of :data:`ACTIVATION_GRADIENTS`, the
        observations' standardization first, if any); None for any other network."""
        steps = plan[1:] if plan and isinstance(plan[0], StandardizeObservations) else plan
        others = [step for step in steps if not isinstance(step, tuple)]
        if not all(isinstance(step, type) and step in ACTIVATION_GRADIENTS for step in others):
            return None
        gradients = {ACTIVATION_GRADIENTS[step] for step in others if isinstance(step, type)}
        if len(gradients) > 1:
            return None
        layers = [step for step in steps if isinstance(step, tuple)]
        return cls(layers, gradients.pop() if gradients else relu_gradient)


@dataclass
class UpdatePass:
    """What :meth:`StackedActorCritic.forward_for_update` keeps for the backward pass by hand: the
    logits and values (leaves, so autograd stops there), each head's linear layers' inputs, the
    parameters used and ``rows``, the seeds they are of (None: every seed)."""

    heads: tuple[torch.Tensor, torch.Tensor]
    inputs: tuple[list[torch.Tensor], list[torch.Tensor]]
    params: dict[str, torch.Tensor]
    rows: torch.Tensor | None


SHAPE_STEPS: dict[type[nn.Module], Callable[[torch.Tensor], torch.Tensor]] = {
    nn.Flatten: flatten_images,
}
"""The parameter-free layers of an image trunk, on a seed axis, but for ``ScalePixels`` (see
:meth:`StackedActorCritic.run`)."""


class StackedActorCritic(FlatParameters[ActorCritic]):
    """The actor-critics of S seeds (:class:`~cartpole.agents.nn.flat_parameters.FlatParameters`),
    each linear layer one ``torch.baddbmm`` for all seeds."""

    def __init__(self, models: list[ActorCritic], device: torch.device):
        super().__init__(models, device)
        self.scaled: tuple[torch.Tensor, torch.Tensor] | None = None
        """The last pixels :meth:`scale_once` scaled, and their scaled values."""
        critic_trunk = "actor_trunk" if self.template.shared_trunk else "critic_trunk"
        self.actor_plan = forward_plan(self.template, "actor_trunk", "policy_head")
        self.critic_plan = forward_plan(self.template, critic_trunk, "value_head")
        self.hand = (HandBackward.of(self.actor_plan), HandBackward.of(self.critic_plan))
        self.by_hand = None not in self.hand
        """Whether an update's gradients are computed by hand (MLPs; autograd's otherwise)."""
        self.update_pass: UpdatePass | None = None

    @staticmethod
    def run(
        plan: list[Layer],
        params: dict[str, torch.Tensor],
        x: torch.Tensor,
        scale: Callable[[torch.Tensor], torch.Tensor] = scale_stacked_pixels,
        inputs: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """``x`` [S, B, *obs_shape] through ``plan``: one baddbmm per linear layer for all seeds, one
        conv2d per seed and convolutional layer; pixels scaled by ``scale``. ``inputs``, when given,
        receives each linear layer's input, in order."""
        for step in plan:
            if isinstance(step, tuple):
                weight, bias = params[step[0]], params[step[1]]
                if inputs is not None:
                    inputs.append(x)
                x = stacked_linear(x, weight, bias)
            elif isinstance(step, ConvStep):
                x = stacked_conv2d(x, params[step.weight], params[step.bias], step.stride)
            elif isinstance(step, StandardizeObservations):
                x = step.forward(x)
            elif step is ScalePixels:
                x = scale(x)
            elif step in SHAPE_STEPS:
                x = SHAPE_STEPS[step](x)
            else:
                x = TORCH_ACTIVATIONS[step](x)
        return x

    def scale_once(self, pixels: torch.Tensor) -> torch.Tensor:
        """:func:`scale_stacked_pixels` of ``pixels``, computed once while the same tensor comes
        again (the actor and the critic see the same observations; PPO's epochs of one whole batch
        the same rollout), until :meth:`forget_scaled`. Pixels take no gradient: sharing is safe."""
        if self.scaled is None or self.scaled[0] is not pixels:
            self.scaled = (pixels, scale_stacked_pixels(pixels))
        return self.scaled[1]

    def forget_scaled(self) -> None:
        """Let go of the scaled pixels that :meth:`scale_once` keeps (4 bytes a pixel)."""
        self.scaled = None

    def logits(self, observations: torch.Tensor) -> torch.Tensor:
        """Action logits [S, B, n_actions] of observations [S, B, *obs_shape]."""
        return self.run(self.actor_plan, self.params, observations, self.scale_once)

    def values(self, observations: torch.Tensor) -> torch.Tensor:
        """State values [S, B]."""
        return self.run(self.critic_plan, self.params, observations, self.scale_once).squeeze(-1)

    def forward_for_update(
        self, observations: torch.Tensor, rows: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Logits [S, B, n_actions] and values [S, B] of observations [S, B, *obs_shape] under the
        networks of the seeds at ``rows`` (None: all), for a loss that :meth:`backward` differentiates.
        An MLP runs without autograd, keeping what the backward pass by hand needs."""
        self.update_pass = None
        if not self.by_hand:
            params = self.rows_of_params(rows)
            scale = self.scale_once
            logits = self.run(self.actor_plan, params, observations, scale)
            return logits, self.run(self.critic_plan, params, observations, scale).squeeze(-1)
        with torch.no_grad():  # the rows' parameters too: the gradients by hand need no graph
            params = self.rows_of_params(rows)
            inputs: tuple[list[torch.Tensor], list[torch.Tensor]] = ([], [])
            logits = self.run(self.actor_plan, params, observations, inputs=inputs[0]).requires_grad_()
            values = self.run(self.critic_plan, params, observations, inputs=inputs[1]).requires_grad_()
        self.update_pass = UpdatePass((logits, values), inputs, params, rows)
        return logits, values.squeeze(-1)

    def rows_of_params(self, rows: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """The parameters of the seeds at ``rows`` (None: all)."""
        return self.params if rows is None else {name: p[rows] for name, p in self.params.items()}

    def backward(self, loss: torch.Tensor) -> None:
        """Add to ``grad`` the gradient of ``loss`` (a scalar) with respect to the parameters, through
        the last :meth:`forward_for_update`. For MLPs, autograd differentiates the loss only as far as
        the logits and values; the networks' gradients are then computed by hand
        (:func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`: autograd's products, without its
        graph's bookkeeping, which costs more than small layers' arithmetic)."""
        update, self.update_pass = self.update_pass, None
        if update is None:
            super().backward(loss)
            return
        head_grads = torch.autograd.grad(loss, update.heads, allow_unused=True)
        for hand, inputs, grad in zip(self.hand, update.inputs, head_grads, strict=True):
            if hand is None or grad is None:  # None: the loss has no value term (REINFORCE alone)
                continue
            layers = [(update.params[weight], update.params[bias]) for weight, bias in hand.layers]
            gradients = mlp_gradients(layers, inputs, grad, hand.activation)
            for names, pair in zip(hand.layers, gradients, strict=True):
                for name, gradient in zip(names, pair, strict=True):
                    self.add_gradient(name, gradient, update.rows)

    def add_gradient(self, name: str, gradient: torch.Tensor, rows: torch.Tensor | None) -> None:
        """Add ``gradient`` to parameter ``name``'s gradient, of every seed or of the seeds at ``rows``."""
        target = self.params[name].grad
        assert target is not None
        if rows is None:
            target.add_(gradient)
        else:
            target.index_add_(0, rows, gradient)

    def numpy_actor(self, rows: list[int] | None = None) -> StackedNumpyMLP:
        """A frozen NumPy copy of the actors of ``rows`` (default: all), logits ``[S, B, n_actions]``.

        NumPy, as a single run's policy (:class:`~cartpole.agents.nn.numpy_mlp.NumpyMLP`): acting
        runs a few rows at a time, where torch's per-op overhead dominates, so ``np.matmul`` over the
        stacked weights (each seed's slice on its own) costs less than ``baddbmm``."""
        plan: list[Step] = []
        for step in self.actor_plan:
            if isinstance(step, tuple):
                plan.append(self.numpy_linear(*step, rows))
            elif isinstance(step, ConvStep):
                raise ValueError("a convolutional actor has no numpy copy: act with rollout_actor")
            elif isinstance(step, StandardizeObservations):
                plan.append(step.constants)
            else:
                plan.append(NUMPY_ACTIVATIONS[step])
        return StackedNumpyMLP(plan)

    def rollout_actor(self) -> Callable[[np.ndarray], np.ndarray]:
        """Logits ``[S, N, n_actions]`` (numpy) of every seed's observations ``[S, N, *obs_shape]``
        during a rollout: through :meth:`numpy_actor` for an MLP, through torch on the current
        weights for a convolutional actor (no numpy twin)."""
        if not self.template.is_image:
            return self.numpy_actor()
        params = {name: p.detach() for name, p in self.params.items()}
        device = self.flat.device

        @torch.no_grad()
        def logits(observations: np.ndarray) -> np.ndarray:
            x = torch.from_numpy(observations).to(device)
            return self.run(self.actor_plan, params, x).cpu().numpy()

        return logits

    def torch_block_actor(self, rows: list[int]) -> BlockActor:
        """The greedy actions of the actors of ``rows`` as one :data:`BlockActor`, through torch: for
        convolutional actors."""
        return self.block_actor(rows, self.template.obs_shape, lambda p, x: self.run(self.actor_plan, p, x))


def sample_actions(logits: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of ``logits`` [..., n_actions] by inverse CDF from ``uniforms`` [...]: the
    number of cumulative softmax probabilities (the last left out) below the uniform."""
    shifted = np.exp(logits - logits.max(axis=-1, keepdims=True))
    cdf = shifted.cumsum(axis=-1)
    return (cdf[..., :-1] < uniforms[..., None] * cdf[..., -1:]).sum(axis=-1)


def masked_mean(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per-seed mean of ``x`` [S, B] over the rows where ``mask`` (float) is 1; [S]."""
    return (x * mask).sum(dim=1) / count.clamp(min=1.0)


def mean_entropy(
    log_probs: torch.Tensor, mask: torch.Tensor, count: torch.Tensor, differentiable: bool
) -> torch.Tensor:
    """Per-seed mean entropy [S] of the policies whose log-probabilities are ``log_probs`` [S, B,
    n_actions], over the masked rows; without a gradient unless ``differentiable`` (a loss that weighs
    it 0 needs none, and its backward pass would only add zeros)."""
    with torch.set_grad_enabled(differentiable and torch.is_grad_enabled()):
        return masked_mean(-(log_probs.exp() * log_probs).sum(dim=-1), mask, count)


def log_probs_and_entropy(
    logits: torch.Tensor, actions: torch.Tensor, mask: torch.Tensor, count: torch.Tensor, ent_coef: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The log-probabilities [S, B] of ``actions`` [S, B] under ``logits`` [S, B, n_actions], and
    each seed's mean entropy [S] over the masked rows (differentiable only where ``ent_coef`` weighs
    it in the loss: :func:`mean_entropy`)."""
    log_probs_all = torch.log_softmax(logits, dim=-1)
    log_probs = log_probs_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    return log_probs, mean_entropy(log_probs_all, mask, count, ent_coef != 0.0)


def masked_normalize(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per seed, ``(x - mean) / (std + 1e-8)`` over the masked rows (a single row is only centred)."""
    mean = masked_mean(x, mask, count).unsqueeze(1)
    centred = (x - mean) * mask
    variance = centred.square().sum(dim=1) / (count - 1.0).clamp(min=1.0)
    std = torch.where(count > 1.0, variance.sqrt() + 1e-8, torch.ones_like(variance))
    return centred / std.unsqueeze(1)


def clipped_surrogate_loss(
    ratio: torch.Tensor, advantages: torch.Tensor, clip: torch.Tensor, mask: torch.Tensor, count: torch.Tensor
) -> torch.Tensor:
    """PPO's policy loss per seed [S]: the masked mean over rows of ``max(-A r, -A clip(r, 1 - c,
    1 + c))``, ``ratio`` r and ``advantages`` A [S, B], ``clip`` c [S, 1] (each seed's own)."""
    clipped_ratio = torch.minimum(torch.maximum(ratio, 1.0 - clip), 1.0 + clip)
    return masked_mean(torch.max(-advantages * ratio, -advantages * clipped_ratio), mask, count)


def clipped_value_loss(
    values: torch.Tensor,
    old_values: torch.Tensor,
    returns: torch.Tensor,
    clip_range_vf: float | None,
    mask: torch.Tensor,
    count: torch.Tensor,
) -> torch.Tensor:
    """Half the masked mean squared error of ``values`` against ``returns`` per seed [S]; with
    ``clip_range_vf``, each row's error is the larger of the plain one and that of the value clipped
    to ``old_values +- clip_range_vf`` (as SB3 and CleanRL clip)."""
    squared = (values - returns).square()
    if clip_range_vf is not None:
        clipped_values = old_values + (values - old_values).clamp(-clip_range_vf, clip_range_vf)
        squared = torch.max(squared, (clipped_values - returns).square())
    return 0.5 * masked_mean(squared, mask, count)


@dataclass
class Transitions:
    """What the envs of every active seed did, time-major ``[T, S * N]`` (observations ``T + 1``)."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    valid: torch.Tensor

    def columns(self, envs: torch.Tensor, steps: int) -> Transitions:
        """The envs ``envs`` only, over ``steps`` steps (padded with invalid rows past the end)."""

        def cut(x: torch.Tensor, rows: int) -> torch.Tensor:
            x = x[: min(rows, x.shape[0]), envs]
            if x.shape[0] < rows:
                x = torch.cat([x, x.new_zeros(rows - x.shape[0], *x.shape[1:])])
            return x

        return Transitions(
            observations=cut(self.observations, steps + 1),
            actions=cut(self.actions, steps),
            log_probs=cut(self.log_probs, steps),
            rewards=cut(self.rewards, steps),
            terminated=cut(self.terminated, steps),
            truncated=cut(self.truncated, steps),
            valid=cut(self.valid, steps),
        )


@dataclass
class Rollout:
    """One rollout of every active seed: rows ``[S, T * N]`` (time-major within a seed)."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    values: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor
    valid: torch.Tensor
    counts: torch.Tensor
    """Valid rows per seed [S]."""


ROW_METRICS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")


class PopulationActorCritic(SeedRows):
    """What every actor-critic population shares: the seeds' stacked networks, their envs and
    generators, the batched rollout with GAE, gradient clipping and the optimizer step, and each
    seed's policy and checkpoint. Subclasses say what one ``learn()`` does with a rollout."""

    config: PPOConfig | A2CConfig | ReinforceConfig

    def __init__(
        self,
        config: PPOConfig | A2CConfig | ReinforceConfig,
        env: EnvInfo,
        seeds: list[int],
        device: str,
        optimizer: str = "adam",
        eps: float = 1e-8,
        rms_alpha: float = 0.99,
    ):
        config.validate()
        self.config, self.env_info = config, env
        self.device = torch.device(device)
        """Where the networks, rollouts and updates live. The envs step on the CPU (numpy) and the
        seeds' random numbers come from their CPU generators, so a seed's draws are the same on any
        device; only the floats of the network arithmetic differ between devices."""
        self.seeds = list(seeds)
        with on_the_cpu():  # initialized as the single run initializes them, then moved
            models = [seeded_actor_critic(config, env, seed) for seed in self.seeds]
        self.model = StackedActorCritic(models, self.device)
        self.optimizer = population_optimizer(
            optimizer, len(self.seeds), self.model.size, self.device, eps, rms_alpha
        )
        self.generators = [torch.Generator().manual_seed(derived_seed(s, "actions")) for s in self.seeds]
        self.episodes = SeedEpisodes(env, config.simulator, self.seeds, config.num_envs)
        self.env_steps = np.zeros(len(self.seeds), dtype=np.int64)
        self.updates = np.zeros(len(self.seeds), dtype=np.int64)

    # -- which seeds --------------------------------------------------------------------------------

    def remove(self, seeds: list[int]) -> None:
        """Stop training ``seeds`` (solved or out of budget): they leave every batch."""
        rows_np, envs = self.leave(seeds, self.config.num_envs)
        rows = torch.from_numpy(rows_np).to(self.device)
        self.model.keep(rows)
        self.optimizer.keep(rows)
        self.episodes.keep(rows_np, envs)
        self.generators = [self.generators[i] for i in rows_np]
        self.env_steps, self.updates = self.env_steps[rows_np], self.updates[rows_np]

    # -- one learning step: the shared parts --------------------------------------------------------

    def learn(self) -> dict[int, LearnResult]:
        """A rollout and an update for every active seed; each seed's result by seed."""
        raise NotImplementedError

    def learning_rates(self) -> list[float]:
        """Each seed's learning rate now (schedules follow the seed's own env steps)."""
        config = self.config
        return [
            schedule_value(config.lr, config.lr_schedule, int(s), config.schedule_steps)
            for s in self.env_steps
        ]

    def count_steps(self, counts: list[int], finished: Finished) -> dict[int, LearnResult]:
        """Add each seed's new transitions (``counts``) to its env steps; its result (steps and
        finished episodes)."""
        results = {}
        for row, seed in enumerate(self.seeds):
            returns, lengths = finished[row]
            self.env_steps[row] += counts[row]
            results[seed] = LearnResult(counts[row], episode_returns=returns, episode_lengths=lengths)
        return results

    def attach_metrics(
        self, results: dict[int, LearnResult], counts: torch.Tensor, metrics: list[dict[str, float]]
    ) -> None:
        """Give each seed that updated (``counts`` [S] of new transitions) its metrics row."""
        for row, (seed, count) in enumerate(zip(self.seeds, counts.tolist(), strict=True)):
            if count == 0:
                continue
            results[seed].scalars = metrics[row]
            results[seed].log_scalars = True

    def backward_and_step(self, losses: torch.Tensor, lr: torch.Tensor, active: torch.Tensor) -> None:
        """Gradients of every active seed's loss (``losses`` [S]), clipped per seed, one optimizer step."""
        self.model.grad.zero_()
        self.model.backward((losses * active.float()).sum())
        self.step(lr, active)

    def explained_variances(self, rollout: Rollout) -> torch.Tensor:
        """Per seed, how much of the returns' variance the values explain (NaN with no variance)."""
        valid = rollout.valid.float()
        variance = masked_variance(rollout.returns, valid, rollout.counts)
        residual = masked_variance(rollout.returns - rollout.values, valid, rollout.counts)
        return torch.where(variance > 0, 1.0 - residual / variance, torch.full_like(variance, math.nan))

    def collect(self, log_probs: bool = True) -> tuple[Rollout, Finished]:
        """``n_steps`` batched steps of all S x N envs; the rollout with GAE advantages (and, with
        ``log_probs``, the actions' log-probabilities), and each seed's finished episodes."""
        transitions, finished = self.play(self.config.n_steps, log_probs=log_probs)  # type: ignore[union-attr]
        return self.advantages(transitions, self.model.params, len(self.seeds)), finished

    @torch.no_grad()
    def play(
        self, steps: int, whole_episodes: bool = False, log_probs: bool = True
    ) -> tuple[Transitions, Finished]:
        """Up to ``steps`` batched steps of all S x N envs; what they did, and each seed's finished
        episodes (returns, lengths). With ``whole_episodes`` (REINFORCE) each env plays one
        episode: its rows after it ended are invalid, and play stops once every env has ended one.
        The actors act through a frozen NumPy copy (:meth:`StackedActorCritic.numpy_actor`); the
        log-probabilities of their actions (PPO's old ones; zeros without ``log_probs``) come from one
        torch pass after the rollout."""
        config = self.config
        seeds, envs = len(self.seeds), config.num_envs
        obs_shape = self.env_info.obs_shape
        actor = self.model.rollout_actor()
        episodes = self.episodes
        observations = np.zeros((steps + 1, seeds * envs, *obs_shape), dtype=episodes.observations.dtype)
        actions = np.zeros((steps, seeds * envs), dtype=np.int64)
        rewards = np.zeros((steps, seeds * envs), dtype=np.float32)
        terminated = np.zeros((steps, seeds * envs), dtype=np.float32)
        truncated = np.zeros((steps, seeds * envs), dtype=np.float32)
        valid = np.zeros((steps, seeds * envs), dtype=bool)
        ended_once = np.zeros(seeds * envs, dtype=bool)
        # Each seed's uniforms for the whole rollout, from its own generator: one call per seed.
        uniforms = np.stack(
            [torch.rand(steps, envs, generator=g, device="cpu").numpy() for g in self.generators], axis=1
        )
        finished: Finished = [([], []) for _ in range(seeds)]
        used = steps
        for t in range(steps):
            observations[t] = episodes.observations
            logits = actor(episodes.observations.reshape(seeds, envs, *obs_shape))
            actions[t] = sample_actions(logits, uniforms[t]).reshape(-1)
            step = episodes.step(actions[t], finished, ended_once if whole_episodes else None)
            rewards[t], terminated[t], truncated[t], valid[t] = (
                step.rewards,
                step.terminated,
                step.truncated,
                step.valid,
            )
            if whole_episodes:
                ended_once |= step.ended
                if ended_once.all():
                    used = t + 1
                    break
        observations[used] = episodes.observations

        def tensor(x: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(x).to(self.device)

        played = tensor(observations[: used + 1])
        taken = tensor(actions[:used])
        transitions = Transitions(
            observations=played,
            actions=taken,
            log_probs=self.log_probs_of(played[:used], taken)
            if log_probs
            else torch.zeros_like(taken, dtype=torch.float32),
            rewards=tensor(rewards[:used]),
            terminated=tensor(terminated[:used]),
            truncated=tensor(truncated[:used]),
            valid=tensor(valid[:used]),
        )
        return transitions, finished

    @torch.no_grad()
    def log_probs_of(self, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """The log-probabilities [T, S * N] under the current actors of ``actions`` [T, S * N] taken at
        ``observations`` [T, S * N, *obs_shape]: one batched pass over the whole rollout."""
        steps, rows, *obs_shape = observations.shape
        seeds = len(self.seeds)
        by_seed = (
            observations.view(steps, seeds, -1, *obs_shape).transpose(0, 1).reshape(seeds, -1, *obs_shape)
        )
        log_probs = torch.log_softmax(self.model.logits(by_seed), dim=-1)
        chosen = actions.view(steps, seeds, -1).transpose(0, 1).reshape(seeds, -1, 1)
        return log_probs.gather(-1, chosen).view(seeds, steps, -1).transpose(0, 1).reshape(steps, rows)

    @torch.no_grad()
    def advantages(
        self,
        t: Transitions,
        params: dict[str, torch.Tensor],
        seeds: int,
        gae_lambda: float | None = None,
        use_values: bool = True,
    ) -> Rollout:
        """GAE over the envs of ``seeds`` seeds at once (envs are columns, the seeds' networks are
        ``params``), reshaped to [S, T * N]. ``use_values`` False: values are 0, so advantages are
        the discounted reward-to-go."""
        config = self.config
        steps, envs = t.rewards.shape[0], config.num_envs
        if gae_lambda is None:
            gae_lambda = config.gae_lambda  # type: ignore[union-attr]  # PPO and A2C have one

        def per_seed(x: torch.Tensor) -> torch.Tensor:  # [T, S * N, ...] -> [S, T * N, ...]
            return (
                x.view(steps, seeds, envs, *x.shape[2:])
                .transpose(0, 1)
                .reshape(seeds, steps * envs, *x.shape[2:])
            )

        obs_shape = self.env_info.obs_shape
        if use_values:
            by_seed = (
                t.observations.view(steps + 1, seeds, envs, *obs_shape)
                .transpose(0, 1)
                .reshape(seeds, -1, *obs_shape)
            )
            critic = StackedActorCritic.run(self.model.critic_plan, params, by_seed).squeeze(-1)
            values = critic.view(seeds, steps + 1, envs).transpose(0, 1).reshape(steps + 1, -1)
        else:
            values = torch.zeros(steps + 1, seeds * envs, device=self.device)
        advantages = generalized_advantages(
            t.rewards, values, t.terminated, t.truncated, t.valid, config.gamma, gae_lambda
        )
        valid_rows = per_seed(t.valid)
        return Rollout(
            observations=per_seed(t.observations[:steps]),
            actions=per_seed(t.actions),
            log_probs=per_seed(t.log_probs),
            values=per_seed(values[:steps]),
            advantages=per_seed(advantages),
            returns=per_seed(advantages + values[:steps]),
            valid=valid_rows,
            counts=valid_rows.sum(dim=1).to(torch.float32),
        )

    def step(self, lr: torch.Tensor, active: torch.Tensor) -> None:
        """Clip each seed's gradient norm to ``max_grad_norm`` (as clip_grad_norm_ does), then Adam."""
        if self.config.max_grad_norm is not None:
            self.model.clip_grad_norms(self.config.max_grad_norm)
        self.optimizer.step(self.model.flat, self.model.grad, lr, active)

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The greedy policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor` (block i
        holds seed i's rows), one stacked NumPy forward pass per call (torch for convolutional actors)."""
        rows = [self.row(s) for s in seeds]
        if self.model.template.is_image:
            return self.model.torch_block_actor(rows)
        return block_greedy_actor(self.model.numpy_actor(rows), self.env_info.obs_dim)

    # -- one seed, as a single run sees it ----------------------------------------------------------

    def seed_policy(self, seed: int) -> CategoricalPolicy:
        """Seed ``seed``'s greedy policy (a frozen copy)."""
        return CategoricalPolicy(self.model.unstack(self.row(seed)))

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``seed``'s checkpoint: ``model.*`` as the single run's (``load_policy`` reads it), and
        with ``resume`` its optimizer, generators, envs and counters."""
        row = self.row(seed)
        model = self.model.unstack(row)
        tensors = {f"model.{k}": v.detach().clone() for k, v in model.state_dict().items()}
        data: dict[str, Any] = {
            "obs_dim": self.env_info.obs_dim,
            "obs_shape": list(self.env_info.obs_shape),
            "n_actions": self.env_info.n_actions,
        }
        if not resume:
            return tensors, data
        optim_tensors, optim_data = self.optimizer.row_state(row)
        env_tensors, env_data = self.episodes.seed_state(row)
        tensors |= optim_tensors | env_tensors | {"rng.torch": self.generators[row].get_state()}
        data |= {
            "population": True,
            **optim_data,
            **env_data,
            "env_steps": int(self.env_steps[row]),
            "updates": int(self.updates[row]),
        }
        return tensors, data

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``seed_state_dict(seed, resume=True)`` gave."""
        require_training_state(data)
        row = self.row(seed)
        model = self.model.template
        model.load_state_dict(
            {k.removeprefix("model."): v for k, v in tensors.items() if k.startswith("model.")}
        )
        self.model.load_row(row, dict(model.named_parameters()))
        self.optimizer.load_row_state(row, tensors, data)
        self.generators[row].set_state(tensors["rng.torch"])
        self.episodes.load_seed_state(row, tensors, data)
        self.env_steps[row], self.updates[row] = int(data["env_steps"]), int(data["updates"])


class PopulationPPO(PopulationActorCritic):
    """PPO for seeds ``seeds``, all with ``config``: one ``learn()`` = a rollout and an update each."""

    config: PPOConfig

    def __init__(self, config: PPOConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device, eps=config.adam_eps)

    # -- one learning step --------------------------------------------------------------------------

    def learn(self) -> dict[int, LearnResult]:
        """A rollout and an update for every active seed; each seed's result by seed."""
        config = self.config
        lr = self.learning_rates()
        clip = [
            max(schedule_value(config.clip_range, config.clip_schedule, int(s), config.schedule_steps), 1e-8)
            for s in self.env_steps
        ]
        rollout, finished = self.collect()
        results = self.count_steps(rollout.counts.to(torch.int64).tolist(), finished)
        metrics = self.update(
            rollout, torch.tensor(lr, device=self.device), torch.tensor(clip, device=self.device).unsqueeze(1)
        )
        self.model.forget_scaled()
        extra = [{"train/learning_rate": r, "train/clip_range": c} for r, c in zip(lr, clip, strict=True)]
        self.attach_metrics(results, rollout.counts, [m | e for m, e in zip(metrics, extra, strict=True)])
        return results

    def update(self, rollout: Rollout, lr: torch.Tensor, clip: torch.Tensor) -> list[dict[str, float]]:
        """``n_epochs`` passes of each seed's shuffled valid rows in minibatches; per-seed metrics."""
        config = self.config
        seeds, rows = rollout.valid.shape
        size = config.minibatch_size
        has_rows = rollout.counts > 0
        whole = size >= rows  # one minibatch of every row, as the single run takes it: no shuffle
        if not whole:  # each seed's shuffles for all epochs from its own generator; invalid rows last
            keys = torch.stack(
                [torch.rand(config.n_epochs, rows, generator=g, device="cpu") for g in self.generators]
            ).to(self.device)
            keys.masked_fill_(~rollout.valid.unsqueeze(1), 2.0)
            orders = keys.argsort(dim=-1, stable=True)
        stopped = torch.zeros(seeds, dtype=torch.bool, device=self.device)
        sums = torch.zeros(seeds, len(ROW_METRICS), device=self.device)
        done_steps = torch.zeros(seeds, device=self.device)
        batches = math.ceil(int(rollout.counts.max()) / size) if bool(has_rows.any()) else 0
        positions = torch.arange(size, device=self.device)
        mask, count = rollout.valid.float(), rollout.counts
        normalize = config.normalize_advantages
        if whole and normalize:  # the same rows in every epoch: their advantages normalized once
            normalized = masked_normalize(rollout.advantages, mask, count)
            rollout = dataclasses.replace(rollout, advantages=normalized)
            normalize = False
        for epoch in range(config.n_epochs):
            for start in range(0, batches * size, size):
                index: torch.Tensor | None = None
                if not whole:
                    index = orders[:, epoch, start : start + size]
                    mask = (positions[: index.shape[1]] + start < rollout.counts.unsqueeze(1)).float()
                    count = mask.sum(dim=1)
                active = (count > 0) & ~stopped
                losses, row_metrics, kl = self.minibatch_loss(rollout, index, mask, count, clip, normalize)
                if config.target_kl is not None:
                    over = active & (kl > config.target_kl)
                    stopped |= over
                    active &= ~over
                if not bool(active.any()):
                    continue
                self.backward_and_step(losses, lr, active)
                sums += row_metrics * active.float().unsqueeze(1)
                done_steps += active.float()
        self.updates += has_rows.cpu().numpy()
        means = (sums / done_steps.clamp(min=1.0).unsqueeze(1)).tolist()
        stopped_list, done_list = stopped.tolist(), done_steps.tolist()
        explained = self.explained_variances(rollout).tolist()
        metrics = []
        for row in range(seeds):
            scalars = {
                "train/updates": float(self.updates[row]),
                "train/stopped_early": float(stopped_list[row]),
            }
            if done_list[row] > 0:
                scalars |= {f"train/{name}": v for name, v in zip(ROW_METRICS, means[row], strict=True)}
            scalars["train/explained_variance"] = float(explained[row])
            metrics.append(scalars)
        return metrics

    def minibatch_loss(
        self,
        rollout: Rollout,
        index: torch.Tensor | None,
        mask: torch.Tensor,
        count: torch.Tensor,
        clip: torch.Tensor,
        normalize: bool,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per-seed PPO loss [S], metrics [S, 5] (detached) and approximate KL [S] of one minibatch:
        each seed's rows ``index`` [S, B] (None: every row), their advantages normalized first with
        ``normalize``."""
        config = self.config

        def take(x: torch.Tensor) -> torch.Tensor:
            if index is None:
                return x
            if x.dim() == 2:
                return x.gather(1, index)
            rows = index.view(*index.shape, *[1] * (x.dim() - 2))  # [S, B, 1, ...]: every column
            return x.gather(1, rows.expand(-1, -1, *x.shape[2:]))

        observations, actions = take(rollout.observations), take(rollout.actions)
        old_log_probs, old_values = take(rollout.log_probs), take(rollout.values)
        advantages, returns = take(rollout.advantages), take(rollout.returns)
        logits, values = self.model.forward_for_update(observations)
        log_probs, entropy = log_probs_and_entropy(logits, actions, mask, count, config.ent_coef)
        if normalize:
            advantages = masked_normalize(advantages, mask, count)
        log_ratio = log_probs - old_log_probs
        ratio = log_ratio.exp()
        policy_loss = clipped_surrogate_loss(ratio, advantages, clip, mask, count)
        value_loss = clipped_value_loss(values, old_values, returns, config.clip_range_vf, mask, count)
        loss = policy_loss - config.ent_coef * entropy + config.vf_coef * value_loss
        with torch.no_grad():
            approx_kl = masked_mean((ratio - 1.0) - log_ratio, mask, count)
            clip_fraction = masked_mean(((ratio - 1.0).abs() > clip).float(), mask, count)
            row_metrics = torch.stack([policy_loss, value_loss, entropy, approx_kl, clip_fraction], dim=1)
        return loss, row_metrics.detach(), approx_kl


class PopulationA2C(PopulationActorCritic):
    """A2C for seeds ``seeds``, all with ``config``: one ``learn()`` = a rollout and one gradient step
    on all of it for each seed."""

    config: A2CConfig

    def __init__(self, config: A2CConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device, config.optimizer, config.optimizer_eps, config.rms_alpha)

    def learn(self) -> dict[int, LearnResult]:
        config = self.config
        lr = self.learning_rates()
        rollout, finished = self.collect(log_probs=False)  # the loss's own forward pass gives them
        results = self.count_steps(rollout.counts.to(torch.int64).tolist(), finished)
        valid, count = rollout.valid.float(), rollout.counts
        logits, values = self.model.forward_for_update(rollout.observations)
        log_probs, entropy = log_probs_and_entropy(logits, rollout.actions, valid, count, config.ent_coef)
        advantages = rollout.advantages
        if config.normalize_advantages:
            advantages = masked_normalize(advantages, valid, count)
        policy_loss = masked_mean(-(advantages * log_probs), valid, count)
        value_loss = 0.5 * masked_mean((values - rollout.returns).square(), valid, count)
        loss = policy_loss - config.ent_coef * entropy + config.vf_coef * value_loss
        active = count > 0
        self.backward_and_step(loss, torch.tensor(lr, device=self.device), active)
        self.model.forget_scaled()
        self.updates += active.cpu().numpy()
        with torch.no_grad():  # how far the step moved each policy on its own batch
            new_log_probs = torch.log_softmax(self.model.logits(rollout.observations), dim=-1)
            log_ratio = (
                new_log_probs.gather(-1, rollout.actions.unsqueeze(-1)).squeeze(-1) - log_probs.detach()
            )
            approx_kl = masked_mean((log_ratio.exp() - 1.0) - log_ratio, valid, count)
            rows = torch.stack([policy_loss, value_loss, entropy, approx_kl], dim=1).tolist()
        explained = self.explained_variances(rollout).tolist()
        names = ("policy_loss", "value_loss", "entropy", "approx_kl")
        metrics = [
            {f"train/{name}": v for name, v in zip(names, row, strict=True)}
            | {
                "train/explained_variance": explained[i],
                "train/learning_rate": lr[i],
                "train/updates": float(self.updates[i]),
            }
            for i, row in enumerate(rows)
        ]
        self.attach_metrics(results, rollout.counts, metrics)
        return results


class PopulationReinforce(PopulationActorCritic):
    """REINFORCE for seeds ``seeds``, all with ``config``: one ``learn()`` = one whole episode in each
    of every seed's envs, all started fresh, then one gradient step each.

    Episodes have different lengths, and play lasts until the longest episode of *any* seed ends. So
    that a seed's arithmetic does not depend on its neighbours, its update runs on its own rows cut
    to a length that depends only on them (its longest episode, rounded up: :func:`rounded_up`).
    Seeds of the same length update together, one batched forward and backward pass per length.
    """

    config: ReinforceConfig

    def __init__(self, config: ReinforceConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device)
        self.episode_rngs = [np.random.default_rng(derived_seed(s, "episodes")) for s in self.seeds]
        """Seed each batch's fresh episodes, as the single run's ``rng`` does."""
        self.longest = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT

    def remove(self, seeds: list[int]) -> None:
        gone = set(seeds)
        rngs = zip(self.seeds, self.episode_rngs, strict=True)
        self.episode_rngs = [rng for seed, rng in rngs if seed not in gone]
        super().remove(seeds)

    def restart(self) -> None:
        """Fresh episodes in every env, from each seed's own episode generator."""
        self.episodes.restart([int(rng.integers(2**32)) for rng in self.episode_rngs])

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors, data = super().seed_state_dict(seed, resume)
        if resume:
            data["rng_numpy"] = self.episode_rngs[self.row(seed)].bit_generator.state
        return tensors, data

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        super().load_seed_state_dict(seed, tensors, data)
        self.episode_rngs[self.row(seed)].bit_generator.state = data["rng_numpy"]

    def update_lengths(self, transitions: Transitions) -> list[int]:
        """Each seed's update length, covering its longest episode (:func:`rounded_up`, at least 8):
        padding costs at most a quarter more rows, and seeds of similar lengths share a pass."""
        steps, envs = transitions.valid.shape[0], self.config.num_envs
        played = transitions.valid.view(steps, len(self.seeds), envs).any(dim=2)  # [T, S]
        longest = [
            int(played[:, row].nonzero().max()) + 1 if bool(played[:, row].any()) else 1
            for row in range(len(self.seeds))
        ]
        return [min(self.longest, max(8, rounded_up(n))) for n in longest]

    def learn(self) -> dict[int, LearnResult]:
        lr = self.learning_rates()
        self.restart()
        transitions, finished = self.play(self.longest, whole_episodes=True, log_probs=False)
        counts = transitions.valid.view(transitions.valid.shape[0], len(self.seeds), -1).sum(dim=(0, 2))
        results = self.count_steps(counts.tolist(), finished)
        lengths = self.update_lengths(transitions)
        self.model.grad.zero_()
        metrics: list[dict[str, float]] = [{} for _ in self.seeds]
        for length in sorted(set(lengths)):
            rows = [row for row, n in enumerate(lengths) if n == length]
            self.backward_group(transitions, rows, length, metrics)
        active = counts > 0
        self.step(torch.tensor(lr, device=self.device), active)
        self.updates += active.cpu().numpy()
        for row, scalars in enumerate(metrics):
            scalars |= {"train/learning_rate": lr[row], "train/updates": float(self.updates[row])}
        self.attach_metrics(results, counts, metrics)
        return results

    def backward_group(
        self, transitions: Transitions, rows: list[int], length: int, metrics: list[dict[str, float]]
    ) -> None:
        """The loss of the seeds at ``rows`` (all with update length ``length``), backpropagated into
        their rows of the gradients; their metrics into ``metrics``."""
        config, envs = self.config, self.config.num_envs
        index = torch.tensor(rows, dtype=torch.int64, device=self.device)
        columns = (index.unsqueeze(1) * envs + torch.arange(envs, device=self.device)).reshape(-1)
        detached = {name: p.detach()[index] for name, p in self.model.params.items()}
        rollout = self.advantages(
            transitions.columns(columns, length), detached, len(rows), 1.0, config.baseline
        )
        valid, count = rollout.valid.float(), rollout.counts
        logits, values = self.model.forward_for_update(rollout.observations, index)
        log_probs, entropy = log_probs_and_entropy(logits, rollout.actions, valid, count, config.ent_coef)
        weights = (
            masked_normalize(rollout.advantages, valid, count)
            if config.normalize_returns
            else rollout.advantages
        )
        policy_loss = masked_mean(-(weights * log_probs), valid, count)
        value_loss = 0.5 * masked_mean((values - rollout.returns).square(), valid, count)
        loss = policy_loss - config.ent_coef * entropy
        if config.baseline:
            loss = loss + config.vf_coef * value_loss
        self.model.backward(loss.sum())
        self.model.forget_scaled()
        explained = self.explained_variances(rollout).tolist()
        values_of = torch.stack([policy_loss, value_loss, entropy], dim=1).tolist()
        for i, row in enumerate(rows):
            policy, value, entropy_value = values_of[i]
            metrics[row] = {"train/policy_loss": policy, "train/entropy": entropy_value}
            if config.baseline:
                metrics[row] |= {"train/value_loss": value, "train/explained_variance": explained[i]}


def rounded_up(n: int) -> int:
    """``n`` (>= 1) rounded up to a multiple of a quarter of the power of two at or below it: at most
    a quarter more, and four lengths per doubling."""
    quarter = max(1, (1 << (n.bit_length() - 1)) // 4)
    return -(-n // quarter) * quarter


def masked_variance(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per-seed unbiased variance of ``x`` [S, B] over the masked rows (0 with fewer than 2)."""
    mean = masked_mean(x, mask, count).unsqueeze(1)
    variance = ((x - mean) * mask).square().sum(dim=1) / (count - 1.0).clamp(min=1.0)
    return torch.where(count > 1.0, variance, torch.zeros_like(variance))


BOOKKEEPING_BYTES = 2 * 1024**2
"""What a seed costs besides its arrays: its run folder's writers, callbacks and status thread."""


def actor_critic_bytes_per_seed(
    config: PPOConfig | A2CConfig | ReinforceConfig, env: EnvInfo, rollout_steps: int, batch_rows: int
) -> int:
    """What one seed of an actor-critic population holds, roughly: parameters with their gradient
    and optimizer state, a rollout of ``rollout_steps`` steps of every env, the activations of a
    batch of ``batch_rows`` rows, and the bookkeeping. Image observations: the rollout keeps their
    uint8 pixels (1 byte each, not 4), and every trunk's activations include the scaled pixels and
    the convolutional layers' outputs, for the batch and for the whole rollout's no-grad passes
    (the old log-probabilities and the values)."""
    parameters = parameter_count(env.obs_shape, env.n_actions, config.hidden_sizes, config.shared_trunk)
    rows, widths, observation_bytes = batch_rows, sum(config.hidden_sizes), env.obs_dim * 4
    if env.is_image:
        rows = max(batch_rows, (rollout_steps + 1) * config.num_envs)
        widths += env.obs_dim + conv_output_size(env.obs_shape) * 4  # scaled pixels, conv outputs
        observation_bytes = env.obs_dim
    rollout = rollout_steps * config.num_envs * (observation_bytes + 8 * 4) * 3
    activations = rows * widths * 4 * 12
    return parameters * 4 * 6 + rollout + activations + BOOKKEEPING_BYTES


def ppo_bytes_per_seed(config: PPOConfig, env: EnvInfo) -> int:
    return actor_critic_bytes_per_seed(config, env, config.n_steps, config.minibatch_size)


def a2c_bytes_per_seed(config: A2CConfig, env: EnvInfo) -> int:
    return actor_critic_bytes_per_seed(config, env, config.n_steps, config.n_steps * config.num_envs)


def reinforce_bytes_per_seed(config: ReinforceConfig, env: EnvInfo) -> int:
    longest = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT
    return actor_critic_bytes_per_seed(config, env, longest, longest * config.num_envs)


def actor_critic_spec(
    name: str,
    summary: str,
    config_cls: type[PPOConfig | A2CConfig | ReinforceConfig],
    bytes_per_seed: Callable[[Any, EnvInfo], int],
    make_population: Callable[[Any, EnvInfo, list[int], str], PopulationActorCritic],
) -> AgentSpec:
    """An actor-critic agent: its checkpoints hold an :class:`ActorCritic`, its scores are action
    probabilities, and it learns from pixels too."""
    return AgentSpec(
        name=name,
        summary=summary,
        config_cls=config_cls,
        policy_from_checkpoint=policy_loader(name, config_cls),
        bytes_per_seed=bytes_per_seed,
        make_population=make_population,
        iteration="update",
        score_label="action probabilities",
        stacked_actor=stacked_greedy_actor,
        image_observations=True,
    )


AGENTS = [
    actor_critic_spec(
        "ppo",
        "Proximal Policy Optimization (PyTorch): clipped surrogate, GAE, minibatch epochs, vector envs",
        PPOConfig,
        ppo_bytes_per_seed,
        PopulationPPO,
    ),
    actor_critic_spec(
        "a2c",
        "Advantage Actor-Critic (PyTorch): n-step rollouts from vector envs, GAE, RMSprop or Adam",
        A2CConfig,
        a2c_bytes_per_seed,
        PopulationA2C,
    ),
    actor_critic_spec(
        "reinforce",
        "REINFORCE (PyTorch): Monte-Carlo policy gradient on whole episodes, optional learned baseline",
        ReinforceConfig,
        reinforce_bytes_per_seed,
        PopulationReinforce,
    ),
]
"""The actor-critic agents: their settings (ppo.py, a2c.py, reinforce.py) and their learners, batched
over seeds (above)."""


__all__ = [
    "AGENTS",
    "PopulationA2C",
    "PopulationPPO",
    "PopulationReinforce",
    "StackedActorCritic",
    "a2c_bytes_per_seed",
    "ppo_bytes_per_seed",
    "reinforce_bytes_per_seed",
]
