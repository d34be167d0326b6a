"""Per-seed statistics over the valid rows of a batch: ``x`` is ``[S, B]``, ``mask`` (float) is 1 on a
seed's valid rows and 0 on its padding, ``count`` [S] is how many valid rows each seed has.

Seeds hold different numbers of valid rows (their episodes end at different steps), but a batch has
one shape for all: each statistic reduces over a seed's own row only, in our fixed order
(:func:`~cartpole.agents.nn.fixed_order.seed_sums`), so a seed's value does not depend on its
neighbours' rows nor on the thread count.
"""

from __future__ import annotations

import torch

from cartpole.agents.nn.fixed_order import seed_sums


def masked_mean(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per-seed mean of ``x`` [S, B] over the rows where ``mask`` (float) is 1; [S]."""
    return seed_sums(x * mask) / count.clamp(min=1.0)


def masked_variance(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per-seed unbiased variance of ``x`` [S, B] over the masked rows (0 with fewer than 2)."""
    mean = masked_mean(x, mask, count).unsqueeze(1)
    variance = seed_sums(((x - mean) * mask).square()) / (count - 1.0).clamp(min=1.0)
    return torch.where(count > 1.0, variance, torch.zeros_like(variance))


def masked_normalize(x: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Per seed, ``(x - mean) / (std + 1e-8)`` over the masked rows (a single row is only centred)."""
    mean = masked_mean(x, mask, count).unsqueeze(1)
    centred = (x - mean) * mask
    variance = seed_sums(centred.square()) / (count - 1.0).clamp(min=1.0)
    std = torch.where(count > 1.0, variance.sqrt() + 1e-8, torch.ones_like(variance))
    return centred / std.unsqueeze(1)


def mean_entropy(
    log_probs: torch.Tensor, mask: torch.Tensor, count: torch.Tensor, differentiable: bool
) -> torch.Tensor:
    """Per-seed mean entropy [S] of the categorical distributions whose log-probabilities are
    ``log_probs`` [S, B, n_actions], over the masked rows; without a gradient unless
    ``differentiable`` (a loss that weighs it 0 needs none, and its backward pass would only add
    zeros)."""
    with torch.set_grad_enabled(differentiable and torch.is_grad_enabled()):
        return masked_mean(-(log_probs.exp() * log_probs).sum(dim=-1), mask, count)


def log_probs_and_entropy(
    logits: torch.Tensor, actions: torch.Tensor, mask: torch.Tensor, count: torch.Tensor, ent_coef: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The log-probabilities [S, B] of ``actions`` [S, B] under ``logits`` [S, B, n_actions], and
    each seed's mean entropy [S] over the masked rows (differentiable only where ``ent_coef`` weighs
    it in the loss: :func:`mean_entropy`)."""
    log_probs_all = torch.log_softmax(logits, dim=-1)
    log_probs = log_probs_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    return log_probs, mean_entropy(log_probs_all, mask, count, ent_coef != 0.0)


__all__ = ["log_probs_and_entropy", "masked_mean", "masked_normalize", "masked_variance", "mean_entropy"]
