"""One linear layer for S networks at once, ``x [S, B, in] -> x W^T + b [S, B, out]``, and its
gradients, every product in the fixed order of :mod:`~cartpole.agents.nn.fixed_order`.

Forward, the input's gradient, the weight's gradient and the bias's gradient are each one call of
:func:`~cartpole.agents.nn.fixed_order.matmul` or :func:`~cartpole.agents.nn.fixed_order.row_sums`
for every seed: each output element of a seed is one sum over that seed's own rows in an order
written in our kernel, so a seed's bits do not depend on the seeds beside it, their number, its
position, the thread count or the BLAS of the machine (torch's ``bmm`` gave none of these on an
Intel CPU: :mod:`~cartpole.agents.nn.fixed_order`). The weight's gradient ``grad^T @ x`` is the same
sum whichever side the kernel vectorizes over; it takes the wider one as its columns, the faster.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import nn

from cartpole.agents.nn.fast_tanh import tanh
from cartpole.agents.nn.fixed_order import matmul, row_sums

TORCH_ACTIVATIONS: dict[type[nn.Module], Callable[[torch.Tensor], torch.Tensor]] = {
    nn.ReLU: torch.relu,
    nn.Tanh: tanh,  # the populations' fast tanh (cartpole.agents.nn.fast_tanh)
    nn.ELU: nn.functional.elu,
    nn.GELU: nn.functional.gelu,
}
"""The hidden activations of the stacked networks, by the module type a single network uses (their
NumPy twins: :data:`~cartpole.agents.nn.numpy_mlp.NUMPY_ACTIVATIONS`)."""


def weight_gradient(grad: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``grad^T @ x`` ``[S, out, in]`` for ``grad`` [S, B, out] and ``x`` [S, B, in], computed with the
    product's wider side as its columns."""
    if grad.shape[-1] <= x.shape[-1]:
        return matmul(grad.transpose(1, 2), x)
    return matmul(x.transpose(1, 2), grad).transpose(1, 2)


def input_gradient(grad: torch.Tensor, weight: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``grad @ weight`` ``[S, B, in]``, written into ``out`` when given (more than one output); for
    one output (a value head) the outer product as a broadcast multiply: one product per element,
    the same bits as the sum of one term."""
    if grad.shape[-1] == 1:
        return grad * weight
    return matmul(grad, weight, out=out)


def linear_forward(
    x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, out: torch.Tensor | None = None
) -> torch.Tensor:
    """``x @ weight^T + bias`` ``[S, B, out]`` for every seed in one call, written into ``out`` when
    given: each element its bias plus the products in input order."""
    return matmul(x, weight.transpose(1, 2), bias.unsqueeze(1), out=out)


class _StackedLinear(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        return linear_forward(x, weight, bias)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, weight = ctx.saved_tensors
        needs_x, needs_weight, needs_bias = ctx.needs_input_grad
        return (
            input_gradient(grad, weight) if needs_x else None,
            weight_gradient(grad, x) if needs_weight else None,
            row_sums(grad) if needs_bias else None,
        )


ActivationGradient = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""The gradient through an activation, from the gradient of its output and the output itself."""


def relu_gradient_by_where(grad: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The gradient through ``y = relu(x)``: ``grad`` where ``y > 0``, else 0 (public torch only)."""
    return torch.where(y > 0.0, grad, 0.0)


def threshold_backward_op() -> Callable[..., torch.Tensor] | None:
    """Autograd's own kernel for ReLU's backward, ``aten::threshold_backward`` (None in a torch
    without it)."""
    try:
        return torch.ops.aten.threshold_backward
    except (AttributeError, RuntimeError):
        return None


THRESHOLD_BACKWARD = threshold_backward_op()
THRESHOLD_BACKWARD_INTO: Callable[..., torch.Tensor] | None = getattr(THRESHOLD_BACKWARD, "grad_input", None)
"""The same kernel's variant that writes into a given tensor (``grad_input=``), None where missing."""


def relu_gradient(grad: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The gradient through ``y = relu(x)``: ``grad`` where ``y > 0``, else 0, by the kernel autograd
    runs for ReLU (one pass, several times faster than :func:`relu_gradient_by_where`'s compare and
    select: benchmarks/README.md#kernels), or by ``torch.where`` where that operator is missing. Both
    give the same bits."""
    if THRESHOLD_BACKWARD is None:
        return relu_gradient_by_where(grad, y)
    return THRESHOLD_BACKWARD(grad, y, 0.0)


def relu_gradient_in_place(grad: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """:func:`relu_gradient`, written over ``grad`` (by autograd's kernel; a new tensor by
    :func:`relu_gradient` where that kernel's ``grad_input`` variant is missing): for a gradient
    nothing else reads, one allocation fewer."""
    if THRESHOLD_BACKWARD_INTO is None:
        return relu_gradient(grad, y)
    return THRESHOLD_BACKWARD_INTO(grad, y, 0.0, grad_input=grad)


@torch.no_grad()
def mlp_gradients(
    layers: list[tuple[torch.Tensor, torch.Tensor]],
    inputs: list[torch.Tensor],
    grad: torch.Tensor,
    activation_gradient: ActivationGradient,
    buffer: Callable[[str, tuple[int, ...]], torch.Tensor] | None = None,
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The weight and bias gradients ``[S, out, in]``, ``[S, out]`` of each of an MLP's ``layers``
    (weights ``[S, out, in]`` and biases, in order, an activation between two layers) from ``grad``
    [S, B, out], the gradient of its output; ``inputs[i]`` was the input of layer ``i`` (so, for ``i >
    0``, the output of the activation before it).

    The products are the ones autograd's backward of :func:`stacked_linear` makes, one per seed's
    slice, so the gradients are autograd's bit for bit; done by hand, a small network's gradient step
    skips the autograd graph's bookkeeping, which costs more than its arithmetic
    (``benchmarks/kernels.py``). ``buffer`` (name, shape), when given, gives the tensors that the
    gradients with respect to the hidden activations are written into, kept between calls."""
    gradients = []
    for index in reversed(range(len(layers))):
        weight, _ = layers[index]
        x = inputs[index]
        gradients.append((weight_gradient(grad, x), row_sums(grad)))
        if index:  # through the layer, then the activation whose output is x
            out = None if buffer is None else buffer(f"gradient.{index}", tuple(x.shape))
            grad = activation_gradient(input_gradient(grad, weight.detach(), out), x)
    return gradients[::-1]


def stacked_linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``x @ weight^T + bias`` per seed: ``x`` [S, B, in], ``weight`` [S, out, in], ``bias`` [S, out]."""
    if torch.is_grad_enabled() and (x.requires_grad or weight.requires_grad or bias.requires_grad):
        return _StackedLinear.apply(x, weight, bias)
    return linear_forward(x, weight, bias)


__all__ = [
    "TORCH_ACTIVATIONS",
    "ActivationGradient",
    "input_gradient",
    "linear_forward",
    "mlp_gradients",
    "relu_gradient",
    "relu_gradient_by_where",
    "relu_gradient_in_place",
    "stacked_linear",
    "weight_gradient",
]
