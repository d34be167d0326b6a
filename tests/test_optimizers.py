"""agents/optimizers.py: the updates and state of torch.optim.Adam(fused=True) and RMSprop, bit for bit."""

from __future__ import annotations

import pytest
import torch

from cartpole.agents.nn.optimizers import FusedAdam, RMSprop


def make_parameters(seed: int) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    shapes = [(8, 4), (8,), (2, 8), (2,)]
    return [torch.randn(shape, generator=generator).requires_grad_() for shape in shapes]


def set_gradients(parameters: list[torch.Tensor], step: int, skip: int | None = None) -> None:
    generator = torch.Generator().manual_seed(1000 + step)
    for index, parameter in enumerate(parameters):
        parameter.grad = None if index == skip else torch.randn(parameter.shape, generator=generator)


OPTIMIZERS = {
    "adam": (
        lambda p: FusedAdam(p, lr=3e-3, betas=(0.8, 0.99), eps=1e-6),
        lambda p: torch.optim.Adam(p, lr=3e-3, betas=(0.8, 0.99), eps=1e-6, fused=True),
    ),
    "rmsprop": (
        lambda p: RMSprop(p, lr=7e-4, alpha=0.9, eps=1e-5),
        lambda p: torch.optim.RMSprop(p, lr=7e-4, alpha=0.9, eps=1e-5),
    ),
}


@pytest.mark.parametrize("name", OPTIMIZERS)
def test_steps_are_bitwise_those_of_torch_optim(name: str) -> None:
    make_ours, make_reference = OPTIMIZERS[name]
    ours_params, torch_params = make_parameters(0), make_parameters(0)
    ours, reference = make_ours(ours_params), make_reference(torch_params)
    for step in range(25):
        skip = 1 if step % 5 == 0 else None  # a parameter without a gradient is left alone, state too
        set_gradients(ours_params, step, skip)
        set_gradients(torch_params, step, skip)
        ours.step()
        reference.step()
    assert all(torch.equal(a, b) for a, b in zip(ours_params, torch_params, strict=True))
    for index, parameter in enumerate(torch_params):
        for slot, value in reference.state[parameter].items():  # step, exp_avg, ... or square_avg
            assert torch.equal(ours.state[slot][index], value), (index, slot)


@pytest.mark.parametrize("name", OPTIMIZERS)
def test_state_dict_round_trip_continues_exactly(name: str) -> None:
    make_ours, _ = OPTIMIZERS[name]
    params_a, params_b = make_parameters(1), make_parameters(1)
    a = make_ours(params_a)
    for step in range(5):
        set_gradients(params_a, step)
        a.step()
    tensors, _ = a.state_dict()
    with torch.no_grad():
        for pa, pb in zip(params_a, params_b, strict=True):
            pb.copy_(pa)
    b = make_ours(params_b)
    b.load_state_dict({k: v.clone() for k, v in tensors.items()})
    for step in range(5, 10):
        set_gradients(params_a, step)
        set_gradients(params_b, step)
        a.step()
        b.step()
    assert all(torch.equal(x, y) for x, y in zip(params_a, params_b, strict=True))


def test_zero_grad_clears_the_gradients() -> None:
    parameters = make_parameters(2)
    optimizer = FusedAdam(parameters, lr=1e-3)
    set_gradients(parameters, 0)
    optimizer.zero_grad()
    assert all(p.grad is None for p in parameters)
    optimizer.step()  # no gradient: nothing moves, no state changes
    assert all(int(step) == 0 for step in optimizer.steps)
