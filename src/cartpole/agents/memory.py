"""How much memory an agent's settings would take, so impossible ones are refused before a run starts.

``--set buffer_size=1e12`` or ``--set hidden_sizes=100000,100000`` would otherwise fail deep inside
torch (or make the machine swap) after the run folder exists. The estimates are lower bounds: the
observation size is not known when a config is validated, so one observation and two actions are
assumed (every real env has at least that many).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence

FLOAT_BYTES = 4
"""float32, the dtype of replay rows, parameters and activations."""
REPLAY_EXTRA_COLUMNS = 3
"""A replay row is obs, next obs, action, reward and done: 2 x obs_dim + 3 floats."""
PARAMETER_COPIES = 5
"""Online and target network, gradients, and Adam's two moment estimates."""
ACTIVATION_COPIES = 4
"""Hidden activations kept per batch row: online forward (and its gradient), target and next-state."""


def physical_memory_bytes() -> int | None:
    """This machine's RAM, or None where the OS does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def mlp_parameters(sizes: Sequence[int]) -> int:
    """Weights and biases of an MLP whose layer widths are ``sizes`` (input first, output last)."""
    return sum(n_in * n_out + n_out for n_in, n_out in itertools.pairwise(sizes))


def dqn_memory_bytes(
    buffer_size: int, hidden_sizes: Sequence[int], batch_size: int, obs_dim: int = 1, n_actions: int = 2
) -> int:
    """A lower bound of the bytes DQN needs: replay memory, networks with their optimizer, one batch."""
    replay = buffer_size * (2 * obs_dim + REPLAY_EXTRA_COLUMNS) * FLOAT_BYTES
    parameters = mlp_parameters([obs_dim, *hidden_sizes, n_actions]) * PARAMETER_COPIES * FLOAT_BYTES
    activations = batch_size * sum(hidden_sizes) * ACTIVATION_COPIES * FLOAT_BYTES
    return replay + parameters + activations


def describe_bytes(count: float) -> str:
    """``1536`` -> ``"1.5 KiB"``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if count < 1024 or unit == "PiB":
            return f"{count:.0f} {unit}" if unit == "B" else f"{count:.1f} {unit}"
        count /= 1024
    raise AssertionError("unreachable")


def dqn_memory_problem(buffer_size: int, hidden_sizes: Sequence[int], batch_size: int) -> str | None:
    """Why these DQN settings cannot fit in this machine's memory, in one line; None if they can."""
    needed = dqn_memory_bytes(buffer_size, hidden_sizes, batch_size)
    available = physical_memory_bytes()
    if available is None or needed <= available:
        return None
    return (
        f"buffer_size={buffer_size} with hidden_sizes={','.join(map(str, hidden_sizes))} needs at least "
        f"{describe_bytes(needed)} of memory, more than this machine's {describe_bytes(available)}: "
        "use a smaller buffer_size or hidden_sizes"
    )
