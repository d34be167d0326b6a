"""One linear layer for S networks at once, ``x [S, B, in] -> x W^T + b [S, B, out]``, whose backward
multiplies in the orientation that is fast for thin matrices.

Forward is one ``torch.baddbmm`` (for one output, in the orientation whose bits do not depend on the
number of seeds, see :func:`linear_forward`). Autograd's own backward of it computes the weight's gradient as
``x^T @ grad`` (``[S, in, B] x [S, B, out]``); when ``out`` is 1 or 2 (a value or policy head) that
product has one or two columns, and a CPU ``bmm`` with so few columns runs several times slower
than the other orientation (``benchmarks/kernels.py`` times both for a population's 2-action
heads). Here the weight gradient is whichever
of ``grad^T @ x`` and ``(x^T @ grad)^T`` has the more columns. Every product is still one seed's
slice on its own, so a seed's gradient does not depend on the seeds beside it.

Every product goes through :func:`per_seed_bmm` or :func:`per_seed_baddbmm`, because torch hands a
batch of several matrices to MKL's batched product but a batch of one to MKL's single product, which
on more than one thread may split one matrix's sums between the threads and so add in another order:
a lone seed's first-layer weight gradient then differs in the last bits from the same seed's among
others (with 6 inputs on any CPU, with 4 on CPUs without AVX-512, i.e. under MKL's AVX2 and SSE4.2
code; ``tests/test_one_engine.py``). So a lone seed on several threads is multiplied as a batch of
two, itself twice (a stride-0 view, no copy), by the batched product, which gives a seed the same
bits whatever else the batch holds (and, on two threads, the bits of one). The twin costs the lone
seed's products again, only there: on one thread, the CLI's default, nothing changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import nn

from cartpole.agents.nn.fast_tanh import tanh

TORCH_ACTIVATIONS: dict[type[nn.Module], Callable[[torch.Tensor], torch.Tensor]] = {
    nn.ReLU: torch.relu,
    nn.Tanh: tanh,  # the populations' fast tanh (cartpole.agents.nn.fast_tanh)
    nn.ELU: nn.functional.elu,
    nn.GELU: nn.functional.gelu,
}
"""The hidden activations of the stacked networks, by the module type a single network uses (their
NumPy twins: :data:`~cartpole.agents.nn.numpy_mlp.NUMPY_ACTIVATIONS`)."""


def is_lone_cpu_seed(a: torch.Tensor) -> bool:
    """Whether ``a`` [S, n, k] holds one seed on the CPU: asked of a product on several threads,
    whether torch would give it to MKL's single product."""
    return a.shape[0] == 1 and a.device.type == "cpu"


def as_two_seeds(t: torch.Tensor) -> torch.Tensor:
    """``t`` [1, ...] seen as the same seed twice, [2, ...] (no copy)."""
    return t.expand(2, *t.shape[1:])


def per_seed_bmm(a: torch.Tensor, b: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``torch.bmm(a, b)``, ``[S, n, m]``, each seed's product by the kernel that multiplies it among
    other seeds (see the module docstring); written into ``out`` when given, but for a lone seed on
    several threads. (One thread, the CLI's default, is asked first: the cheapest test; and ``out``
    is passed only when given, since torch parses ``out=None`` more slowly.)"""
    if torch.get_num_threads() > 1 and is_lone_cpu_seed(a):
        return torch.bmm(as_two_seeds(a), as_two_seeds(b))[:1]
    return torch.bmm(a, b) if out is None else torch.bmm(a, b, out=out)


def per_seed_baddbmm(
    c: torch.Tensor, a: torch.Tensor, b: torch.Tensor, out: torch.Tensor | None = None
) -> torch.Tensor:
    """``torch.baddbmm(c, a, b)``, ``[S, n, m]``, as :func:`per_seed_bmm` (``c`` [S, 1 or n, m])."""
    if torch.get_num_threads() > 1 and is_lone_cpu_seed(a):
        return torch.baddbmm(as_two_seeds(c), as_two_seeds(a), as_two_seeds(b))[:1]
    return torch.baddbmm(c, a, b) if out is None else torch.baddbmm(c, a, b, out=out)


def weight_gradient(grad: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``grad^T @ x`` ``[S, out, in]`` for ``grad`` [S, B, out] and ``x`` [S, B, in], computed with the
    product's wider side as its columns."""
    if grad.shape[-1] <= x.shape[-1]:
        return per_seed_bmm(grad.transpose(1, 2), x)
    return per_seed_bmm(x.transpose(1, 2), grad).transpose(1, 2)


def input_gradient(grad: torch.Tensor, weight: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``grad @ weight`` ``[S, B, in]``, written into ``out`` when given (more than one output; see
    :func:`per_seed_bmm`); for one output (a value head) the outer product as a broadcast multiply,
    which ``bmm`` runs several times slower."""
    if grad.shape[-1] == 1:
        return grad * weight
    return per_seed_bmm(grad, weight, out=out)


def linear_forward(
    x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, out: torch.Tensor | None = None
) -> torch.Tensor:
    """``x @ weight^T + bias`` as one batched product, written into ``out`` ([S, B, out]) when given
    and the layer has more than one output (see :func:`per_seed_baddbmm`). With one output (a value
    head) it is taken as ``weight @ x^T``, ``[S, 1, B]``: ``x @ weight^T`` with a single column runs,
    for a lone seed, in another order than for many (a matrix-vector kernel), so its bits would
    depend on how many seeds share the batch; this orientation's do not (tested), and it is no
    slower."""
    if weight.shape[1] == 1:
        return per_seed_baddbmm(bias.unsqueeze(2), weight, x.transpose(1, 2)).transpose(1, 2)
    return per_seed_baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2), out=out)


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
            grad.sum(dim=1) if needs_bias else None,
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
        gradients.append((weight_gradient(grad, x), grad.sum(dim=1)))
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
    "per_seed_baddbmm",
    "per_seed_bmm",
    "relu_gradient",
    "relu_gradient_by_where",
    "relu_gradient_in_place",
    "stacked_linear",
    "weight_gradient",
]
