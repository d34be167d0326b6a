"""RMSprop for small nets, as ``torch.optim.RMSprop`` computes it (no momentum, not centered).

Constructing any ``torch.optim`` optimizer imports ``torch._dynamo`` (~1.8 s of CPU once per process,
see :mod:`cartpole.agents.adam`); this is the same update in public ``torch._foreach`` ops, with the
same state (``step``, ``square_avg`` per parameter) and the same ``zero_grad``/``step``/``state_dict``
interface as :class:`~cartpole.agents.adam.FusedAdam`.
"""

from __future__ import annotations

from typing import Any

import torch


class RMSprop:
    """``square_avg = alpha * square_avg + (1 - alpha) * g^2``; ``p -= lr * g / (sqrt(square_avg) + eps)``."""

    def __init__(self, parameters: list[torch.Tensor], lr: float, alpha: float = 0.99, eps: float = 1e-8):
        self.parameters = list(parameters)
        self.lr, self.alpha, self.eps = float(lr), float(alpha), float(eps)
        self.steps = [torch.zeros((), dtype=torch.float32) for _ in self.parameters]
        self.square_avgs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]

    def zero_grad(self) -> None:
        for parameter in self.parameters:
            parameter.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient."""
        kept = [i for i, p in enumerate(self.parameters) if p.grad is not None]
        if not kept:
            return
        params = [self.parameters[i] for i in kept]
        grads = [p.grad for p in params]
        square_avgs = [self.square_avgs[i] for i in kept]
        torch._foreach_add_([self.steps[i] for i in kept], 1)
        torch._foreach_mul_(square_avgs, self.alpha)
        torch._foreach_addcmul_(square_avgs, grads, grads, value=1.0 - self.alpha)  # type: ignore[arg-type]
        denominators = torch._foreach_sqrt(square_avgs)
        torch._foreach_add_(denominators, self.eps)
        torch._foreach_addcdiv_(params, grads, denominators, value=-self.lr)  # type: ignore[arg-type]

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Tensors keyed ``"{index}.step|square_avg"`` (``torch.optim``'s state layout) and the settings."""
        tensors: dict[str, torch.Tensor] = {}
        for index, (step, square_avg) in enumerate(zip(self.steps, self.square_avgs, strict=True)):
            tensors |= {f"{index}.step": step, f"{index}.square_avg": square_avg}
        return tensors, {"lr": self.lr, "alpha": self.alpha, "eps": self.eps}

    def load_state_dict(self, tensors: dict[str, torch.Tensor]) -> None:
        for index in range(len(self.parameters)):
            self.steps[index].copy_(tensors[f"{index}.step"])
            self.square_avgs[index].copy_(tensors[f"{index}.square_avg"])
