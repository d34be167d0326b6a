"""Proximal Policy Optimization (PPO, clipped surrogate) for a batch of seeds, read top to bottom.

1. :class:`PPOConfig`: every setting, with a one-line docstring each (presets in ``presets/ppo.toml``).
2. The loss of one minibatch, each seed's on its own rows of ``[S, B]`` tensors:
   :func:`clipped_surrogate_loss` (the probability ratio clipped to ``1 +- clip_range``),
   :func:`clipped_value_loss`, and the entropy term (:meth:`PopulationPPO.minibatch_loss`); and the
   same loss differentiated in closed form (:func:`ppo_loss_gradients`), what an MLP's update uses
   (without value clipping): fewer operations than autograd's backward pass, the same gradients to
   within rounding.
3. The update (:meth:`PopulationPPO.update`): ``n_epochs`` passes over each seed's rollout in
   shuffled minibatches, each one gradient step with the gradient norm clipped, with an optional
   early stop once a seed's approximate KL passes ``target_kl``.
4. One ``learn()`` (:meth:`PopulationPPO.learn`): a rollout of ``n_steps`` batched steps from
   ``num_envs`` envs per seed, GAE advantages (bootstrapping at truncation, never at termination:
   :mod:`cartpole.agents.actor_critic.rollout`), then the update.
5. The agent's spec, as the registry finds it.

A single run is a population of one. What every actor-critic shares (the stacked networks, the envs,
the optimizer, checkpoints) is :class:`~cartpole.agents.actor_critic.population.PopulationActorCritic`.
The greedy policy (``act`` = argmax of the action probabilities) is
:class:`~cartpole.agents.actor_critic.network.CategoricalPolicy`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig
from cartpole.agents.actor_critic.population import (
    PopulationActorCritic,
    actor_critic_bytes_per_seed,
    actor_critic_spec,
)
from cartpole.agents.actor_critic.rollout import Rollout
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.fixed_order import is_fixed_order, seed_sums
from cartpole.agents.nn.masked import log_probs_and_entropy, masked_mean, masked_normalize
from cartpole.agents.nn.schedules import SCHEDULES, schedule_value
from cartpole.core.config import require
from cartpole.envs import EnvInfo

# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------


@dataclass
class PPOConfig(PolicyGradientConfig):
    """Hyperparameters of PPO. `cartpole train ppo` uses the ``default`` preset (presets/ppo.toml), not
    these field defaults."""

    n_steps: int = 32
    """Batched steps per rollout (a rollout holds n_steps x num_envs rows)."""
    gae_lambda: float = 0.8
    """GAE lambda: 0 = one-step TD advantages, 1 = Monte-Carlo returns minus the value."""
    n_epochs: int = 10
    """Passes over each rollout."""
    minibatch_size: int = 64
    """Rows per gradient step (the last minibatch of a pass may be smaller)."""
    clip_range: float = 0.2
    """Clip the probability ratio to [1 - clip_range, 1 + clip_range] (start value if scheduled)."""
    clip_schedule: str = "constant"
    """constant, or linear: the clip range decays to 0 at schedule_steps env steps."""
    clip_range_vf: float | None = None
    """Clip the value prediction to old value +- this (none: no value clipping)."""
    target_kl: float | None = None
    """Stop the update's remaining epochs once a minibatch's approximate KL exceeds this (none: never)."""
    normalize_advantages: bool = True
    """Standardize the advantages within each minibatch."""
    adam_eps: float = 1e-5
    """Adam's epsilon."""

    def validate(self) -> None:
        super().validate()
        require(self.n_steps >= 1, f"n_steps must be >= 1, got {self.n_steps}")
        require(0.0 <= self.gae_lambda <= 1.0, f"gae_lambda must be in [0, 1], got {self.gae_lambda}")
        require(self.n_epochs >= 1, f"n_epochs must be >= 1, got {self.n_epochs}")
        require(self.minibatch_size >= 1, f"minibatch_size must be >= 1, got {self.minibatch_size}")
        require(self.clip_range > 0, f"clip_range must be > 0, got {self.clip_range}")
        require(self.clip_schedule in SCHEDULES, f"clip_schedule must be one of {', '.join(SCHEDULES)}")
        require(self.clip_range_vf is None or self.clip_range_vf > 0, "clip_range_vf must be > 0 or none")
        require(self.target_kl is None or self.target_kl > 0, "target_kl must be > 0 or none")
        require(self.adam_eps > 0, f"adam_eps must be > 0, got {self.adam_eps}")


