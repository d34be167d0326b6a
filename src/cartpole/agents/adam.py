"""Adam for small nets: the update and state of ``torch.optim.Adam(fused=True)``, without its costs.

For a net as small as a CartPole Q-network two costs around Adam's one fused kernel dominate:

- constructing *any* ``torch.optim`` optimizer imports ``torch._dynamo`` (its ``add_param_group`` is
  wrapped to disable dynamo), ~1.8 s of CPU once per process;
- ``Optimizer.step()``'s wrapper (hooks, profiler scopes) costs several times the kernel itself.

The public path, used by default, avoids the first: torch's functional Adam,
``torch.optim.adam.adam(..., fused=True)`` (public, in ``torch.optim.adam.__all__``), which imports
nothing more, updates the same state tensors (``step``, ``exp_avg``, ``exp_avg_sq`` per parameter,
in the same dtypes and devices) and runs the same kernel, so the result is bitwise that of
``torch.optim.Adam(fused=True).step()`` (tested).

PRIVATE_PATH_NOTE
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

import torch
from torch.optim.adam import adam as functional_adam

PRIVATE_TORCH_VARIABLE = "CARTPOLE_PRIVATE_TORCH"
"""Set it to 0 to run the public path only (the benchmark's A/B switch)."""


def private_torch_enabled() -> bool:
    """False when the environment says ``CARTPOLE_PRIVATE_TORCH=0``: the one place the switch is read."""
    return os.environ.get(PRIVATE_TORCH_VARIABLE, "1").strip() != "0"


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
        self.use_private_kernel = private_torch_enabled()
        """Call the fused kernel directly; turned off for good the first time torch refuses the call."""

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
        exp_avgs, exp_avg_sqs = [self.exp_avgs[i] for i in kept], [self.exp_avg_sqs[i] for i in kept]
        steps = [self.steps[i] for i in kept]
        if self.use_private_kernel:
            if fused_adam_kernel(params, grads, exp_avgs, exp_avg_sqs, steps, self.lr, self.betas, self.eps):
                return
            self.use_private_kernel = False
        functional_adam(
            params, grads, exp_avgs, exp_avg_sqs, [], steps, fused=True,
            amsgrad=False, beta1=self.betas[0], beta2=self.betas[1], lr=self.lr, weight_decay=0.0,
            eps=self.eps, maximize=False,
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


# ----------------------------------------------------------------------------------------------
# The private path
# ----------------------------------------------------------------------------------------------


def fused_adam_kernel(
    params: list[torch.Tensor],
    grads: list[torch.Tensor],
    exp_avgs: list[torch.Tensor],
    exp_avg_sqs: list[torch.Tensor],
    steps: list[torch.Tensor],
    lr: float,
    betas: tuple[float, float],
    eps: float,
) -> bool:
    """The step the public path takes, as one direct call of the private op ``torch._fused_adam_``
    (what ``torch.optim.adam.adam(fused=True)`` calls after its checks and its per-call grouping of
    the tensors by device and dtype). False, with nothing changed, if this torch refuses the call.

    PRIVATE_GAIN_NOTE
    """
    kernel = getattr(torch, "_fused_adam_", None)
    if kernel is None:
        return False
    for step in steps:
        step += 1
    try:
        kernel(
            params, grads, exp_avgs, exp_avg_sqs, [], steps,
            lr=lr, beta1=betas[0], beta2=betas[1], weight_decay=0.0, eps=eps, amsgrad=False, maximize=False,
        )  # fmt: skip
    except (TypeError, RuntimeError):  # named or shaped differently in this torch: refused before any update
        for step in steps:
            step -= 1
        return False
    return True
