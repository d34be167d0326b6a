"""One convolutional layer for S networks at once, ``x [S, B, C, H, W] -> [S, B, C', H', W']``.

Each seed's images go through its own weights in its own ``conv2d`` call (a loop over the seed
axis), not one grouped convolution: a seed's call then has the same shapes, memory layout and
kernel whether it trains alone or beside other seeds, so its bits do not depend on its neighbours
(a population's seed N is the single run of seed N). The loop costs one call per seed and layer,
small beside a frame stack's convolution.

Each call takes its images channels-last (:func:`channels_last`: the channels of a pixel side by
side in memory, ``torch.channels_last`` for each seed): on a CPU, torch's convolutions of these few
channels run faster that way, the backward pass of the 8x8 stride-4 layer most
(``benchmarks/kernels.py --pixels`` times both layouts).
"""

from __future__ import annotations

import torch
from torch.nn import functional


def channels_last(x: torch.Tensor) -> torch.Tensor:
    """``x`` [S, B, C, H, W] laid out so that each seed's ``x[s]`` is ``torch.channels_last``
    (the same values; no copy when it already is). Cheapest on the uint8 pixels, before scaling:
    elementwise operations keep the layout."""
    return x.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)


def stacked_conv2d(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, stride: int) -> torch.Tensor:
    """``x`` [S, B, C, H, W] through each seed's ``weight`` [S, C', C, k, k] and ``bias`` [S, C']
    (no padding), as one tensor [S, B, C', H', W'] (one seed's output as it comes, channels-last)."""
    x = channels_last(x)
    outputs = [functional.conv2d(x[s], weight[s], bias[s], stride=stride) for s in range(x.shape[0])]
    return outputs[0].unsqueeze(0) if len(outputs) == 1 else torch.stack(outputs)


__all__ = ["channels_last", "stacked_conv2d"]