# ----------------------------------------------------------------------------------------------
# 2. The loss
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PPOBatch:
    """A minibatch: each seed's rows of its rollout, ``[S, B, ...]``."""

    observations: torch.Tensor
    actions: torch.Tensor
    old_log_probs: torch.Tensor
    old_values: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor

    @classmethod
    def of(cls, rollout: Rollout, index: torch.Tensor | None) -> PPOBatch:
        """Each seed's rows ``index`` [S, B] of ``rollout`` (None: every row)."""

        def take(x: torch.Tensor) -> torch.Tensor:
            if index is None:
                return x
            if x.dim() == 2:
                return x.gather(1, index)
            rows = index.view(*index.shape, *[1] * (x.dim() - 2))  # [S, B, 1, ...]: every column
            return x.gather(1, rows.expand(-1, -1, *x.shape[2:]))

        return cls(
            take(rollout.observations), take(rollout.actions), take(rollout.log_probs), take(rollout.values),
            take(rollout.advantages), take(rollout.returns),
        )  # fmt: skip


def clipped_surrogate_loss(
    ratio: torch.Tensor, advantages: torch.Tensor, clip: torch.Tensor, mask: torch.Tensor, count: torch.Tensor
) -> torch.Tensor:
    """PPO's policy loss per seed [S]: the masked mean over rows of ``max(-A r, -A clip(r, 1 - c,
    1 + c))``, ``ratio`` r and ``advantages`` A [S, B], ``clip`` c [S, 1] (each seed's own)."""
    clipped_ratio = torch.minimum(torch.maximum(ratio, 1.0 - clip), 1.0 + clip)
    return masked_mean(torch.max(-advantages * ratio, -advantages * clipped_ratio), mask, count)


def clipped_value_loss(
    values: torch.Tensor,
    old_values: torch.Tensor,
    returns: torch.Tensor,
    clip_range_vf: float | None,
    mask: torch.Tensor,
    count: torch.Tensor,
) -> torch.Tensor:
    """Half the masked mean squared error of ``values`` against ``returns`` per seed [S]; with
    ``clip_range_vf``, each row's error is the larger of the plain one and that of the value clipped
    to ``old_values +- clip_range_vf`` (as SB3 and CleanRL clip)."""
    squared = (values - returns).square()
    if clip_range_vf is not None:
        clipped_values = old_values + (values - old_values).clamp(-clip_range_vf, clip_range_vf)
        squared = torch.max(squared, (clipped_values - returns).square())
    return 0.5 * masked_mean(squared, mask, count)


