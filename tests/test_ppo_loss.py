"""PPO's loss differentiated in closed form: the compiled CPU pass against the tensor form that CUDA
runs (and that autograd checks in tests/test_population.py), and a seed's bits among others."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cartpole.agents.actor_critic.ppo import PPOBatch, ppo_loss_gradients, ppo_loss_gradients_compiled


def batch_of(rng: np.random.Generator, seeds: int, rows: int, actions: int, dtype=torch.float32):
    def normal(*shape: int, scale: float = 1.0) -> torch.Tensor:
        return torch.from_numpy(rng.standard_normal(shape) * scale).to(dtype)

    logits = normal(seeds, rows, actions)
    chosen = torch.from_numpy(rng.integers(0, actions, (seeds, rows)))
    old = torch.log_softmax(logits + normal(seeds, rows, actions, scale=0.3), dim=-1)
    batch = PPOBatch(
        observations=normal(seeds, rows, 4),
        actions=chosen,
        old_log_probs=old.gather(-1, chosen.unsqueeze(-1)).squeeze(-1),
        old_values=normal(seeds, rows),
        advantages=normal(seeds, rows),
        returns=normal(seeds, rows),
    )
    mask = torch.from_numpy(rng.random((seeds, rows)) < 0.9).to(dtype)
    return logits, normal(seeds, rows), batch, mask, mask.sum(dim=1)


@pytest.mark.parametrize("ent_coef", [0.0, 0.01])
@pytest.mark.parametrize("actions", [2, 3])
def test_the_compiled_loss_gradients_match_the_tensor_form(ent_coef, actions):
    rng = np.random.default_rng(actions)
    logits, values, batch, mask, count = batch_of(rng, 3, 50, actions, torch.float64)
    clip = torch.tensor([[0.2], [0.1], [0.05]], dtype=torch.float64)
    want = ppo_loss_gradients(logits, values, batch, clip, mask, count, ent_coef, 0.5)  # float64: tensors

    def f32(t: torch.Tensor) -> torch.Tensor:
        return t.float() if t.is_floating_point() else t

    batch32 = PPOBatch(*(f32(getattr(batch, name)) for name in PPOBatch.__dataclass_fields__))
    got = ppo_loss_gradients(
        f32(logits), f32(values), batch32, f32(clip), f32(mask), f32(count), ent_coef, 0.5
    )
    for g, w in zip(got, want, strict=True):
        assert g.dtype == torch.float32
        torch.testing.assert_close(g.double(), w, rtol=1e-5, atol=1e-6)
    assert float(want[2][:, 4].max()) > 0.0  # some rows clipped: both sides of the clip are checked


@pytest.mark.independence
@pytest.mark.parametrize("neighbours", [1, 3, 6])
def test_a_seeds_loss_gradients_are_its_own_bits_at_every_position(neighbours):
    rng = np.random.default_rng(neighbours)
    alone = batch_of(rng, 1, 40, 2)
    clip = torch.full((1, 1), 0.2)
    logits, values, batch, mask, count = alone
    want = ppo_loss_gradients_compiled(logits, values, batch, clip, mask, count, 0.01, 0.5)
    for position in range(neighbours + 1):
        others = batch_of(rng, neighbours, 40, 2)

        def put(mine: torch.Tensor, theirs: torch.Tensor, at: int = position) -> torch.Tensor:
            return torch.cat([theirs[:at], mine, theirs[at:]])

        logits, values = put(alone[0], others[0]), put(alone[1], others[1])
        batch = PPOBatch(
            *(put(getattr(alone[2], n), getattr(others[2], n)) for n in PPOBatch.__dataclass_fields__)
        )
        clips = torch.full((neighbours + 1, 1), 0.2)
        got = ppo_loss_gradients_compiled(
            logits, values, batch, clips, put(alone[3], others[3]), put(alone[4], others[4]), 0.01, 0.5
        )
        for g, w in zip(got, want, strict=True):
            assert torch.equal(g[position : position + 1], w)
