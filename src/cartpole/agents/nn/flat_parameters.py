"""The networks of S seeds in one flat ``[S, P]`` tensor: what every population's stacked networks share.

Each parameter is a ``[S, *shape]`` view of the flat rows, and so is its gradient (of a second flat
tensor, into which autograd accumulates in place), so clipping and the optimizer step are a handful
of operations over ``[S, P]`` for the whole population. One seed's row comes out as an ordinary
module (``unstack``: a template overwritten) and goes back in (``load_row``); seeds that stop leave
(``keep``).

Why stacked: each layer then runs as one kernel for every seed
(:mod:`~cartpole.agents.nn.stacked_linear`), so S seeds train in one process for much less than S
separate runs (benchmarks/README.md#population). Batched products rather than ``torch.func.vmap``
over ``functional_call``: a batched product multiplies each seed's slice on its own, so a seed's bits
do not depend on the seeds beside it (tested), and on the CPU vmap's per-call batching rules cost
more than these small layers' arithmetic.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Generic, TypeVar

import numpy as np
import torch
from torch import nn

from cartpole.agents.nn.fixed_order import row_norms
from cartpole.agents.nn.numpy_mlp import Step
from cartpole.evaluation import BlockActor

Params = dict[str, torch.Tensor]
"""Parameters by their module name, each ``[S, *shape]``."""

Module = TypeVar("Module", bound=nn.Module)


def on_the_cpu() -> AbstractContextManager[object]:
    """Where the seeds' networks are built: on the CPU (each from its seed's CPU generator, as a single
    run builds it), whatever default device the user set; only then moved to the population's device.
    Entered only when the default is another device: ``torch.device`` as a context routes every
    factory call through a torch-function mode, whose first use imports sympy (a quarter second)."""
    return nullcontext() if torch.get_default_device().type == "cpu" else torch.device("cpu")


def to_device(tensor: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A CPU tensor copied to ``device`` without waiting for the device (no sync): only a read-back
    waits for it."""
    return tensor.to(device, non_blocking=True)


