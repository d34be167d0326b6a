"""The actor-critics of S seeds as one: their parameters in one flat ``[S, P]`` tensor, each layer run
for every seed at once, and an update's gradients computed by hand for MLPs.

- :class:`StackedActorCritic` (:class:`~cartpole.agents.nn.flat_parameters.FlatParameters`): each
  linear layer is a view ``[S, out, in]`` of the flat rows and runs as one fixed-order product over
  the seed axis (:func:`~cartpole.agents.nn.stacked_linear.stacked_linear`); the convolutional layers of
  an image trunk run one ``conv2d`` per seed (:func:`~cartpole.agents.nn.stacked_conv.stacked_conv2d`).
  Each network is walked by its *forward plan* (:func:`forward_plan`: the layers from observation to
  one head, by parameter name), the same plan for every seed.
- :class:`HandBackward`: for an MLP, autograd takes the loss only as far as the logits and values;
  :func:`~cartpole.agents.nn.stacked_linear.mlp_gradients` makes autograd's own products from
  there, bit for bit (tested against autograd for every loss, activation and a shared trunk).
- :meth:`StackedActorCritic.numpy_actor`: a frozen NumPy copy of the actors, what a rollout acts
  through (:mod:`cartpole.agents.nn.numpy_mlp`); a convolutional actor acts through torch.

Why each of these forms, and the measurements behind them: :mod:`cartpole.agents.nn`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from cartpole.agents.actor_critic.network import ActorCritic, ScalePixels, scale_pixels
from cartpole.agents.nn import fused_mlp
from cartpole.agents.nn.fast_tanh import tanh_gradient
from cartpole.agents.nn.flat_parameters import FlatParameters
from cartpole.agents.nn.numpy_mlp import NUMPY_ACTIVATIONS, StackedNumpyMLP, Step
from cartpole.agents.nn.stacked_conv import channels_last, stacked_conv2d
from cartpole.agents.nn.stacked_linear import (
    TORCH_ACTIVATIONS,
    ActivationGradient,
    mlp_gradients,
    relu_gradient,
    stacked_linear,
)
from cartpole.agents.nn.standardize import StandardizeObservations
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


def tanh_mlp_layers(plan: list[Layer]) -> list[tuple[str, str]] | None:
    """The linear layers of ``plan`` when it is a tanh MLP of a hidden layer or more (the
    observations' standardization first, if any), what :mod:`~cartpole.agents.nn.fused_mlp` runs in
    one call; None for any other network."""
    steps = plan[1:] if plan and isinstance(plan[0], StandardizeObservations) else plan
    linear, between = steps[0::2], steps[1::2]
    if len(steps) < 3 or len(steps) % 2 == 0 or any(step is not nn.Tanh for step in between):
        return None
    layers = [step for step in linear if isinstance(step, tuple)]
    return layers if len(layers) == len(linear) else None


_TANH_MLPS: dict[int, tuple[list[Layer], list[tuple[str, str]] | None]] = {}
""":func:`tanh_mlp_layers` of each plan met, by the plan's id (the plan kept with it, so that the id
stays its own)."""


def run_fused(
    plan: list[Layer], params: dict[str, torch.Tensor], x: torch.Tensor, inputs: list[torch.Tensor] | None
) -> torch.Tensor | None:
    """:meth:`StackedActorCritic.run` of a tanh MLP in one compiled call
    (:mod:`~cartpole.agents.nn.fused_mlp`, the same bits), or None where that does not apply: another
    network, another dtype or device, or a pass autograd records."""
    if id(plan) not in _TANH_MLPS:
        if len(_TANH_MLPS) >= 64:  # a long process builds many models: keep the recent plans only
            _TANH_MLPS.clear()
        _TANH_MLPS[id(plan)] = (plan, tanh_mlp_layers(plan))
    names = _TANH_MLPS[id(plan)][1]
    if names is None:
        return None
    layers = [(params[weight], params[bias]) for weight, bias in names]
    tensors = [x, *(t for pair in layers for t in pair)]
    recorded = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
    if recorded or not fused_mlp.fusable(x, layers):
        return None
    if isinstance(plan[0], StandardizeObservations):
        x = plan[0].forward(x)
    out, kept = fused_mlp.forward(x, layers)
    if inputs is not None:
        inputs.extend(kept)
    return out


def flatten_images(x: torch.Tensor) -> torch.Tensor:
    """[S, B, C, H, W] -> [S, B, H * W * C]: each row's values in channels-last order, the order a
    seed's convolution leaves them in memory (no copy, and none in the backward pass). nn.Flatten
    orders them C, H, W: :func:`channels_last_columns` reorders the next layer's weight to match."""
    return x.permute(0, 1, 3, 4, 2).flatten(2)


