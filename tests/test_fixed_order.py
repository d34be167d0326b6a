"""A seed's bits by construction (agents/nn/fixed_order.py and the kernels every seed trains with).

Two kinds of test, so that they fail on this machine whenever the design would fail on another:

- the products and sums are the sum written out in NumPy, bit for bit: any BLAS, FMA or reordering
  (which is what lets a batch change a matrix's bits on some CPU, as ``torch.bmm`` does on an Intel
  Xeon: ``../shared/evidence/intel-xeon.md``) gives other bits and fails here, whatever this CPU's
  BLAS happens to do;
- every kernel a seed's training uses gives a seed alone the bits it gets at every position of
  batches of 2 to 8 seeds, beside random neighbours, on one thread and on two.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import numpy as np
import pytest
import torch

from cartpole.agents.nn import fixed_order, stacked_conv
from cartpole.agents.nn.fast_tanh import tanh
from cartpole.agents.nn.fixed_order import matmul, matmul_arrays, row_norms, row_sums, seed_sums
from cartpole.agents.nn.masked import log_probs_and_entropy, masked_mean, masked_normalize, masked_variance
from cartpole.agents.nn.population_optimizers import PopulationAdam, PopulationRMSprop
from cartpole.agents.nn.stacked_conv import stacked_conv2d
from cartpole.agents.nn.stacked_linear import mlp_gradients, relu_gradient, stacked_linear

pytestmark = pytest.mark.independence


def written_out(a: np.ndarray, b: np.ndarray, c: np.ndarray | None = None) -> np.ndarray:
    """``a @ b + c`` [S, n, m] as the sum the kernels promise: from 0, each product in turn (a
    float32 multiply, then a float32 add), then ``c``."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    out = np.zeros((max(a.shape[0], b.shape[0]), a.shape[1], b.shape[2]), dtype=np.float32)
    for p in range(a.shape[2]):
        out = out + a[:, :, p : p + 1] * b[:, p : p + 1, :]
    return out if c is None else out + c


def bits(t: torch.Tensor | np.ndarray) -> np.ndarray:
    """The float32 bits of ``t`` as integers (-0.0 and 0.0 differ, NaNs compare)."""
    array = t.detach().numpy() if isinstance(t, torch.Tensor) else t
    return np.ascontiguousarray(array, dtype=np.float32).view(np.int32)


def assert_same_bits(ours: torch.Tensor | np.ndarray, theirs: torch.Tensor | np.ndarray) -> None:
    assert np.array_equal(bits(ours), bits(theirs))


@pytest.mark.parametrize(
    ("seeds", "n", "k", "m"), [(1, 1, 1, 1), (3, 7, 5, 3), (2, 256, 16, 16), (1, 9, 64, 1), (4, 13, 300, 33)]
)
@pytest.mark.parametrize("transposed", [False, True])
def test_the_product_is_the_sum_written_out(seeds: int, n: int, k: int, m: int, transposed: bool) -> None:
    rng = np.random.default_rng(n * 1000 + k)
    a = rng.standard_normal((seeds, k, n) if transposed else (seeds, n, k), dtype=np.float32)
    a = a.transpose(0, 2, 1) if transposed else a
    b = rng.standard_normal((seeds, k, m), dtype=np.float32)
    for c in (
        None,
        rng.standard_normal((seeds, 1, m), dtype=np.float32),
        rng.standard_normal((1, n, 1), dtype=np.float32),
    ):
        expected = written_out(a, b, c)
        ours = matmul(torch.from_numpy(a), torch.from_numpy(b), None if c is None else torch.from_numpy(c))
        assert_same_bits(ours, expected)
        assert_same_bits(
            matmul_arrays(a, b, np.zeros((1, 1, m), np.float32) if c is None else c[:, :1]),
            written_out(a, b, None if c is None else c[:, :1]),
        )


