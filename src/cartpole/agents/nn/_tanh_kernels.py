"""Numba kernels behind :mod:`cartpole.agents.nn.fast_tanh` (imported lazily, on first use).

``tanh`` is the odd rational minimax approximation ``x p(x^2) / q(x^2)`` of degrees 13/6 on
``[-7.9053, 7.9053]`` (beyond it float32 tanh is 1 to within the approximation's error), with the
coefficients of Eigen's ``generic_fast_tanh_float`` (also in XLA and ONNX Runtime's MLAS). Against
float64 ``tanh`` on a 2M-point grid over [-12, 12] plus every decade down to 1e-38: relative
error <= 2.7e-7 (2-4 float32 ulps) for normal numbers (below 4e-4 it returns x, as XLA does); NaN
stays NaN, the sign of zero is kept (tests/test_fast_tanh.py). The loops have no branch that LLVM
cannot turn into a select, so they vectorize; ``contract`` lets it fuse the polynomial's multiply-adds
(FMA), which saves time where the CPU has FMA (so the last bits differ between CPUs with and without
it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

_F32 = np.float32
_CLAMP = _F32(7.90531110763549805)
_A13, _A11, _A9 = _F32(-2.76076847742355e-16), _F32(2.00018790482477e-13), _F32(-8.60467152213735e-11)
_A7, _A5, _A3 = _F32(5.12229709037114e-08), _F32(1.48572235717979e-05), _F32(6.37261928875436e-04)
_A1 = _F32(4.89352455891786e-03)
_B6, _B4, _B2, _B0 = (
    _F32(1.19825839466702e-06),
    _F32(1.18534705686654e-04),
    _F32(2.26843463243900e-03),
    _F32(4.89352518554385e-03),
)
_ONE = _F32(1.0)
_SMALL = _F32(4e-4)

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"contract"}}


@njit(**_JIT, inline="always")
def tanh_f32(x: np.float32) -> np.float32:
    v = _CLAMP if x > _CLAMP else x  # comparisons with NaN are false: NaN passes through
    v = -_CLAMP if v < -_CLAMP else v
    v2 = v * v
    p = v2 * _A13 + _A11
    p = v2 * p + _A9
    p = v2 * p + _A7
    p = v2 * p + _A5
    p = v2 * p + _A3
    p = v2 * p + _A1
    q = v2 * _B6 + _B4
    q = v2 * q + _B2
    q = v2 * q + _B0
    # Below 4e-4, tanh(x) = x to within half an ulp (x^3 / 3 is 5e-8 of x), and x p / q would
    # lose digits to denormals near the smallest normal float32.
    return x if abs(x) < _SMALL else v * p / q


@njit(**_JIT)
def tanh_into(x: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """``out[i] = tanh(x[i])`` over flat float32 arrays that do not overlap."""
    for i in range(x.size):
        out[i] = tanh_f32(x[i])


@njit(**_JIT)
def tanh_in_place(x: NDArray[np.float32]) -> None:
    """``x[i] = tanh(x[i])`` over a flat float32 array. (With ``out`` the same array as ``x``,
    ``tanh_into`` would run LLVM's scalar fallback, several times slower: its vector loop needs arrays
    that do not overlap.)"""
    for i in range(x.size):
        x[i] = tanh_f32(x[i])


@njit(**_JIT)
def tanh_backward_into(y: NDArray[np.float32], grad: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """``out[i] = grad[i] * (1 - y[i]^2)``, the gradient through ``y = tanh(x)``, in one pass."""
    for i in range(y.size):
        out[i] = grad[i] * (_ONE - y[i] * y[i])
