"""One convolutional layer for S networks at once, ``x [S, B, C, H, W] -> [S, B, C', H', W']``.

Each seed's images go through its own weights in its own ``conv2d`` call (a loop over the seed
axis), not one grouped convolution: a seed's call then has the same shapes, memory layout and
kernel whether it trains alone or beside other seeds, so its bits do not depend on its neighbours
(a population's seed N is the single run of seed N). The loop costs one call per seed and layer,
small beside a frame stack's convolution.
"""

from __future__ import annotations

import torch
from torch.nn import functional


def stacked_conv2d(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, stride: int) -> torch.Tensor:
    """``x`` [S, B, C, H, W] through each seed's ``weight`` [S, C', C, k, k] and ``bias`` [S, C']
    (no padding), as one tensor [S, B, C', H', W']."""
    return torch.stack(
        [functional.conv2d(x[s], weight[s], bias[s], stride=stride) for s in range(x.shape[0])]
    )


__all__ = ["stacked_conv2d"]