def test_the_evidence_shapes_give_one_matrix_the_same_bits_in_any_batch() -> None:
    """``../shared/evidence/intel-xeon.md``'s 500 shapes (``bmm_batch_bits.py``: m, k, n, each side
    transposed or not), where ``torch.bmm`` gave 74 matrices other bits in a batch of 3 than alone on
    an Intel Xeon: through our product, batch 1, batch 3 and the 2-D form agree, and are the sum."""
    generator = torch.Generator().manual_seed(0)
    for m, k, n in itertools.product([1, 2, 4, 16, 64], [8, 72, 84, 256, 512], [1, 2, 4, 16, 64]):
        for ta, tb in itertools.product([False, True], repeat=2):
            a = (
                torch.randn(3, k, m, generator=generator).transpose(1, 2)
                if ta
                else torch.randn(3, m, k, generator=generator)
            )
            b = (
                torch.randn(3, n, k, generator=generator).transpose(1, 2)
                if tb
                else torch.randn(3, k, n, generator=generator)
            )
            three = matmul(a, b)[0]
            assert_same_bits(matmul(a[:1], b[:1])[0], three)
            assert_same_bits(matmul_arrays(a[0].numpy(), b[0].numpy(), np.zeros(n, np.float32)), three)
            if k == 72 and ta:  # the written-out sum costs k passes: one k, every other size
                assert_same_bits(three, written_out(a[:1].numpy(), b[:1].numpy())[0])


def test_sums_and_norms_are_written_out() -> None:
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 50, 6), dtype=np.float32)
    expected = np.zeros((3, 6), np.float32)
    for row in range(50):
        expected = expected + x[:, row]
    assert_same_bits(row_sums(torch.from_numpy(x)), expected)
    assert_same_bits(seed_sums(torch.from_numpy(x[:, :, 0])), expected[:, 0])
    squares = np.zeros(3, np.float32)
    for p in range(50):
        squares = squares + x[:, p, 0] * x[:, p, 0]
    assert_same_bits(row_norms(torch.from_numpy(np.ascontiguousarray(x[:, :, 0]))), np.sqrt(squares))


