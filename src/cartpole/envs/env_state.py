"""Save and restore the per-env state of a batched CartPole vector env, for exact resume.

Our fast simulator has public ``snapshot()``/``restore()``; Gymnasium's CartPoleVectorEnv keeps its
state in public fields (``state``, ``steps``, ``prev_done``, ``np_random``). Other vector envs cannot be
saved: a resumed learner then starts fresh episodes from a seed it derives deterministically.
"""

from __future__ import annotations

from typing import Any

import numpy as np

GYMNASIUM_CARTPOLE_FIELDS = ("state", "steps", "prev_done")
"""The public state of Gymnasium's CartPoleVectorEnv."""


def vector_env_state(envs: Any) -> dict[str, Any] | None:
    """Plain-data snapshot of a batched CartPole vector env, or None if we do not know its state."""
    base = envs.unwrapped
    if hasattr(base, "snapshot"):  # our fast simulator
        return {"snapshot": base.snapshot()}
    fields = {name: getattr(base, name, None) for name in GYMNASIUM_CARTPOLE_FIELDS}
    arrays_only = {k: v for k, v in fields.items() if isinstance(v, np.ndarray)}
    if len(arrays_only) != len(fields):
        return None
    arrays = {k: {"values": v.tolist(), "dtype": str(v.dtype)} for k, v in arrays_only.items()}
    return {"fields": arrays, "np_random": base.np_random.bit_generator.state}


def restore_vector_env_state(envs: Any, saved: dict[str, Any] | None) -> bool:
    """Put a vector env back where :func:`vector_env_state` found it; False if it cannot."""
    if not saved:
        return False
    base = envs.unwrapped
    if "snapshot" in saved:
        base.restore(saved["snapshot"])
        return True
    for name, value in saved["fields"].items():
        setattr(base, name, np.asarray(value["values"], dtype=value["dtype"]))
    base.np_random.bit_generator.state = saved["np_random"]
    return True
