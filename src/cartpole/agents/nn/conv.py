"""The generic pieces of a convolutional trunk on pixel observations, shared by the agents that
learn from images: pixels scaled as darkness, the last frames' difference, and the feature count
of a stack of convolutional layers.

A layer is ``(filters, kernel size, stride)``, square kernels, no padding, each followed by a ReLU.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

ConvLayers = Sequence[Sequence[int]]
"""Convolutional layers as ``(filters, kernel size, stride)`` each."""

PIXEL_SCALE = 1.0 / 255.0
"""uint8 pixels to [0, 1]."""


def scale_pixels(observations: torch.Tensor) -> torch.Tensor:
    """Pixels (uint8, or floats of the same values) as float32 darkness in [0, 1]: ``1 - x / 255``.

    Inverted because Gymnasium draws the cart-pole dark on a white screen: as darkness the
    background is 0, so the convolutions' outputs are sparse and start from what moves (as Atari's
    dark backgrounds give DQN's networks), instead of a large constant from the white that hides the
    pole. The network's first step, so rollouts can keep observations as uint8.

    Computed as ``x * -scale + 1`` in place of a new tensor: bit for bit ``1 - x * scale`` (negation
    is exact, and ``1 + (-p)`` rounds as ``1 - p``), with one pass less over a batch of frame stacks
    and no temporary."""
    return torch.mul(observations.to(torch.float32), -PIXEL_SCALE).add_(1.0)


class ScalePixels(nn.Module):
    """:func:`scale_pixels` as a layer (no parameters)."""

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return scale_pixels(observations)


def last_frame_difference(frames: torch.Tensor) -> torch.Tensor:
    """The last frame minus the one before it, as one channel: ``[..., C, H, W] -> [..., 1, H, W]``
    (the "screen difference" state of the old PyTorch DQN tutorial: what moved, and which way)."""
    return frames[..., -1:, :, :] - frames[..., -2:-1, :, :]


class LastFrameDifference(nn.Module):
    """:func:`last_frame_difference` as a layer (no parameters)."""

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return last_frame_difference(frames)


def conv_output_shape(obs_shape: Sequence[int], layers: ConvLayers) -> tuple[int, int, int]:
    """``(channels, height, width)`` that ``layers`` make of one image ``[channels, height, width]``;
    ValueError when the image is too small for them."""
    channels, height, width = obs_shape
    for filters, kernel, stride in layers:
        height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1
        channels = filters
        if height < 1 or width < 1:
            raise ValueError(f"images {tuple(obs_shape)} are too small for the convolutional layers")
    return channels, height, width


def conv_output_size(obs_shape: Sequence[int], layers: ConvLayers) -> int:
    """Features ``layers`` make of one image ``[channels, height, width]`` (flattened)."""
    channels, height, width = conv_output_shape(obs_shape, layers)
    return channels * height * width


def conv_parameters(channels: int, layers: ConvLayers) -> int:
    """Weights and biases of ``layers`` on images of ``channels`` channels."""
    count = 0
    for filters, kernel, _ in layers:
        count += filters * channels * kernel * kernel + filters
        channels = filters
    return count


def conv_activations(obs_shape: Sequence[int], layers: ConvLayers) -> int:
    """Floats one image's pass through ``layers`` makes (every layer's output), for memory estimates."""
    total, shape = 0, tuple(obs_shape)
    for layer in layers:
        shape = conv_output_shape(shape, [layer])
        total += shape[0] * shape[1] * shape[2]
    return total


__all__ = [
    "PIXEL_SCALE",
    "ConvLayers",
    "LastFrameDifference",
    "ScalePixels",
    "conv_activations",
    "conv_output_shape",
    "conv_output_size",
    "conv_parameters",
    "last_frame_difference",
    "scale_pixels",
]