def ppo_loss_gradients(
    logits: torch.Tensor,
    values: torch.Tensor,
    batch: PPOBatch,
    clip: torch.Tensor,
    mask: torch.Tensor,
    count: torch.Tensor,
    ent_coef: float,
    vf_coef: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PPO's loss per seed (without value clipping) differentiated in closed form: the gradients of
    each seed's ``policy_loss - ent_coef * entropy + vf_coef * value_loss`` with respect to its
    ``logits`` [S, B, n_actions] and ``values`` [S, B], and the metrics [S, 5] (:data:`ROW_METRICS`).

    What autograd would compute through :func:`clipped_surrogate_loss`, the entropy and
    :func:`clipped_value_loss`, in fewer and fused operations (an update of small networks is bound
    by the count of operations): with ``r`` the ratio, the row's term ``max(-A r, -A clip(r))`` has
    the derivative ``-A`` in ``r`` where its unclipped side is the larger (half of it on a tie, as
    autograd splits a tie), ``-A`` times whether ``r`` lies inside the clip range where the clipped
    side is; ``d r / d logits = r (onehot(action) - softmax)``; the mean entropy's ``-p (log p +
    H)``; the value loss's ``values - returns``; each over the seed's masked rows. Equal to
    autograd's gradients to within float32 rounding (tests/test_population.py).

    On the CPU, one compiled pass computes them (:func:`ppo_loss_gradients_compiled`); elsewhere
    (CUDA) these tensor operations do."""
    if is_fixed_order(logits):
        return ppo_loss_gradients_compiled(logits, values, batch, clip, mask, count, ent_coef, vf_coef)
    log_probs_all = torch.log_softmax(logits, dim=-1)
    probs = log_probs_all.exp()
    log_ratio = log_probs_all.gather(-1, batch.actions.unsqueeze(-1)).squeeze(-1) - batch.old_log_probs
    ratio = log_ratio.exp()
    clipped_ratio = torch.minimum(torch.maximum(ratio, 1.0 - clip), 1.0 + clip)
    unclipped_term, clipped_term = -batch.advantages * ratio, -batch.advantages * clipped_ratio
    row_entropy = -(probs * log_probs_all).sum(dim=-1)
    error = values - batch.returns
    rows = torch.stack(
        [
            torch.max(unclipped_term, clipped_term),
            0.5 * error.square(),
            row_entropy,
            (ratio - 1.0) - log_ratio,
            ((ratio - 1.0).abs() > clip).float(),
        ],
        dim=-1,
    )  # [S, B, 5]: the rows of each metric, whose masked means are the metrics (one reduction)
    divisor = count.clamp(min=1.0).unsqueeze(1)
    metrics = seed_sums(rows * mask.unsqueeze(-1)) / divisor
    per_row = mask / divisor  # d masked_mean / d row
    unclipped_side = (unclipped_term > clipped_term).float() + 0.5 * (unclipped_term == clipped_term).float()
    inside = ((ratio > 1.0 - clip) & (ratio < 1.0 + clip)).float()
    d_ratio = -batch.advantages * (unclipped_side + (1.0 - unclipped_side) * inside)
    one_hot = torch.zeros_like(logits).scatter_(-1, batch.actions.unsqueeze(-1), 1.0)
    logits_grad = (d_ratio * ratio * per_row).unsqueeze(-1) * (one_hot - probs)
    if ent_coef != 0.0:
        logits_grad += (
            (ent_coef * per_row).unsqueeze(-1) * probs * (log_probs_all + row_entropy.unsqueeze(-1))
        )
    return logits_grad, vf_coef * per_row * error, metrics


def ppo_loss_gradients_compiled(
    logits: torch.Tensor,
    values: torch.Tensor,
    batch: PPOBatch,
    clip: torch.Tensor,
    mask: torch.Tensor,
    count: torch.Tensor,
    ent_coef: float,
    vf_coef: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`ppo_loss_gradients` on the CPU, in one compiled pass over each seed's rows
    (:mod:`._ppo_loss_kernels`: the same formulas, a seed's bits its own)."""
    from cartpole.agents.actor_critic import _ppo_loss_kernels

    seeds, rows, n_actions = logits.shape
    logits_grad = np.empty((seeds, rows, n_actions), dtype=np.float32)
    values_grad = np.empty((seeds, rows), dtype=np.float32)
    metrics = np.empty((seeds, len(ROW_METRICS)), dtype=np.float32)

    def array(t: torch.Tensor, dtype: type = np.float32) -> np.ndarray:
        return np.ascontiguousarray(t.detach().numpy(), dtype=dtype)

    _ppo_loss_kernels.ppo_loss_gradients_into(
        array(logits), array(values), array(batch.actions, np.int64), array(batch.old_log_probs),
        array(batch.advantages), array(batch.returns), array(mask), array(count.reshape(seeds)),
        array(clip.reshape(seeds)), float(ent_coef), float(vf_coef), logits_grad, values_grad, metrics,
    )  # fmt: skip
    return torch.from_numpy(logits_grad), torch.from_numpy(values_grad), torch.from_numpy(metrics)


ROW_METRICS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")
"""What each minibatch reports per seed; an update reports their means over its gradient steps."""


# ----------------------------------------------------------------------------------------------
# 3. and 4. The update, and one learn()
# ----------------------------------------------------------------------------------------------