class FlatParameters(Generic[Module]):
    """The parameters of ``models`` (one per seed, all shaped like the first) in ``flat`` ``[S, P]``,
    each row padded with zeros to a multiple of ``align`` floats; ``params`` and their gradients are
    views of ``flat`` and ``grad``. ``size`` is one network's parameter count, padding excluded."""

    def __init__(self, models: list[Module], device: torch.device, align: int = 1):
        self.template = models[0]
        """A CPU module that :meth:`unstack` overwrites with one seed's weights."""
        self.shapes = {name: tuple(p.shape) for name, p in self.template.named_parameters()}
        self.offsets: dict[str, tuple[int, int]] = {}
        offset = 0
        for name, shape in self.shapes.items():
            self.offsets[name] = (offset, offset + math.prod(shape))
            offset += math.prod(shape)
        self.size = offset
        with torch.no_grad():
            flat = torch.zeros(len(models), -(-offset // align) * align, device="cpu")
            rows = [torch.cat([p.reshape(-1) for p in m.parameters()]) for m in models]
            flat[:, :offset] = torch.stack(rows)
        self.flat = flat.to(device)
        self.bind()

    def bind(self) -> None:
        """Make the parameter leaves (views of ``flat``) and their gradients (views of ``grad``)."""
        self.grad = torch.zeros_like(self.flat)
        self.params = self.views(self.flat)
        grads = self.views(self.grad)
        for name, leaf in self.params.items():
            leaf.requires_grad_(True)
            leaf.grad = grads[name]

    def views(self, flat: torch.Tensor) -> Params:
        """Each parameter of the rows of ``flat`` (any ``[S, P]`` tensor laid out as ``self.flat``)."""
        return {
            name: flat[:, start:end].view(-1, *self.shapes[name])
            for name, (start, end) in self.offsets.items()
        }

    def unstack(self, row: int, flat: torch.Tensor | None = None) -> Module:
        """Row ``row`` of ``flat`` (default: ``self.flat``) as the template module."""
        source = self.flat if flat is None else flat
        with torch.no_grad():
            for name, p in self.template.named_parameters():
                start, end = self.offsets[name]
                p.copy_(source[row, start:end].view_as(p))
        return self.template

    def row_state_dict(
        self, row: int, prefix: str, flat: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Row ``row`` of ``flat`` (default: ``self.flat``) as the template's state dict, each name
        prefixed with ``prefix`` (CPU copies)."""
        model = self.unstack(row, flat)
        return {prefix + k: v.detach().clone() for k, v in model.state_dict().items()}

    def load_row(self, row: int, tensors: dict[str, torch.Tensor], flat: torch.Tensor | None = None) -> None:
        """Put the parameters ``tensors`` (by module name) into row ``row`` of ``flat`` (default:
        ``self.flat``)."""
        target = self.flat if flat is None else flat
        with torch.no_grad():
            for name, (start, end) in self.offsets.items():
                target[row, start:end] = tensors[name].reshape(-1).to(target.device)

    def keep(self, rows: torch.Tensor) -> None:
        """Keep only the seeds at ``rows``."""
        self.flat = self.flat[rows.to(self.flat.device)]
        self.bind()

    def backward(self, loss: torch.Tensor) -> None:
        """Accumulate the gradient of ``loss`` (a scalar) into ``grad`` through autograd."""
        with warnings.catch_warnings():
            # The gradients are views of one [S, P] tensor on purpose (see the module docstring).
            warnings.filterwarnings("ignore", "grad and param do not obey the gradient layout")
            loss.backward()

    @torch.no_grad()
    def clip_grad_norms(self, max_norm: float) -> None:
        """Scale each seed's gradient down to a global norm of at most ``max_norm``, as
        ``torch.nn.utils.clip_grad_norm_`` computes it for one network (the norm in our fixed order:
        :func:`~cartpole.agents.nn.fixed_order.row_norms`)."""
        norms = row_norms(self.grad).unsqueeze(1)
        self.grad.mul_((max_norm / (norms + 1e-6)).clamp(max=1.0))

    def numpy_linear(self, weight: str, bias: str, rows: list[int] | None = None, copy: bool = True) -> Step:
        """The linear layer of parameters ``weight`` and ``bias`` of the networks at ``rows`` (None:
        all) as a NumPy step (:data:`~cartpole.agents.nn.numpy_mlp.Step`: weights ``[S, in, out]``,
        biases ``[S, 1, out]``): frozen copies, or with ``copy`` False (CPU, all rows) views of the
        parameters, which follow the updates made in place."""
        w, b = self.params[weight].detach(), self.params[bias].detach()
        if rows is not None:
            w, b = w[rows], b[rows]
        step = (w.cpu().numpy().transpose(0, 2, 1), b.cpu().numpy()[:, None, :])
        return (step[0].copy(), step[1].copy()) if copy else step

    def block_actor(
        self,
        rows: list[int],
        obs_shape: tuple[int, ...],
        scores: Callable[[Params, torch.Tensor], torch.Tensor],
    ) -> BlockActor:
        """The greedy actions of the networks of ``rows`` as one :data:`BlockActor` (block b: row
        ``rows[b]``'s episodes), through torch on a frozen copy of their weights; ``scores`` gives the
        per-action scores ``[S, B, n_actions]`` of stacked parameters and observations."""
        device = self.flat.device
        chosen = torch.tensor(rows, dtype=torch.int64, device=device)
        frozen = {name: p.detach()[chosen] for name, p in self.params.items()}

        @torch.no_grad()
        def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
            index = torch.as_tensor(np.asarray(blocks, dtype=np.int64), device=device)
            params = frozen if len(blocks) == len(rows) else {k: v[index] for k, v in frozen.items()}
            x = torch.as_tensor(np.asarray(observations)).to(device).reshape(len(blocks), -1, *obs_shape)
            return scores(params, x).argmax(dim=-1).reshape(-1).cpu().numpy()

        return act


__all__ = ["FlatParameters", "Params", "on_the_cpu", "to_device"]
