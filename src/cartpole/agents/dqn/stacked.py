"""The Q-networks of S seeds as one: :class:`StackedQNetwork`, the online networks' parameters in one
flat ``[S, P]`` tensor (:class:`~cartpole.agents.nn.flat_parameters.FlatParameters`) and the target
networks in the rows above them, each linear layer one fixed-order product for all seeds
(:func:`~cartpole.agents.nn.stacked_linear.stacked_linear`), and a plain ReLU MLP's gradients by hand.

Why a seed's bits do not depend on the seeds beside it: every operation is either per seed (each
product and each sum over a seed's rows runs in an order of our own,
:mod:`~cartpole.agents.nn.fixed_order`: the layers, their gradients, the loss, the Q mean, the
gradient norm for clipping) or elementwise, and nothing is ever reduced over the seed axis (the
summed loss that is backpropagated has the gradient 1 or 0 per seed). One detail keeps the bits
equal where torch's elementwise kernels would otherwise betray a seed's position in the batch:
they run vectorized over the whole tensor and finish its last few elements with scalar code, whose
transcendental functions (tanh, elu, gelu, lerp's fused multiply-add) may round differently. So
every per-seed block is a multiple of :data:`ALIGN` elements (the flat parameters are padded,
minibatches and acting batches have a multiple of :data:`ALIGN` rows): no seed's elements ever
fall into the scalar tail.

Image networks (a convolutional trunk) run their convolutions one ``conv2d`` per seed on fresh
copies (:func:`~cartpole.agents.nn.stacked_conv.stacked_conv2d`, for the same reason) and take their
gradients from autograd. Why each form of a network, and the measurements behind them:
:mod:`cartpole.agents.nn`.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from cartpole.agents.dqn.q_network import QNetwork
from cartpole.agents.nn.conv import LastFrameDifference, last_frame_difference, scale_pixels
from cartpole.agents.nn.flat_parameters import FlatParameters
from cartpole.agents.nn.stacked_conv import channels_last, stacked_conv2d
from cartpole.agents.nn.stacked_linear import (
    linear_forward,
    mlp_gradients,
    relu_gradient_in_place,
    stacked_linear,
)

ALIGN = 32
"""Every seed's block of an elementwise operation is a multiple of this many float32 elements: two
AVX-512 vectors, the widest step of torch's vectorized CPU loops (see the module docstring)."""


def padded(n: int, multiple: int = ALIGN) -> int:
    """``n`` rounded up to a multiple of ``multiple``."""
    return -(-n // multiple) * multiple


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


__all__ = ["ALIGN", "StackedQNetwork", "padded"]