def test_seed_sums_are_differentiable_as_sums() -> None:
    x = torch.randn(3, 40, requires_grad=True)
    (seed_sums(x) * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert x.grad is not None
    assert torch.equal(x.grad, torch.tensor([1.0, 2.0, 3.0]).unsqueeze(1).expand(3, 40))


def test_torch_s_own_sum_splits_a_lone_long_row_between_threads() -> None:
    """The case that :func:`seed_sums` exists for (and a check that the independence tests below can
    fail): on two threads, torch sums one long row in another order than the same row among others."""
    torch.set_num_threads(2)  # conftest's autouse fixture sets one thread again for the next test
    generator = torch.Generator().manual_seed(1)
    rows = [torch.randn(3, 200_000, generator=generator) for _ in range(8)]
    assert any(not torch.equal(x[1:2].sum(dim=1)[0], x.sum(dim=1)[1]) for x in rows)
    assert all(torch.equal(seed_sums(x[1:2])[0], seed_sums(x)[1]) for x in rows)


Kernel = Callable[[Sequence[torch.Tensor]], Sequence[torch.Tensor]]
"""A kernel under test: every seed's inputs (each [S, ...]) to every seed's outputs (each [S, ...])."""


def assert_seed_independent(
    kernel: Kernel, make: Callable[[int, torch.Generator], list[torch.Tensor]]
) -> None:
    """``kernel`` gives a seed alone the bits it gets at every position of batches of 2 to 8 seeds
    beside random neighbours (``make(S, generator)`` draws S seeds' inputs), on one and two threads."""
    generator = torch.Generator().manual_seed(7)
    for threads in (1, 2):
        torch.set_num_threads(threads)
        one = make(1, generator)
        alone = [out.detach().clone() for out in kernel([t.clone() for t in one])]
        for seeds in range(2, 9):
            for position in range(seeds):
                batch = make(seeds, generator)
                for t, seed in zip(batch, one, strict=True):
                    t.data[position] = seed[0]
                among = kernel(batch)
                for ours, theirs in zip(alone, among, strict=True):
                    assert_same_bits(ours[0], theirs[position])
    torch.set_num_threads(1)


def randn(*shape: int) -> Callable[[int, torch.Generator], torch.Tensor]:
    return lambda seeds, generator: torch.randn(seeds, *shape, generator=generator)


def inputs(
    *makers: Callable[[int, torch.Generator], torch.Tensor],
) -> Callable[[int, torch.Generator], list[torch.Tensor]]:
    return lambda seeds, generator: [make(seeds, generator) for make in makers]


@pytest.mark.parametrize(
    ("n", "k", "m"), [(256, 4, 16), (256, 16, 16), (16, 256, 4), (128, 6, 64), (1, 64, 2), (37, 33, 1)]
)
def test_products_and_sums(n: int, k: int, m: int) -> None:
    assert_seed_independent(
        lambda t: [matmul(t[0], t[1], t[2])], inputs(randn(n, k), randn(k, m), randn(1, m))
    )
    assert_seed_independent(lambda t: [matmul(t[0].transpose(1, 2), t[1])], inputs(randn(k, n), randn(k, m)))
    assert_seed_independent(
        lambda t: [row_sums(t[0]), seed_sums(t[0]), row_norms(t[0].flatten(1))], inputs(randn(n, m))
    )
    assert_seed_independent(
        lambda t: [torch.from_numpy(matmul_arrays(t[0].numpy(), t[1].numpy(), t[2].numpy()))],
        inputs(randn(n, k), randn(k, m), randn(1, m)),
    )


@pytest.mark.parametrize(("inputs_", "width", "outputs"), [(4, 16, 2), (6, 64, 1), (4, 64, 3), (5, 7, 2)])
def test_a_linear_layer_and_an_mlp_s_gradients(inputs_: int, width: int, outputs: int) -> None:
    batch = 128

    def layer(t: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        leaves = [x.clone().requires_grad_(True) for x in t[:3]]
        out = stacked_linear(*leaves)
        (out * t[3]).sum().backward()
        return [out, *[leaf.grad for leaf in leaves if leaf.grad is not None]]

    assert_seed_independent(
        layer, inputs(randn(batch, inputs_), randn(width, inputs_), randn(width), randn(batch, width))
    )

    def mlp(t: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        x, w1, b1, w2, b2, grad = t
        hidden = tanh(stacked_linear(x, w1, b1))
        layers = [(w1, b1), (w2, b2)]
        gradients = mlp_gradients(layers, [x, hidden], grad, relu_gradient)
        return [hidden, stacked_linear(hidden, w2, b2), *[g for pair in gradients for g in pair]]

    assert_seed_independent(
        mlp,
        inputs(
            randn(batch, inputs_),
            randn(width, inputs_),
            randn(width),
            randn(outputs, width),
            randn(outputs),
            randn(batch, outputs),
        ),
    )


def test_per_seed_statistics_and_log_probabilities() -> None:
    def statistics(t: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        x, mask_draw, logits = t
        mask = (mask_draw > -0.5).float()
        count = seed_sums(mask)
        log_probs, entropy = log_probs_and_entropy(logits, (logits[..., 0] > 0).long(), mask, count, 0.01)
        return [
            masked_mean(x, mask, count),
            masked_variance(x, mask, count),
            masked_normalize(x, mask, count),
            log_probs,
            entropy,
        ]

    assert_seed_independent(statistics, inputs(randn(200), randn(200), randn(200, 2)))


@pytest.mark.parametrize("optimizer", [PopulationAdam, PopulationRMSprop])
def test_an_optimizer_step_with_clipped_gradients(optimizer: type) -> None:
    from cartpole.agents.nn.flat_parameters import FlatParameters

    def step(t: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        params, grads = t[0].contiguous(), t[1].contiguous()
        seeds = params.shape[0]
        norms = row_norms(grads).unsqueeze(1)
        grads = grads * (0.5 / (norms + 1e-6)).clamp(max=1.0)  # as FlatParameters.clip_grad_norms
        opt = (
            optimizer(seeds, params.shape[1], 1e-5)
            if optimizer is PopulationAdam
            else optimizer(seeds, params.shape[1], 0.99, 1e-5)
        )
        for _ in range(3):
            opt.step(params, grads, torch.full((seeds,), 1e-2), torch.ones(seeds, dtype=torch.bool))
        return [params, norms]

    assert FlatParameters.clip_grad_norms  # the form the test repeats
    assert_seed_independent(step, inputs(randn(1000), randn(1000)))


def test_a_convolutional_trunk_and_its_gradients() -> None:
    def trunk(t: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        x, w1, b1, w2, b2, upstream = t
        leaves = [p.clone().requires_grad_(True) for p in (w1, b1, w2, b2)]
        hidden = torch.relu(stacked_conv2d(x, leaves[0] * 0.1, leaves[1], 4))
        out = stacked_conv2d(hidden, leaves[2] * 0.1, leaves[3], 1)
        (out * upstream).sum().backward()
        return [out, *[leaf.grad for leaf in leaves if leaf.grad is not None]]

    make = inputs(
        randn(3, 2, 30, 40), randn(8, 2, 8, 8), randn(8), randn(16, 8, 3, 3), randn(16), randn(3, 16, 4, 7)
    )
    assert_seed_independent(trunk, make)


def test_each_seed_s_convolution_is_one_call_that_never_sees_the_population(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """What the convolutions' promise rests on (agents/nn/stacked_conv.py): every library call of a
    seed gets tensors of the same shapes, strides and (64-byte) alignment whether the seed is alone or
    at any position of any batch: a population's calls are the lone seed's, once per seed."""
    calls: list[list[object]] = []

    def describe(arg: object) -> object:
        if isinstance(arg, torch.Tensor):
            return (tuple(arg.shape), arg.stride(), arg.data_ptr() % 64)
        return arg

    def recording(function: Callable[..., torch.Tensor]) -> Callable[..., torch.Tensor]:
        def call(*args: object, **kwargs: object) -> torch.Tensor:
            calls.append([function.__name__, *map(describe, args), sorted(kwargs.items())])
            return function(*args, **kwargs)

        return call

    monkeypatch.setattr(stacked_conv.functional, "conv2d", recording(torch.nn.functional.conv2d))
    monkeypatch.setattr(stacked_conv.conv_grad, "conv2d_input", recording(torch.nn.grad.conv2d_input))
    monkeypatch.setattr(stacked_conv.conv_grad, "conv2d_weight", recording(torch.nn.grad.conv2d_weight))

    def calls_of(seeds: int) -> list[str]:
        calls.clear()
        x = torch.rand(seeds, 4, 2, 21, 23)[:, :, :, 1:, 3:]  # a view, as a population's rows are
        first = torch.randn(seeds, 6, 2, 3, 3, requires_grad=True)
        second = torch.randn(seeds, 5, 6, 2, 2, requires_grad=True)
        hidden = torch.relu(stacked_conv2d(x, first, torch.zeros(seeds, 6), 2))
        stacked_conv2d(hidden, second, torch.zeros(seeds, 5), 1).sum().backward()
        return sorted(map(repr, calls))

    alone = calls_of(1)
    assert len(alone) == 5  # two convolutions; the first's weight gradient, the second's two gradients
    assert all(", 0)" in call for call in alone)  # every tensor 64-byte aligned
    for seeds in (2, 5):  # each seed's calls are the lone seed's, whatever its position
        assert calls_of(seeds) == sorted(alone * seeds)


@pytest.mark.skipif(
    not torch.cuda.is_available(),
    reason="needs a CUDA GPU (where a seed's bits are not promised: cuBLAS and cuDNN choose kernels by "
    "the whole batch, and the products are torch's there; docs/DESIGN.md)",
)
def test_on_cuda_the_products_are_torch_s() -> None:
    a, b = torch.randn(2, 5, 3, device="cuda"), torch.randn(2, 3, 4, device="cuda")
    assert not fixed_order.is_fixed_order(a)
    torch.testing.assert_close(matmul(a, b), torch.bmm(a, b))


def test_shapes_that_do_not_multiply_are_a_value_error_not_a_kernel_s() -> None:
    """The kernels check no bounds: a damaged checkpoint's weights must be refused before them (as
    ``np.matmul`` refused them), so that loading it says so in one line (tests/test_bad_input.py)."""
    x = np.zeros((1, 5, 4), np.float32)
    for weight, bias in [
        (np.zeros((1, 3, 2), np.float32), None),
        (np.zeros((1, 4, 2, 1), np.float32), None),
        (np.zeros((1, 4, 2), np.float32), np.zeros((1, 1, 3), np.float32)),
        (np.zeros((2, 4, 2), np.float32), np.zeros((3, 1, 2), np.float32)),
    ]:
        with pytest.raises(ValueError, match="cannot multiply"):
            matmul_arrays(x, weight, bias)
    with pytest.raises(ValueError, match="cannot multiply"):
        matmul(torch.zeros(2, 5, 4), torch.zeros(3, 4, 2))