class PopulationPPO(PopulationActorCritic):
    """PPO for seeds ``seeds``, all with ``config``: one ``learn()`` = a rollout and an update each."""

    config: PPOConfig
    closed_form = True
    """Set False to differentiate the loss with autograd even where the closed form applies
    (:attr:`differentiates_in_closed_form`)."""

    def __init__(self, config: PPOConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device, eps=config.adam_eps)

    def minibatch_loss(
        self, batch: PPOBatch, mask: torch.Tensor, count: torch.Tensor, clip: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per-seed PPO loss [S], metrics [S, 5] (detached) and approximate KL [S] of one minibatch
        (:meth:`minibatch`)."""
        config = self.config
        logits, values = self.model.forward_for_update(batch.observations)
        log_probs, entropy = log_probs_and_entropy(logits, batch.actions, mask, count, config.ent_coef)
        log_ratio = log_probs - batch.old_log_probs
        ratio = log_ratio.exp()
        policy_loss = clipped_surrogate_loss(ratio, batch.advantages, clip, mask, count)
        value_loss = clipped_value_loss(
            values, batch.old_values, batch.returns, config.clip_range_vf, mask, count
        )
        loss = policy_loss - config.ent_coef * entropy + config.vf_coef * value_loss
        with torch.no_grad():
            approx_kl = masked_mean((ratio - 1.0) - log_ratio, mask, count)
            clip_fraction = masked_mean(((ratio - 1.0).abs() > clip).float(), mask, count)
            row_metrics = torch.stack([policy_loss, value_loss, entropy, approx_kl, clip_fraction], dim=1)
        return loss, row_metrics.detach(), approx_kl

    def minibatch(
        self,
        rollout: Rollout,
        index: torch.Tensor | None,
        mask: torch.Tensor,
        count: torch.Tensor,
        normalize: bool,
    ) -> PPOBatch:
        """Each seed's rows ``index`` [S, B] of ``rollout`` (None: every row), their advantages
        normalized with ``normalize``."""
        batch = PPOBatch.of(rollout, index)
        if not normalize:
            return batch
        return dataclasses.replace(batch, advantages=masked_normalize(batch.advantages, mask, count))

    @property
    def differentiates_in_closed_form(self) -> bool:
        """Whether an update takes its loss's gradients from :func:`ppo_loss_gradients` (MLPs
        differentiated by hand, no value clipping) rather than from autograd."""
        return self.closed_form and self.model.by_hand and self.config.clip_range_vf is None

    def minibatch_gradients(
        self, batch: PPOBatch, mask: torch.Tensor, count: torch.Tensor, clip: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`minibatch_loss` differentiated in closed form (:func:`ppo_loss_gradients`): the
        gradients of each seed's loss with respect to its logits and values, its metrics [S, 5] and
        approximate KL [S]."""
        logits, values = self.model.forward_for_update(batch.observations)
        with torch.no_grad():
            logits_grad, values_grad, metrics = ppo_loss_gradients(
                logits.detach(), values.detach(), batch, clip, mask, count,
                self.config.ent_coef, self.config.vf_coef,
            )  # fmt: skip
        return logits_grad, values_grad, metrics, metrics[:, ROW_METRICS.index("approx_kl")]

    def update(self, rollout: Rollout, lr: torch.Tensor, clip: torch.Tensor) -> list[dict[str, float]]:
        """``n_epochs`` passes of each seed's shuffled valid rows in minibatches; per-seed metrics."""
        config = self.config
        seeds, rows = rollout.valid.shape
        size = config.minibatch_size
        has_rows = rollout.counts > 0
        whole = size >= rows  # one minibatch of every row: no shuffle
        if not whole:  # each seed's shuffles for all epochs from its own generator; invalid rows last
            keys = torch.stack(
                [torch.rand(config.n_epochs, rows, generator=g, device="cpu") for g in self.generators]
            ).to(self.device)
            keys.masked_fill_(~rollout.valid.unsqueeze(1), 2.0)
            orders = keys.argsort(dim=-1, stable=True)
        stopped = torch.zeros(seeds, dtype=torch.bool, device=self.device)
        sums = torch.zeros(seeds, len(ROW_METRICS), device=self.device)
        done_steps = torch.zeros(seeds, device=self.device)
        batches = math.ceil(int(rollout.counts.max()) / size) if bool(has_rows.any()) else 0
        positions = torch.arange(size, device=self.device)
        mask, count = rollout.valid.float(), rollout.counts
        normalize = config.normalize_advantages
        closed_form = self.differentiates_in_closed_form
        if whole and normalize:  # the same rows in every epoch: their advantages normalized once
            normalized = masked_normalize(rollout.advantages, mask, count)
            rollout = dataclasses.replace(rollout, advantages=normalized)
            normalize = False
        for epoch in range(config.n_epochs):
            for start in range(0, batches * size, size):
                index: torch.Tensor | None = None
                if not whole:
                    index = orders[:, epoch, start : start + size]
                    mask = (positions[: index.shape[1]] + start < rollout.counts.unsqueeze(1)).float()
                    count = mask.sum(dim=1)
                active = (count > 0) & ~stopped
                batch = self.minibatch(rollout, index, mask, count, normalize)
                if closed_form:
                    logits_grad, values_grad, row_metrics, kl = self.minibatch_gradients(
                        batch, mask, count, clip
                    )
                else:
                    losses, row_metrics, kl = self.minibatch_loss(batch, mask, count, clip)
                if config.target_kl is not None:
                    over = active & (kl > config.target_kl)
                    stopped |= over
                    active &= ~over
                if not bool(active.any()):
                    continue
                if closed_form:
                    self.heads_backward_and_step(logits_grad, values_grad, lr, active)
                else:
                    self.backward_and_step(losses, lr, active)
                sums += row_metrics * active.float().unsqueeze(1)
                done_steps += active.float()
        self.updates += has_rows.cpu().numpy()
        means = (sums / done_steps.clamp(min=1.0).unsqueeze(1)).tolist()
        stopped_list, done_list = stopped.tolist(), done_steps.tolist()
        explained = self.explained_variances(rollout).tolist()
        metrics = []
        for row in range(seeds):
            scalars = {
                "train/updates": float(self.updates[row]),
                "train/stopped_early": float(stopped_list[row]),
            }
            if done_list[row] > 0:
                scalars |= {f"train/{name}": v for name, v in zip(ROW_METRICS, means[row], strict=True)}
            scalars["train/explained_variance"] = float(explained[row])
            metrics.append(scalars)
        return metrics

    def learn(self) -> dict[int, LearnResult]:
        """A rollout and an update for every active seed; each seed's result by seed."""
        config = self.config
        lr = self.learning_rates()
        clip = [
            max(schedule_value(config.clip_range, config.clip_schedule, int(s), config.schedule_steps), 1e-8)
            for s in self.env_steps
        ]
        rollout, finished = self.collect(config.n_steps, config.gae_lambda)
        results = self.count_steps(rollout.counts.to(torch.int64).tolist(), finished)
        metrics = self.update(
            rollout, torch.tensor(lr, device=self.device), torch.tensor(clip, device=self.device).unsqueeze(1)
        )
        self.model.forget_scaled()
        extra = [{"train/learning_rate": r, "train/clip_range": c} for r, c in zip(lr, clip, strict=True)]
        self.attach_metrics(results, rollout.counts, [m | e for m, e in zip(metrics, extra, strict=True)])
        return results


# ----------------------------------------------------------------------------------------------
# 5. The spec
# ----------------------------------------------------------------------------------------------


def ppo_bytes_per_seed(config: PPOConfig, env: EnvInfo) -> int:
    return actor_critic_bytes_per_seed(config, env, config.n_steps, config.minibatch_size)


AGENT = actor_critic_spec(
    "ppo",
    "Proximal Policy Optimization (PyTorch): clipped surrogate, GAE, minibatch epochs, vector envs",
    PPOConfig,
    ppo_bytes_per_seed,
    PopulationPPO,
)


__all__ = [
    "AGENT",
    "PPOBatch",
    "PPOConfig",
    "PopulationPPO",
    "clipped_surrogate_loss",
    "clipped_value_loss",
    "ppo_bytes_per_seed",
    "ppo_loss_gradients",
]