def channels_last_columns(weight: torch.Tensor, image_shape: torch.Size) -> torch.Tensor:
    """``weight`` [S, out, C * H * W] (an nn.Linear's after nn.Flatten) with its columns in the
    order of :func:`flatten_images`, so that ``flatten_images(x) @ w^T`` is nn.Flatten's layer."""
    return weight.unflatten(2, image_shape).permute(0, 1, 3, 4, 2).flatten(2)


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


class StackedActorCritic(FlatParameters[ActorCritic]):
    """The actor-critics of S seeds (:class:`~cartpole.agents.nn.flat_parameters.FlatParameters`),
    each linear layer one fixed-order product for all seeds (:mod:`~cartpole.agents.nn.fixed_order`)."""

    def __init__(self, models: list[ActorCritic], device: torch.device):
        super().__init__(models, device)
        self.scaled: tuple[torch.Tensor, torch.Tensor] | None = None
        """The last pixels :meth:`scale_once` scaled, and their scaled values."""
        critic_trunk = "actor_trunk" if self.template.shared_trunk else "critic_trunk"
        self.actor_plan = forward_plan(self.template, "actor_trunk", "policy_head")
        self.critic_plan = forward_plan(self.template, critic_trunk, "value_head")
        self.one_trunk = self.template.is_image and self.actor_plan[:-1] == self.critic_plan[:-1]
        """Whether both heads sit on one image trunk (``shared_trunk`` on pixels): an update then runs it
        once. An MLP's shared trunk runs for each head, as its gradients by hand do, so that autograd's
        gradients are the same bits."""
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
        """``x`` [S, B, *obs_shape] through ``plan``: one product per linear layer for all seeds, one
        conv2d per seed and convolutional layer; pixels scaled by ``scale``. ``inputs``, when given,
        receives each linear layer's input, in order."""
        fused = run_fused(plan, params, x, inputs)
        if fused is not None:
            return fused
        image_shape: torch.Size | None = None
        """[C, H, W] of the images the last flatten took, until the linear layer after it."""
        for step in plan:
            if isinstance(step, tuple):
                weight, bias = params[step[0]], params[step[1]]
                if image_shape is not None:
                    weight, image_shape = channels_last_columns(weight, image_shape), None
                if inputs is not None:
                    inputs.append(x)
                x = stacked_linear(x, weight, bias)
            elif isinstance(step, ConvStep):
                x = stacked_conv2d(x, params[step.weight], params[step.bias], step.stride)
            elif isinstance(step, StandardizeObservations):
                x = step.forward(x)
            elif step is ScalePixels:
                x = scale(x)
            elif step is nn.Flatten:
                image_shape = x.shape[2:]
                x = flatten_images(x)
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
            return self.heads(self.rows_of_params(rows), observations)
        with torch.no_grad():  # the rows' parameters too: the gradients by hand need no graph
            params = self.rows_of_params(rows)
            inputs: tuple[list[torch.Tensor], list[torch.Tensor]] = ([], [])
            logits = self.run(self.actor_plan, params, observations, inputs=inputs[0]).requires_grad_()
            values = self.run(self.critic_plan, params, observations, inputs=inputs[1]).requires_grad_()
        self.update_pass = UpdatePass((logits, values), inputs, params, rows)
        return logits, values.squeeze(-1)

    def heads(
        self, params: dict[str, torch.Tensor], observations: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Logits [S, B, n_actions] and values [S, B] under ``params``, pixels scaled once; a shared
        trunk runs once for both heads."""
        if not self.one_trunk:
            logits = self.run(self.actor_plan, params, observations, self.scale_once)
            return logits, self.run(self.critic_plan, params, observations, self.scale_once).squeeze(-1)
        features = self.run(self.actor_plan[:-1], params, observations, self.scale_once)
        policy, value = self.actor_plan[-1], self.critic_plan[-1]
        assert isinstance(policy, tuple) and isinstance(value, tuple)  # forward_plan ends on a head
        (policy_weight, policy_bias), (value_weight, value_bias) = policy, value
        logits = stacked_linear(features, params[policy_weight], params[policy_bias])
        return logits, stacked_linear(features, params[value_weight], params[value_bias]).squeeze(-1)

    def rows_of_params(self, rows: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """The parameters of the seeds at ``rows`` (None: all)."""
        return self.params if rows is None else {name: p[rows] for name, p in self.params.items()}

    def backward(self, loss: torch.Tensor) -> None:
        """Add to ``grad`` the gradient of ``loss`` (a scalar) with respect to the parameters, through
        the last :meth:`forward_for_update`. For MLPs, autograd differentiates the loss only as far as
        the logits and values; the networks' gradients are then computed by hand, autograd's own
        products (:func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`)."""
        update, self.update_pass = self.update_pass, None
        if update is None:
            super().backward(loss)
            return
        self.backward_through_networks(update, torch.autograd.grad(loss, update.heads, allow_unused=True))

    def backward_from_heads(self, logits_grad: torch.Tensor, values_grad: torch.Tensor) -> None:
        """Add to ``grad`` the gradient of a loss whose gradients with respect to the logits [S, B,
        n_actions] and values [S, B] of the last :meth:`forward_for_update` (an MLP's) are
        ``logits_grad`` and ``values_grad``: the caller differentiated the loss itself (PPO's in
        closed form), the networks are differentiated by hand as in :meth:`backward`."""
        update, self.update_pass = self.update_pass, None
        if update is None:
            raise ValueError("backward_from_heads needs an MLP's forward_for_update first")
        self.backward_through_networks(update, (logits_grad, values_grad.unsqueeze(-1)))

    def backward_through_networks(
        self, update: UpdatePass, head_grads: tuple[torch.Tensor | None, ...] | list[torch.Tensor | None]
    ) -> None:
        """The networks' gradients by hand from their heads' gradients ``head_grads`` (the logits',
        the values'; None: that head has no term in the loss), added to ``grad``."""
        for hand, inputs, grad in zip(self.hand, update.inputs, head_grads, strict=True):
            if hand is None or grad is None:  # None: the loss has no value term (REINFORCE alone)
                continue
            layers = [(update.params[weight], update.params[bias]) for weight, bias in hand.layers]
            fused = hand.activation is tanh_gradient and fused_mlp.fusable(inputs[0], layers)
            if update.rows is None and fused:
                into = [(self.params[weight].grad, self.params[bias].grad) for weight, bias in hand.layers]
                fused_mlp.gradients(layers, inputs, grad, into)  # type: ignore[arg-type]
                continue
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
        """A frozen NumPy twin of the actors of ``rows`` (default: all), logits ``[S, B, n_actions]``
        (:class:`~cartpole.agents.nn.numpy_mlp.StackedNumpyMLP`: each seed's slice multiplied on its
        own; why NumPy: :mod:`cartpole.agents.nn.numpy_mlp`)."""
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


__all__ = ["HandBackward", "Layer", "StackedActorCritic", "forward_plan"]
