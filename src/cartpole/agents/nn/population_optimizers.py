"""One optimizer step for every seed of a population: Adam and RMSprop over ``[S, P]`` parameters,
with a learning rate, a step count and a "sit this step out" flag per seed.

Each seed's row gets the update torch.optim.Adam's and RMSprop's formulas give one network (the
floats may differ in the last bits). On the CPU the update is one numba pass per row
(:mod:`cartpole.agents.nn._population_optimizer_kernels`, compiled on first use): torch's
elementwise form of Adam makes about ten passes over a population's ``[S, P]`` tensors, which no
longer fit the core's cache, and costs several times the one pass (benchmarks/README.md#kernels).
Other devices (and ``fused=False``) use the torch form.
"""

from __future__ import annotations

import functools
from types import ModuleType
from typing import Any, Protocol

import torch


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernels, compiled on first use (importing this module does not import numba)."""
    from cartpole.agents.nn import _population_optimizer_kernels

    return _population_optimizer_kernels


def use_kernels(fused: bool | None, *tensors: torch.Tensor) -> bool:
    """Whether the numba pass can update ``tensors`` in place: ``fused`` is not False and they are
    C-contiguous CPU tensors (the kernels compile for their dtypes)."""
    if fused is False:
        return False
    return all(t.device.type == "cpu" and t.is_contiguous() for t in tensors)


class PopulationAdam:
    """Adam (torch.optim.Adam's update) over ``[S, P]`` parameters with a learning rate, a step count
    and a "sit this step out" flag per seed."""

    def __init__(
        self,
        rows: int,
        size: int,
        eps: float,
        betas: tuple[float, float] = (0.9, 0.999),
        device: torch.device | str = "cpu",
        fused: bool | None = None,
    ):
        self.eps, self.betas = eps, betas
        self.fused = fused
        """None: the numba pass where it can run (CPU), torch's elementwise form elsewhere; False:
        always torch's."""
        self.exp_avg = torch.zeros(rows, size, device=device)
        self.exp_avg_sq = torch.zeros(rows, size, device=device)
        self.steps = torch.zeros(rows, 1, dtype=torch.float64, device=device)

    @torch.no_grad()
    def step(self, params: torch.Tensor, grads: torch.Tensor, lr: torch.Tensor, active: torch.Tensor) -> None:
        """One step of the seeds where ``active`` [S] is True; ``lr`` is [S]."""
        beta1, beta2 = self.betas
        state = (params, grads, self.exp_avg, self.exp_avg_sq, self.steps)
        if use_kernels(self.fused, *state):
            arrays = [t.numpy() for t in state]
            arrays[-1] = arrays[-1].reshape(-1)
            _kernels().adam_rows(
                *arrays, lr.double().cpu().numpy(), active.cpu().numpy(), beta1, beta2, self.eps
            )
            return
        every = bool(active.all())
        if not every:
            old = (params.clone(), self.exp_avg.clone(), self.exp_avg_sq.clone())
        self.steps += active.unsqueeze(1).to(self.steps.dtype)
        steps = self.steps.clamp(min=1.0)
        step_size = (lr.double().unsqueeze(1) / (1.0 - beta1**steps)).float()
        correction2 = (1.0 - beta2**steps).sqrt().float()
        self.exp_avg.lerp_(grads, 1.0 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grads, grads, value=1.0 - beta2)
        denom = (self.exp_avg_sq.sqrt() / correction2).add_(self.eps)
        params.addcdiv_(self.exp_avg * step_size, denom, value=-1.0)
        if not every:
            keep = active.unsqueeze(1)
            params.copy_(torch.where(keep, params, old[0]))
            self.exp_avg.copy_(torch.where(keep, self.exp_avg, old[1]))
            self.exp_avg_sq.copy_(torch.where(keep, self.exp_avg_sq, old[2]))

    def keep(self, rows: torch.Tensor) -> None:
        rows = rows.to(self.exp_avg.device)
        self.exp_avg, self.exp_avg_sq, self.steps = (
            self.exp_avg[rows],
            self.exp_avg_sq[rows],
            self.steps[rows],
        )

    def row_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {
            "optim.exp_avg": self.exp_avg[row].cpu().clone(),
            "optim.exp_avg_sq": self.exp_avg_sq[row].cpu().clone(),
        }
        return tensors, {"optim_steps": float(self.steps[row, 0])}

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.exp_avg[row] = tensors["optim.exp_avg"].to(self.exp_avg.device)
        self.exp_avg_sq[row] = tensors["optim.exp_avg_sq"].to(self.exp_avg.device)
        self.steps[row, 0] = float(data["optim_steps"])


class PopulationRMSprop:
    """RMSprop (torch.optim.RMSprop's update: no momentum, not centred) over ``[S, P]`` parameters
    with a learning rate and a "sit this step out" flag per seed."""

    def __init__(
        self,
        rows: int,
        size: int,
        alpha: float,
        eps: float,
        device: torch.device | str = "cpu",
        fused: bool | None = None,
    ):
        self.alpha, self.eps = alpha, eps
        self.fused = fused
        """As :attr:`PopulationAdam.fused`."""
        self.square_avg = torch.zeros(rows, size, device=device)

    @torch.no_grad()
    def step(self, params: torch.Tensor, grads: torch.Tensor, lr: torch.Tensor, active: torch.Tensor) -> None:
        """One step of the seeds where ``active`` [S] is True; ``lr`` is [S]."""
        if use_kernels(self.fused, params, grads, self.square_avg):
            arrays = [t.numpy() for t in (params, grads, self.square_avg)]
            _kernels().rmsprop_rows(
                *arrays, lr.double().cpu().numpy(), active.cpu().numpy(), self.alpha, self.eps
            )
            return
        keep = active.unsqueeze(1)
        square_avg = self.square_avg.mul(self.alpha).addcmul_(grads, grads, value=1.0 - self.alpha)
        update = grads / square_avg.sqrt().add_(self.eps) * lr.unsqueeze(1)
        params.sub_(torch.where(keep, update, torch.zeros_like(update)))
        self.square_avg = torch.where(keep, square_avg, self.square_avg)

    def keep(self, rows: torch.Tensor) -> None:
        self.square_avg = self.square_avg[rows.to(self.square_avg.device)]

    def row_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        return {"optim.square_avg": self.square_avg[row].cpu().clone()}, {}

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.square_avg[row] = tensors["optim.square_avg"].to(self.square_avg.device)


class PopulationOptimizer(Protocol):
    """One optimizer step for every seed of a population (see PopulationAdam, PopulationRMSprop)."""

    def step(
        self, params: torch.Tensor, grads: torch.Tensor, lr: torch.Tensor, active: torch.Tensor
    ) -> None: ...

    def keep(self, rows: torch.Tensor) -> None: ...

    def row_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]: ...

    def load_row_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None: ...


def population_optimizer(
    name: str, rows: int, size: int, device: torch.device, eps: float = 1e-8, rms_alpha: float = 0.99
) -> PopulationOptimizer:
    """Optimizer ``name`` ("adam" or "rmsprop") over ``[rows, size]`` parameters, with torch's
    defaults but for ``eps`` (and RMSprop's ``rms_alpha``)."""
    if name == "adam":
        return PopulationAdam(rows, size, eps, device=device)
    return PopulationRMSprop(rows, size, rms_alpha, eps, device)


__all__ = ["PopulationAdam", "PopulationOptimizer", "PopulationRMSprop", "population_optimizer"]
