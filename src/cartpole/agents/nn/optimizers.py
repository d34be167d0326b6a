"""Adam and RMSprop for small nets: the update and state of ``torch.optim.Adam(fused=True)`` and of
``torch.optim.RMSprop``, without the import that constructing them costs.

Constructing *any* ``torch.optim`` optimizer imports ``torch._dynamo`` (its ``add_param_group`` is
wrapped to disable dynamo): seconds of CPU once per process, a large share of a whole CartPole
training run. Torch's functional optimizers, ``torch.optim.adam.adam`` and
``torch.optim.rmsprop.rmsprop`` (public: in their modules' ``__all__``), import nothing more and run
the same kernels over the same state tensors (``step``, ``exp_avg``, ``exp_avg_sq``, or ``step`` and
``square_avg``, per parameter, in the same dtypes and devices), so an update is bitwise that of the
``torch.optim`` class (tested), and the state loads into either.

The private kernel ``torch._fused_adam_`` is not called directly: skipping the functional API's checks
and per-call grouping of the tensors gives the same trajectories but saves far less than the 20% of
the CPU time to solve that a private call must save to stay (``benchmarks/time_to_solve.py --agents
dqn`` measures it; benchmarks/README.md has the figures).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

import torch
from torch.optim.adam import adam as functional_adam
from torch.optim.rmsprop import rmsprop as functional_rmsprop


class FunctionalOptimizer:
    """What FusedAdam and RMSprop share: the parameters, a learning rate, and per-parameter state in
    ``torch.optim``'s layout (a float32 ``step`` on the parameter's device, as ``torch.optim`` creates
    it, and the ``slots`` shaped like the parameter)."""

    slots: tuple[str, ...] = ()

    def __init__(self, parameters: Iterable[torch.Tensor], lr: float):
        self.parameters = list(parameters)
        self.lr = float(lr)
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.parameters]
        self.state: dict[str, list[torch.Tensor]] = {"step": self.steps}
        for name in self.slots:
            self.state[name] = [
                torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters
            ]

    def zero_grad(self) -> None:
        for parameter in self.parameters:  # as Optimizer.zero_grad(set_to_none=True)
            parameter.grad = None

    def with_gradients(self) -> tuple[list[torch.Tensor], list[torch.Tensor], dict[str, list[torch.Tensor]]]:
        """The parameters that have a gradient, their gradients and their state (as torch.optim, a
        step leaves the others and their state alone)."""
        kept = [i for i, p in enumerate(self.parameters) if p.grad is not None]
        params = [self.parameters[i] for i in kept]
        grads = [p.grad for p in params if p.grad is not None]
        return params, grads, {name: [values[i] for i in kept] for name, values in self.state.items()}

    def hyperparameters(self) -> dict[str, Any]:
        return {"lr": self.lr}

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Tensors keyed ``"{index}.{name}"`` (``torch.optim``'s state layout) and the hyperparameters."""
        tensors = {
            f"{index}.{name}": value
            for name, values in self.state.items()
            for index, value in enumerate(values)
        }
        return tensors, self.hyperparameters()

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None:
        """Restore what ``state_dict`` gave, or a ``torch.optim`` state flattened the same way (copies in
        place)."""
        for index in range(len(self.parameters)):
            present = f"{index}.step" in tensors  # torch.optim keeps no state for a never-updated parameter
            for name, values in self.state.items():
                if present:
                    values[index].copy_(tensors[f"{index}.{name}"])
                else:
                    values[index].zero_()


class FusedAdam(FunctionalOptimizer):
    """Adam over ``parameters`` with the state and update of ``torch.optim.Adam(fused=True)``."""

    slots = ("exp_avg", "exp_avg_sq")

    def __init__(
        self,
        parameters: Iterable[torch.Tensor],
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ):
        super().__init__(parameters, lr)
        self.betas, self.eps = (float(betas[0]), float(betas[1])), float(eps)
        self.exp_avgs, self.exp_avg_sqs = self.state["exp_avg"], self.state["exp_avg_sq"]

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient."""
        params, grads, state = self.with_gradients()
        if not params:
            return
        functional_adam(
            params, grads, state["exp_avg"], state["exp_avg_sq"], [], state["step"], fused=True,
            amsgrad=False, beta1=self.betas[0], beta2=self.betas[1], lr=self.lr, weight_decay=0.0,
            eps=self.eps, maximize=False,
        )  # fmt: skip

    def hyperparameters(self) -> dict[str, Any]:
        return {"lr": self.lr, "betas": list(self.betas), "eps": self.eps}


class RMSprop(FunctionalOptimizer):
    """RMSprop over ``parameters`` with the state and update of ``torch.optim.RMSprop`` (no momentum,
    not centred, no weight decay: the single-tensor loop it runs on CPU)."""

    slots = ("square_avg",)

    def __init__(self, parameters: Iterable[torch.Tensor], lr: float, alpha: float = 0.99, eps: float = 1e-8):
        super().__init__(parameters, lr)
        self.alpha, self.eps = float(alpha), float(eps)
        self.square_avgs = self.state["square_avg"]

    @torch.no_grad()
    def step(self) -> None:
        """One RMSprop update of every parameter that has a gradient."""
        params, grads, state = self.with_gradients()
        if not params:
            return
        functional_rmsprop(
            params, grads, state["square_avg"], [], [], state["step"], foreach=False, lr=self.lr,
            alpha=self.alpha, eps=self.eps, weight_decay=0.0, momentum=0.0, centered=False,
        )  # fmt: skip

    def hyperparameters(self) -> dict[str, Any]:
        return {"lr": self.lr, "alpha": self.alpha, "eps": self.eps}


class Optimizer(Protocol):
    """What the learners need of an optimizer (FusedAdam, RMSprop): a settable ``lr``, steps, state."""

    lr: float

    def zero_grad(self) -> None: ...

    def step(self) -> None: ...

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]: ...

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None: ...
