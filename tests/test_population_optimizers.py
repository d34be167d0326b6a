"""agents/nn/population_optimizers.py: one optimizer step for every seed, the numba pass and torch's form."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch

from cartpole.agents.nn.population_optimizers import PopulationAdam, PopulationOptimizer, PopulationRMSprop

MAKERS: dict[str, Callable[[bool | None], PopulationOptimizer]] = {
    "adam": lambda fused: PopulationAdam(4, 33, eps=1e-5, betas=(0.8, 0.99), fused=fused),
    "rmsprop": lambda fused: PopulationRMSprop(4, 33, alpha=0.95, eps=1e-5, fused=fused),
}


def run_steps(optimizer: PopulationOptimizer) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Five steps with different learning rates per seed and seed 2 sitting out steps 1 and 3."""
    generator = torch.Generator().manual_seed(0)
    params = torch.randn(4, 33, generator=generator)
    lr = torch.tensor([1e-3, 2e-3, 5e-3, 1e-2])
    snapshots = []
    for step in range(5):
        grads = torch.randn(4, 33, generator=generator)
        active = torch.tensor([True, True, step not in (1, 3), True])
        optimizer.step(params, grads, lr, active)
        snapshots.append(params.clone())
    return params, snapshots


@pytest.mark.parametrize("name", MAKERS)
def test_the_numba_pass_is_torchs_update(name: str) -> None:
    fused, _ = run_steps(MAKERS[name](None))
    plain, _ = run_steps(MAKERS[name](False))
    torch.testing.assert_close(fused, plain, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("name", MAKERS)
@pytest.mark.parametrize("fused", [None, False])
def test_a_seed_that_sits_out_keeps_its_parameters(name: str, fused: bool | None) -> None:
    _, snapshots = run_steps(MAKERS[name](fused))
    assert torch.equal(snapshots[1][2], snapshots[0][2])
    assert torch.equal(snapshots[3][2], snapshots[2][2])
    assert not torch.equal(snapshots[2][2], snapshots[1][2])
    assert not torch.equal(snapshots[1][0], snapshots[0][0])


@pytest.mark.parametrize("fused", [None, False])
def test_adam_counts_only_the_steps_a_seed_took(fused: bool | None) -> None:
    optimizer = PopulationAdam(4, 33, eps=1e-5, fused=fused)
    run_steps(optimizer)
    assert [optimizer.row_state(row)[1]["optim_steps"] for row in range(4)] == [5.0, 5.0, 3.0, 5.0]
