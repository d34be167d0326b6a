"""A saved agent's greedy policy as an ONNX graph, and the check that it acts as ours does.

The graph is the agent's :attr:`~cartpole.agents.registry.AgentSpec.scores_network` (its exact,
torch form: Q-values, action logits or linear scores, with the observations' standardization or
scaling inside) and their argmax, exported by ``torch.onnx.export`` (the ``torch.export`` based
exporter; it needs ``onnx`` and ``onnxscript``, the ``export`` extra). One input, two outputs:

- ``observations``: ``[N, *obs_shape]``, float32 (uint8 pixels for image observations);
- ``action``: ``[N]`` int64, the greedy action; ``scores``: ``[N, n_actions]`` float32.

Our policies act through fast approximations (NumPy twins with a rational ``tanh``:
:mod:`cartpole.agents.nn.fast_tanh`), so on an observation whose two best scores nearly tie the two
may pick different actions. :func:`check_parity` compares the actions onnxruntime picks with ours
wherever our two best scores differ by more than :data:`NEAR_TIE`, and counts the near-ties.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from cartpole.agents.registry import OpenedPolicy, spec_of
from cartpole.core.errors import InputError
from cartpole.core.version import __version__
from cartpole.envs import EnvInfo, make_vec_env
from cartpole.evaluation import Policy
from cartpole.runs.atomic import write_bytes_atomic

EXPORT_EXTRA = 'pip install -e ".[export]"'
"""How to install what ONNX export needs (onnx, onnxscript, onnxruntime)."""
EXPORT_MODULES = ("onnx", "onnxscript", "onnxruntime")
NEAR_TIE = 1e-4
"""Observations whose two best action scores differ by this or less are counted, not compared."""
PARITY_OBSERVATIONS = 10_000
"""Observations :func:`check_parity` compares on (``cartpole export`` plays them)."""
RANDOM_ACTION_SHARE = 0.25
"""The share of random actions among those that play the observations: states the greedy policy
alone would not visit, and episodes that end early."""
PLAYING_ENVS = 16
"""Envs :func:`play_observations` plays at once (the policy acts for all of them in one call)."""
CHUNK = 1_000
"""Observations run through a network at once (10,000 frame stacks as float32 are half a gigabyte)."""


class ExportError(InputError):
    """A saved agent cannot be exported: the export extra is missing, or the agent has no graph."""


def require_export_extra() -> None:
    """ExportError (one line naming the extra) unless onnx, onnxscript and onnxruntime import."""
    for name in EXPORT_MODULES:
        try:
            __import__(name)
        except ImportError as err:
            raise ExportError(
                f"ONNX export needs the export extra ({name} is not installed): {EXPORT_EXTRA}"
            ) from err


def input_dtype(env: EnvInfo) -> np.dtype[Any]:
    """The graph's observations: uint8 pixels for images, else float32."""
    return np.dtype(np.uint8) if env.is_image else np.dtype(np.float32)


