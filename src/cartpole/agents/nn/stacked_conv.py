"""One convolutional layer for S networks at once, ``x [S, B, C, H, W] -> [S, B, C', H', W']`` (no
padding), with its gradients.

Each seed's images go through its own weights in its own ``conv2d`` call (a loop over the seed
axis), and its gradients come from its own calls of the same kernels (``torch.nn.grad``), each on
*fresh copies* of that seed's tensors: new allocations, so that a call sees the same shapes, strides
and memory alignment whether the seed trains alone or at any position beside any others. A CPU
library's convolution (oneDNN, or MKL's matrix product) may choose its kernel by the whole call,
the alignment of its operands included (MKL's own documentation names alignment and the thread count
as what can change its bits); a call that never depends on the population gives a seed the same bits
in any population. The bias's gradient is our own fixed-order sum
(:func:`~cartpole.agents.nn.fixed_order.row_sums`). Why not a convolution of our own, as the linear
layers have: an im2col and our product measured 3-4x torch's whole trunk on the pixel networks'
shapes (``benchmarks/kernels.py --pixels``), while the copies cost a few percent.

Each call takes its images channels-last (:func:`channels_last`: the channels of a pixel side by
side in memory, ``torch.channels_last`` for each seed): on a CPU, torch's convolutions of these few
channels run faster that way, the backward pass of the 8x8 stride-4 layer most
(``benchmarks/kernels.py --pixels`` times both layouts).
"""

from __future__ import annotations

from typing import Any

import torch
from torch.nn import functional
from torch.nn import grad as conv_grad

from cartpole.agents.nn.fixed_order import row_sums


def channels_last(x: torch.Tensor) -> torch.Tensor:
    """``x`` [S, B, C, H, W] laid out so that each seed's ``x[s]`` is ``torch.channels_last``
    (the same values; no copy when it already is). Cheapest on the uint8 pixels, before scaling:
    elementwise operations keep the layout."""
    return x.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)


def fresh(t: torch.Tensor) -> torch.Tensor:
    """A copy of ``t`` in a new allocation (channels-last for images [B, C, H, W]): the same bytes
    at the same alignment wherever ``t`` sat in a larger tensor."""
    layout = torch.channels_last if t.dim() == 4 else torch.contiguous_format
    return torch.empty_like(t, memory_format=layout).copy_(t)


def seed_conv(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, stride: int) -> torch.Tensor:
    """One seed's convolution ``x`` [B, C, H, W] on fresh copies of its operands."""
    return functional.conv2d(fresh(x), fresh(weight), fresh(bias), stride=stride)


class _StackedConv2d(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx: Any, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, stride: int
    ) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        ctx.stride = stride
        return torch.stack([seed_conv(x[s], weight[s], bias[s], stride) for s in range(x.shape[0])])

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, weight = ctx.saved_tensors
        needs_x, needs_weight, needs_bias = ctx.needs_input_grad[:3]
        x_grads, weight_grads, bias_grads = [], [], []
        for s in range(x.shape[0]):
            g = fresh(grad[s])
            if needs_x:
                x_grads.append(conv_grad.conv2d_input(x[s].shape, fresh(weight[s]), g, ctx.stride))
            if needs_weight:
                weight_grads.append(conv_grad.conv2d_weight(fresh(x[s]), weight[s].shape, g, ctx.stride))
            if needs_bias:  # channels-last: [B, H', W', C'] in memory, a row per output pixel
                bias_grads.append(row_sums(g.permute(0, 2, 3, 1).reshape(1, -1, g.shape[1]))[0])
        return (
            torch.stack(x_grads) if needs_x else None,
            torch.stack(weight_grads) if needs_weight else None,
            torch.stack(bias_grads) if needs_bias else None,
            None,
        )


def stacked_conv2d(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, stride: int) -> torch.Tensor:
    """``x`` [S, B, C, H, W] through each seed's ``weight`` [S, C', C, k, k] and ``bias`` [S, C']
    (no padding), as one tensor [S, B, C', H', W'] (one seed's output as it comes, channels-last)."""
    x = channels_last(x)
    if torch.is_grad_enabled() and (x.requires_grad or weight.requires_grad or bias.requires_grad):
        return _StackedConv2d.apply(x, weight, bias, stride)
    return torch.stack([seed_conv(x[s], weight[s], bias[s], stride) for s in range(x.shape[0])])


__all__ = ["channels_last", "stacked_conv2d"]
