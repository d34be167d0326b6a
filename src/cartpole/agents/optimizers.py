"""Adam and RMSprop for small nets: the update and state of ``torch.optim.Adam(fused=True)`` and of
``torch.optim.RMSprop``, without the import that constructing them costs.

Constructing *any* ``torch.optim`` optimizer imports ``torch._dynamo`` (its ``add_param_group`` is
wrapped to disable dynamo): 1.5-2.7 s of CPU once per process, a fifth of a whole CartPole training
run. Torch's functional optimizers, ``torch.optim.adam.adam`` and ``torch.optim.rmsprop.rmsprop``
(public: in their modules' ``__all__``), import nothing more and run the same kernels over the same
state tensors (``step``, ``exp_avg``, ``exp_avg_sq``, or ``step`` and ``square_avg``, per parameter,
in the same dtypes and devices), so an update is bitwise that of the ``torch.optim`` class (tested),
and the state loads into either.

Calling the private kernel ``torch._fused_adam_`` directly, skipping the functional API's checks and
per-call grouping of the tensors, was measured and removed: it saved 2.5% of the CPU time to solve,
far from the 20% that would keep a private call (``benchmarks/time_to_solve.py --agents dqn --seeds
5``, 2026-11-23: 107.2 s summed over seeds 0-4 with it, 110.0 s without; the same trajectories, so the
same env steps, on every seed).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

import torch
from torch.optim.adam import adam as functional_adam
from torch.optim.rmsprop import rmsprop as functional_rmsprop


class FusedAdam:
    """Adam over ``parameters`` with the state and update of ``torch.optim.Adam(fused=True)``."""

    def __init__(
        self,
        parameters: Iterable[torch.Tensor],
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ):
        self.parameters = list(parameters)
        self.lr, self.betas, self.eps = float(lr), (float(betas[0]), float(betas[1])), float(eps)
        # As torch.optim.Adam creates them lazily for fused=True: a float32 step on the parameter's device.
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.parameters]
        self.exp_avgs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]
        self.exp_avg_sqs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]

    def zero_grad(self) -> None:
        for parameter in self.parameters:  # as Optimizer.zero_grad(set_to_none=True)
            parameter.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient (as torch.optim, the others and
        their state are left alone)."""
        kept = [i for i, p in enumerate(self.parameters) if p.grad is not None]
        if not kept:
            return
        params = [self.parameters[i] for i in kept]
        grads = [p.grad for p in params if p.grad is not None]
        functional_adam(
            params, grads, [self.exp_avgs[i] for i in kept], [self.exp_avg_sqs[i] for i in kept], [],
            [self.steps[i] for i in kept], fused=True, amsgrad=False, beta1=self.betas[0],
            beta2=self.betas[1], lr=self.lr, weight_decay=0.0, eps=self.eps, maximize=False,
        )  # fmt: skip

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Tensors keyed ``"{index}.step|exp_avg|exp_avg_sq"`` (``torch.optim``'s state layout) and the
        hyperparameters."""
        tensors: dict[str, torch.Tensor] = {}
        for index, (step, exp_avg, exp_avg_sq) in enumerate(
            zip(self.steps, self.exp_avgs, self.exp_avg_sqs, strict=True)
        ):
            tensors |= {f"{index}.step": step, f"{index}.exp_avg": exp_avg, f"{index}.exp_avg_sq": exp_avg_sq}
        return tensors, {"lr": self.lr, "betas": list(self.betas), "eps": self.eps}

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None:
        """Restore what ``state_dict`` gave, or a ``torch.optim.Adam`` state flattened the same way
        (copies in place)."""
        for index in range(len(self.parameters)):
            if f"{index}.step" not in tensors:  # torch.optim keeps no state for a never-updated parameter
                self.steps[index].zero_()
                self.exp_avgs[index].zero_()
                self.exp_avg_sqs[index].zero_()
                continue
            self.steps[index].copy_(tensors[f"{index}.step"])
            self.exp_avgs[index].copy_(tensors[f"{index}.exp_avg"])
            self.exp_avg_sqs[index].copy_(tensors[f"{index}.exp_avg_sq"])


class RMSprop:
    """RMSprop over ``parameters`` with the state and update of ``torch.optim.RMSprop`` (no momentum,
    not centred, no weight decay: the single-tensor loop it runs on CPU)."""

    def __init__(self, parameters: Iterable[torch.Tensor], lr: float, alpha: float = 0.99, eps: float = 1e-8):
        self.parameters = list(parameters)
        self.lr, self.alpha, self.eps = float(lr), float(alpha), float(eps)
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.parameters]
        self.square_avgs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]

    def zero_grad(self) -> None:
        for parameter in self.parameters:  # as Optimizer.zero_grad(set_to_none=True)
            parameter.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One RMSprop update of every parameter that has a gradient (the others are left alone)."""
        kept = [i for i, p in enumerate(self.parameters) if p.grad is not None]
        if not kept:
            return
        params = [self.parameters[i] for i in kept]
        grads = [p.grad for p in params if p.grad is not None]
        functional_rmsprop(
            params, grads, [self.square_avgs[i] for i in kept], [], [], [self.steps[i] for i in kept],
            foreach=False, lr=self.lr, alpha=self.alpha, eps=self.eps, weight_decay=0.0, momentum=0.0,
            centered=False,
        )  # fmt: skip

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Tensors keyed ``"{index}.step|square_avg"`` (``torch.optim``'s state layout) and the
        hyperparameters."""
        tensors: dict[str, torch.Tensor] = {}
        for index, (step, square_avg) in enumerate(zip(self.steps, self.square_avgs, strict=True)):
            tensors |= {f"{index}.step": step, f"{index}.square_avg": square_avg}
        return tensors, {"lr": self.lr, "alpha": self.alpha, "eps": self.eps}

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None:
        """Restore what ``state_dict`` gave, or a ``torch.optim.RMSprop`` state flattened the same way."""
        for index in range(len(self.parameters)):
            if f"{index}.step" not in tensors:  # torch.optim keeps no state for a never-updated parameter
                self.steps[index].zero_()
                self.square_avgs[index].zero_()
                continue
            self.steps[index].copy_(tensors[f"{index}.step"])
            self.square_avgs[index].copy_(tensors[f"{index}.square_avg"])


class Optimizer(Protocol):
    """What the learners need of an optimizer (FusedAdam, RMSprop): a settable ``lr``, steps, state."""

    lr: float

    def zero_grad(self) -> None: ...

    def step(self) -> None: ...

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]: ...

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None: ...
