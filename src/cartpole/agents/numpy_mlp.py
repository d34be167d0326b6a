"""A frozen numpy copy of a small torch MLP, for the greedy policies (CategoricalPolicy, QNetworkPolicy).

A greedy policy acts on a few observations at a time (one per step in the web app, one per env in an
evaluation), where torch's per-op overhead dominates: for DQN's 64x64 network one row costs ~150 us
through torch and ~20 us here, 100 rows ~200 us and ~95 us. Copying the weights also makes the policy
a snapshot that later training cannot change.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np
from torch import nn


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


def _tanh(x: np.ndarray) -> np.ndarray:
    return np.tanh(x, out=x)


def _elu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0, x, np.expm1(np.minimum(x, 0.0)))


def _gelu(x: np.ndarray) -> np.ndarray:
    """``nn.GELU()``'s exact form, ``x * Phi(x)``."""
    from scipy.special import erf

    return (0.5 * x * (1.0 + erf(x / math.sqrt(2.0)))).astype(x.dtype)


NUMPY_ACTIVATIONS: dict[type[nn.Module], Callable[[np.ndarray], np.ndarray]] = {
    nn.ReLU: _relu,
    nn.Tanh: _tanh,
    nn.ELU: _elu,
    nn.GELU: _gelu,
}


def is_dropout(layer: nn.Module) -> bool:
    """Dropout of any kind (torch's or a hand-written one): the identity when a policy acts."""
    return "dropout" in type(layer).__name__.lower()


class NumpyMLP:
    """Linear layers and activations, in order, run with numpy on float32 copies of the weights.

    Dropout layers are left out (a greedy policy acts in eval mode); any other module is refused.
    """

    def __init__(self, layers: Iterable[nn.Module]):
        self.plan: list[tuple[np.ndarray, np.ndarray] | Callable[[np.ndarray], np.ndarray]] = []
        for layer in layers:
            if isinstance(layer, nn.Linear):
                weight = layer.weight.detach().cpu().numpy().T.copy()
                self.plan.append((weight, layer.bias.detach().cpu().numpy().copy()))
            elif type(layer) in NUMPY_ACTIVATIONS:
                self.plan.append(NUMPY_ACTIVATIONS[type(layer)])
            elif not is_dropout(layer):
                raise TypeError(f"no numpy form for {type(layer).__name__}")

    def __call__(self, inputs: np.ndarray) -> np.ndarray:
        features = np.asarray(inputs, dtype=np.float32)
        for step in self.plan:
            if isinstance(step, tuple):  # a linear layer: x W^T + b
                features = features @ step[0]
                features += step[1]
            else:
                features = step(features)
        return features


__all__ = ["NUMPY_ACTIVATIONS", "NumpyMLP"]