class GreedyGraph(nn.Module):
    """What is exported: observations -> (the greedy action, the scores as float32)."""

    def __init__(self, scores: nn.Module):
        super().__init__()
        self.scores = scores

    def forward(self, observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        scores = self.scores(observations)
        return scores.argmax(dim=1), scores.to(torch.float32)


def scores_network(opened: OpenedPolicy) -> nn.Module:
    """The exact form of ``opened``'s greedy scores (its agent's ``scores_network``)."""
    spec = spec_of(opened.checkpoint)
    if spec.scores_network is None:
        raise ExportError(f"{spec.name} agents cannot be exported to ONNX yet")
    return spec.scores_network(opened.checkpoint)


def write_onnx(opened: OpenedPolicy, out: Path) -> Path:
    """Write ``opened``'s greedy policy to ``out`` as an ONNX graph (atomically), with the agent, the
    env, the run's seed, the checkpoint's step and our version in its metadata; ``out``."""
    require_export_extra()
    graph = GreedyGraph(scores_network(opened))
    example = torch.zeros((2, *opened.env.obs_shape), dtype=torch_dtype(input_dtype(opened.env)))
    with quiet_exporter():
        program = torch.onnx.export(
            graph,
            (example,),
            None,
            input_names=["observations"],
            output_names=["action", "scores"],
            dynamic_shapes={"observations": {0: torch.export.Dim("batch")}},
            dynamo=True,
            verbose=False,
        )
    assert program is not None
    model = program.model_proto
    checkpoint = opened.checkpoint
    metadata = {
        "agent": checkpoint.agent,
        "env_id": opened.env.label,
        "seed": str(checkpoint.meta.get("seed")),
        "step": str(checkpoint.meta.get("step")),
        "cartpole_version": __version__,
    }
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    write_bytes_atomic(out, model.SerializeToString(), durable=True)
    return out


@contextlib.contextmanager
def quiet_exporter() -> Iterator[None]:
    """The exporter's own chatter (a missing torchvision's operators, its deprecations) kept out
    of our output for the export's length; the loggers' levels are put back after."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)


def play_observations(
    policy: Policy, env: EnvInfo, count: int = PARITY_OBSERVATIONS, seed: int = 0
) -> np.ndarray:
    """``count`` observations of ``env`` (``[count, *obs_shape]``) met by ``policy`` playing it,
    one action in four random (:data:`RANDOM_ACTION_SHARE`), on our fast simulator where it has the
    env (CartPole and its pixels), else Gymnasium's."""
    num_envs = PLAYING_ENVS
    envs = make_vec_env(env, num_envs, simulator="fast")
    rng = np.random.default_rng(seed)
    rows: list[np.ndarray] = []
    try:
        observations, _ = envs.reset(seed=seed)
        while sum(len(r) for r in rows) < count:
            rows.append(np.array(observations))
            actions = np.asarray(policy.act(observations))
            random = rng.random(num_envs) < RANDOM_ACTION_SHARE
            actions = np.where(random, rng.integers(env.n_actions, size=num_envs), actions)
            observations, *_ = envs.step(actions)
    finally:
        envs.close()
    return np.concatenate(rows)[:count]


@dataclass(frozen=True)
class Parity:
    """How an ONNX graph's actions compare with our policy's on some observations."""

    observations: int
    near_ties: int
    """Observations whose two best scores differ by :data:`NEAR_TIE` or less: not compared."""
    differing: int
    """Compared observations on which the graph's action is not ours."""

    @property
    def compared(self) -> int:
        return self.observations - self.near_ties

    @property
    def equal(self) -> bool:
        return self.differing == 0

    def summary(self) -> str:
        """One line: on how many observations the actions are equal, and the near-ties."""
        same = "equal" if self.equal else f"DIFFER on {self.differing:,}, equal"
        return (
            f"onnxruntime's actions {same} on {self.compared - self.differing:,} of {self.compared:,} "
            f"observations ({self.near_ties:,} near-ties within {NEAR_TIE:g} not compared)"
        )


def check_parity(opened: OpenedPolicy, onnx_file: Path, observations: np.ndarray) -> Parity:
    """The graph in ``onnx_file`` run by onnxruntime against ``opened``'s policy on ``observations``:
    actions compared where our two best action scores (the exact ones, from the agent's
    ``scores_network``) differ by more than :data:`NEAR_TIE`."""
    require_export_extra()
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1  # a check, not a benchmark: no thread pool spinning
    session = onnxruntime.InferenceSession(str(onnx_file), options, providers=["CPUExecutionProvider"])
    observations = np.asarray(observations, dtype=input_dtype(opened.env))
    ours = np.concatenate([opened.policy.act(chunk) for chunk in chunks(observations)])
    theirs = np.concatenate([session.run(["action"], {"observations": c})[0] for c in chunks(observations)])
    near = score_gaps(opened, observations) <= NEAR_TIE
    differing = int(np.count_nonzero((ours != theirs) & ~near))
    return Parity(len(observations), int(np.count_nonzero(near)), differing)


def score_gaps(opened: OpenedPolicy, observations: np.ndarray) -> np.ndarray:
    """The gap between the two best exact action scores of each observation ``[N]``."""
    module = scores_network(opened)
    with torch.inference_mode():
        scores = np.concatenate(
            [module(torch.as_tensor(chunk)).to(torch.float64).numpy() for chunk in chunks(observations)]
        )
    best_two = np.sort(scores, axis=1)[:, -2:]
    return best_two[:, 1] - best_two[:, 0]


def chunks(observations: np.ndarray) -> list[np.ndarray]:
    return [observations[i : i + CHUNK] for i in range(0, len(observations), CHUNK)]


def torch_dtype(dtype: np.dtype[Any]) -> torch.dtype:
    return torch.from_numpy(np.zeros(0, dtype)).dtype


__all__ = [
    "EXPORT_EXTRA",
    "NEAR_TIE",
    "PARITY_OBSERVATIONS",
    "ExportError",
    "GreedyGraph",
    "Parity",
    "check_parity",
    "play_observations",
    "require_export_extra",
    "write_onnx",
]
