"""Adam for small nets: torch's fused Adam kernel, called without ``torch.optim``'s wrapper.

``torch.optim.Adam(fused=True)`` runs one kernel, ``torch._fused_adam_``, per step. For a net as small
as a CartPole Q-network two costs around that kernel dominate, and this class avoids both:

- ``Optimizer.step()``'s wrapper (hooks, profiler scopes, regrouping the tensors by device on every
  call) costs ~5x the kernel itself;
- constructing *any* ``torch.optim`` optimizer imports ``torch._dynamo`` (its ``add_param_group`` is
  wrapped to disable dynamo), ~1.8 s of CPU once per process: a fifth of a whole CartPole training run.

The state is exactly ``torch.optim.Adam``'s (``step``, ``exp_avg``, ``exp_avg_sq`` per parameter, in the
same dtypes and devices) and the update is the same kernel, so the result is bitwise that of
``torch.optim.Adam(fused=True).step()`` (tested). If a torch version refuses the direct call (the op
is private), a real ``torch.optim.Adam`` is built over the same state tensors and used from then on.
"""

from __future__ import annotations

from typing import Any

import torch


class FusedAdam:
    """Adam over ``parameters`` with the state and update of ``torch.optim.Adam(fused=True)``."""

    def __init__(
        self,
        parameters: list[torch.Tensor],
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
        self._torch_optimizer: torch.optim.Adam | None = None
        """Set once the direct kernel call was refused (or asked for): every step goes through it."""

    def zero_grad(self) -> None:
        for parameter in self.parameters:  # = Optimizer.zero_grad(), without its ~40 us of wrapper
            parameter.grad = None

    def step(self) -> None:
        """One Adam update of every parameter that has a gradient."""
        if self._torch_optimizer is not None:
            self._torch_optimizer.step()
            return
        grads = [p.grad for p in self.parameters]
        if all(g is not None for g in grads):
            params, steps = self.parameters, self.steps
            exp_avgs, exp_avg_sqs = self.exp_avgs, self.exp_avg_sqs
        else:  # as torch.optim: a parameter without a gradient is left alone, its state too
            kept = [i for i, g in enumerate(grads) if g is not None]
            params, grads = [self.parameters[i] for i in kept], [grads[i] for i in kept]
            exp_avgs, exp_avg_sqs = [self.exp_avgs[i] for i in kept], [self.exp_avg_sqs[i] for i in kept]
            steps = [self.steps[i] for i in kept]
            if not kept:
                return
        torch._foreach_add_(steps, 1)
        try:
            torch._fused_adam_(
                params, grads, exp_avgs, exp_avg_sqs, [], steps,  # type: ignore[arg-type]
                lr=self.lr, beta1=self.betas[0], beta2=self.betas[1], weight_decay=0.0, eps=self.eps,
                amsgrad=False, maximize=False,
            )  # fmt: skip
        except (AttributeError, TypeError, RuntimeError):
            # A private op: if this torch names or shapes it differently, use the public optimizer
            # from now on (the kernel refused before touching any tensor).
            torch._foreach_sub_(steps, 1)
            self.torch_optimizer().step()

    def torch_optimizer(self) -> torch.optim.Adam:
        """The equivalent ``torch.optim.Adam``, over these same state tensors; steps use it from now on."""
        if self._torch_optimizer is None:
            optimizer = torch.optim.Adam(
                self.parameters, lr=self.lr, betas=self.betas, eps=self.eps, fused=True
            )
            for parameter, step, exp_avg, exp_avg_sq in zip(
                self.parameters, self.steps, self.exp_avgs, self.exp_avg_sqs, strict=True
            ):
                optimizer.state[parameter] = {"step": step, "exp_avg": exp_avg, "exp_avg_sq": exp_avg_sq}
            self._torch_optimizer = optimizer
        return self._torch_optimizer

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
        """Restore what ``state_dict`` gave, or a ``torch.optim.Adam`` state flattened the same way.

        Copies in place, so a torch optimizer built over these tensors stays in step.
        """
        for index in range(len(self.parameters)):
            if f"{index}.step" not in tensors:  # torch.optim keeps no state for a never-updated parameter
                self.steps[index].zero_()
                self.exp_avgs[index].zero_()
                self.exp_avg_sqs[index].zero_()
                continue
            self.steps[index].copy_(tensors[f"{index}.step"])
            self.exp_avgs[index].copy_(tensors[f"{index}.exp_avg"])
            self.exp_avg_sqs[index].copy_(tensors[f"{index}.exp_avg_sq"])
