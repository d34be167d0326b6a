"""The arithmetic under a population's update, one thread (``--threads``): float32 tanh three ways,
the batched matmul, a policy head's weight gradient in both orientations, and the Adam step two ways.

    python benchmarks/kernels.py
    python benchmarks/kernels.py --seeds 100 --rows 128 --width 64
    python benchmarks/kernels.py --pixels      # the pixel trunk's convolutions, and a pixel PPO update
    python benchmarks/kernels.py --pixels --threads 2

Shapes are a 100-seed PPO population's full-batch step: ``[seeds, rows, width]`` activations, and
``[seeds, rows, width] x [seeds, width, width]`` for a hidden layer. Printed: nanoseconds an element for
``torch.tanh``, ``np.tanh`` and ``cartpole.agents.nn.fast_tanh`` (the one the populations and the numpy
greedy policies use), the largest relative difference of the last from float64 ``tanh``, and GFLOP/s of
``torch.bmm``; then the weight gradient of a 2-output head (``[seeds, width, rows] x [seeds, rows, 2]``,
autograd's orientation for ``baddbmm``, against ``[seeds, 2, rows] x [seeds, rows, width]``, and the
latter in our fixed order, what ``agents/nn/stacked_linear.py`` runs), one seed's ReLU gradient by
``torch.where`` and by autograd's ``threshold_backward`` (``relu_gradient``), and one Adam step of
``[seeds, 9218]`` parameters (a 64x64 actor-critic) in torch's elementwise form and in the numba pass of
``agents/nn/population_optimizers.py``. Then our fixed-order product (``agents/nn/fixed_order.py``, what
every seed trains with, so that its bits never depend on its neighbours) against ``torch.bmm`` on the
default agents' shapes, for one seed and for ``--seeds``. Which kernels NumPy and torch pick depends on
the CPU (AVX-512 or not), so the CPU is printed first. Last, one ``learn()`` (rollout and update) of
PPO's, A2C's and REINFORCE's default presets for one seed and for ``--seeds``, with the networks'
gradients by autograd and by hand (``agents/nn/stacked_linear.py``'s ``mlp_gradients``, what the
populations use for MLPs). Then acting: one step of PPO's and DQN's default networks for every env of 1
and ``--seeds`` seeds, through the NumPy twins (``agents/nn/numpy_mlp.py``, how they act) and through
torch on the same weights; a greedy policy on 1 and 100 rows, through its compiled forward pass
(``agents/nn/greedy_play.py``, how it acts) and through torch; and 10 and 100 greedy episodes of our
float64 CartPole (an in-training evaluation), stepped by the vector env and played in one compiled call,
per env step.

``--pixels``: instead, one seed's conv trunk (a 512-row batch of 4x30x100 frame stacks through
``agents/actor_critic/network.py``'s ``CONV_LAYERS``, forward and backward) with the images laid
out as torch makes them and channels-last (what ``agents/nn/stacked_conv.py`` does), then one
``learn()`` of PPO's ``pixels`` preset (a 512-step rollout and its 4 epochs), per env step.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments

from cartpole.agents.nn.fast_tanh import tanh_array
from cartpole.agents.nn.fixed_order import matmul
from cartpole.agents.nn.population_optimizers import PopulationAdam
from cartpole.agents.nn.stacked_linear import relu_gradient, relu_gradient_by_where


def seconds_per_call(call: Callable[[], object], repeats: int) -> float:
    """The best of five timings of ``repeats`` calls, per call."""
    call()
    best = float("inf")
    for _ in range(5):
        started = time.perf_counter()
        for _ in range(repeats):
            call()
        best = min(best, (time.perf_counter() - started) / repeats)
    return best


def adam_step(seeds: int, size: int, fused: bool | None) -> Callable[[], None]:
    """One PopulationAdam step of every seed, as a call to time."""
    adam = PopulationAdam(seeds, size, eps=1e-5, fused=fused)
    params, grads = torch.randn(seeds, size), 1e-3 * torch.randn(seeds, size)
    lr, active = torch.full((seeds,), 2e-3), torch.ones(seeds, dtype=torch.bool)
    return lambda: adam.step(params, grads, lr, active)


def conv_trunk(channels_last: bool) -> Callable[[], None]:
    """One forward and backward pass of a 512-row batch through the pixel trunk's conv layers."""
    from torch.nn import functional

    from cartpole.agents.actor_critic.network import CONV_LAYERS

    generator = torch.Generator().manual_seed(0)
    images = torch.rand(512, 4, 30, 100, generator=generator)
    if channels_last:
        images = images.contiguous(memory_format=torch.channels_last)
    weights, channels = [], 4
    for filters, kernel, stride in CONV_LAYERS:
        weight = torch.randn(filters, channels, kernel, kernel, generator=generator) * 0.05
        weights.append((weight.requires_grad_(True), stride))
        channels = filters

    def step() -> None:
        x = images
        for weight, stride in weights:
            x = torch.relu(functional.conv2d(x, weight, stride=stride))
        x.sum().backward()

    return step


def pixel_ppo_learn() -> tuple[Callable[[], object], int]:
    """One ``learn()`` of a single seed with PPO's ``pixels`` preset, and its env steps."""
    from cartpole.agents.registry import build_population, get_agent
    from cartpole.envs import env_info
    from cartpole.training.config import resolve_config

    spec = get_agent("ppo")
    config, _ = resolve_config("ppo", spec.config_cls, "pixels")
    population = build_population(spec, config, env_info("cartpole/CartPolePixels-v1"), [1], "cpu")
    return population.learn, config.num_envs * config.n_steps


def actor_critic_learn(agent: str, seeds: int, by_hand: bool) -> Callable[[], object]:
    """One ``learn()`` (a rollout and its update) of ``agent``'s default preset for ``seeds`` seeds,
    its gradients by hand (what the populations do for MLPs) or by autograd."""
    from cartpole.agents.registry import build_population, get_agent
    from cartpole.envs import env_info
    from cartpole.training.config import resolve_config

    spec = get_agent(agent)
    config, _ = resolve_config(agent, spec.config_cls, "default")
    population = build_population(spec, config, env_info("CartPole-v1"), list(range(seeds)), "cpu")
    population.model.by_hand = by_hand
    for _ in range(20):  # past the first, short episodes
        population.learn()
    return population.learn


def updates_by_hand(seeds: int, repeats: int) -> list[list[str]]:
    rows = []
    for agent in ("ppo", "a2c", "reinforce"):
        for count in (1, seeds):
            times = {
                by_hand: seconds_per_call(actor_critic_learn(agent, count, by_hand), repeats)
                for by_hand in (False, True)
            }
            autograd, by_hand = times[False] * 1e3, times[True] * 1e3
            rows.append([
                f"{agent} default preset, one `learn()` of {count} seed(s): autograd / by hand",
                f"{autograd:.2f} / {by_hand:.2f} ms ({by_hand / autograd:.2f}x)",
            ])  # fmt: skip
            print(*rows[-1], sep=": ", flush=True)
    return rows


def default_population(agent: str, seeds: int) -> tuple[object, int]:
    """``seeds`` seeds of ``agent``'s default preset on CartPole-v1, and their envs per seed."""
    from cartpole.agents.registry import build_population, get_agent
    from cartpole.envs import env_info
    from cartpole.training.config import resolve_config

    spec = get_agent(agent)
    config, _ = resolve_config(agent, spec.config_cls, "default")
    return build_population(spec, config, env_info("CartPole-v1"), list(range(seeds)), "cpu"), config.num_envs


def acting_calls(population: Any, x: np.ndarray) -> dict[str, Callable[[], object]]:
    """The greedy actions of every seed's envs ``x`` [S, N, 4] through the NumPy twin the population
    acts through, and through torch's stacked forward pass on the same weights."""
    if hasattr(population, "model"):  # an actor-critic: its actors
        model = population.model
        params = {name: p.detach() for name, p in model.params.items()}
        twin = model.numpy_actor()
        return {
            "numpy": lambda: twin(x).argmax(axis=-1),
            "torch": lambda: model.run(model.actor_plan, params, torch.from_numpy(x)).argmax(-1),
        }
    net = population.net  # DQN: the online Q-networks, on their padded acting rows
    padded = np.zeros((x.shape[0], population.acting_rows, x.shape[2]), dtype=np.float32)
    padded[:, : x.shape[1]] = x
    return {
        "numpy": lambda: population.numpy_q_values(x).argmax(axis=-1),
        "torch": lambda: net.forward(net.params, torch.from_numpy(padded), population.activation).argmax(-1),
    }


def policy_calls(population: Any, observations: np.ndarray) -> dict[str, Callable[[], object]]:
    """Seed 0's greedy policy on ``observations`` as it acts (its snapshot's compiled forward pass,
    ``agents/nn/greedy_play.py``), and through torch."""
    policy = population.seed_policy(0)
    if hasattr(population, "model"):
        forward = population.model.unstack(0).logits
    else:
        forward = population.net.unstack(0).forward
    return {
        "numpy": lambda: policy.act(observations),
        "torch": lambda: forward(torch.from_numpy(observations)).argmax(-1),
    }


def numpy_against_torch(
    what: str, calls: dict[str, Callable[[], object]], repeats: int, ours: str = "numpy"
) -> list[str]:
    """Microseconds a call of ``calls["numpy"]`` (our way, named ``ours``) and of ``calls["torch"]``."""
    with torch.no_grad():
        times = {name: seconds_per_call(call, repeats) * 1e6 for name, call in calls.items()}
    return [f"{what}: {ours} / torch", f"{times['numpy']:.1f} / {times['torch']:.1f} us"]


def greedy_episodes(population: Any, episodes: int, repeats: int) -> list[str]:
    """Seed 0's greedy policy on ``episodes`` evaluation episodes of our float64 CartPole (an
    in-training evaluation), stepped by the vector env and played in one compiled call
    (``agents/nn/greedy_play.py``): CPU microseconds per env step."""
    from cartpole.evaluation import evaluate

    policy = population.seed_policy(0)

    class Stepped:  # the same policy, without play_cartpole: the vector env steps its episodes
        def act(self, observations: np.ndarray) -> np.ndarray:
            return policy.act(observations)

    times = {}
    for name, player in (("vector env", Stepped()), ("compiled", policy)):
        steps = sum(evaluate(player, "CartPole-v1", episodes, seed=0, simulator="fast").lengths)
        seconds = seconds_per_call(
            lambda p=player: evaluate(p, "CartPole-v1", episodes, seed=0, simulator="fast"), repeats
        )
        times[name] = seconds / steps * 1e6
    return [f"greedy episodes, {episodes} at once (an evaluation on our simulator): vector env / compiled",
            f"{times['vector env']:.2f} / {times['compiled']:.2f} us an env step"]  # fmt: skip


def acting(seeds: int, repeats: int) -> list[list[str]]:
    """What acting costs our way and through torch on the same weights: one step of the default
    presets' networks for every env of 1 and ``seeds`` seeds (a rollout's or DQN's batched env step,
    through the NumPy twins), a greedy policy on 1 and 100 rows (the web app's step, a block of
    Gymnasium's envs in a verdict; its compiled forward pass), and greedy episodes
    (:func:`greedy_episodes`)."""
    rng = np.random.default_rng(0)
    rows = []
    for agent in ("ppo", "dqn"):
        for count in (1, seeds):
            population, envs = default_population(agent, count)
            x = rng.standard_normal((count, envs, 4)).astype(np.float32)
            what = f"acting, {agent} default network, {count} seed(s) x {envs} envs"
            rows.append(numpy_against_torch(what, acting_calls(population, x), repeats * 20))
        for batch in (1, 100):
            observations = rng.standard_normal((batch, 4)).astype(np.float32)
            what = f"greedy policy, {agent} default network, {batch} row(s)"
            calls = policy_calls(population, observations)  # its compiled forward pass (greedy_play)
            rows.append(numpy_against_torch(what, calls, repeats * 20, ours="compiled"))
        for episodes in (10, 100):
            row = greedy_episodes(population, episodes, repeats * 5)
            rows.append(
                [row[0].replace("greedy episodes", f"greedy episodes, {agent} default network"), row[1]]
            )
    for row in rows:
        print(*row, sep=": ", flush=True)
    return rows


def pixels() -> list[list[str]]:
    rows = []
    for channels_last in (False, True):
        seconds = seconds_per_call(conv_trunk(channels_last), 3)
        layout = "channels-last" if channels_last else "as made (NCHW)"
        rows.append([f"conv trunk, 512 rows, forward + backward, {layout}", f"{seconds * 1e3:.1f} ms"])
    learn, steps = pixel_ppo_learn()
    seconds = seconds_per_call(learn, 2)
    rows.append(
        [
            f"PPO pixels preset, one `learn()` of {steps} env steps",
            f"{seconds:.2f} s, {steps / seconds:.0f} steps/s",
        ]
    )
    return rows


PRODUCT_SHAPES = (
    ("PPO default, first layer", 256, 4, 16),
    ("PPO default, hidden layer", 256, 16, 16),
    ("PPO default, a weight gradient", 16, 256, 16),
    ("DQN default, hidden layer", 256, 64, 64),
    ("DQN default, a weight gradient", 64, 256, 64),
    ("a 2-action head's weight gradient", 2, 256, 64),
)
"""(what, n, k, m) of ``[S, n, k] x [S, k, m]`` products a seed's training makes."""


def products(seeds: int, repeats: int) -> list[list[str]]:
    """Our fixed-order product (``agents/nn/fixed_order.py``, what every seed trains with) against
    ``torch.bmm`` on the agents' shapes, for one seed and for ``seeds``: GFLOP/s of each."""
    generator = torch.Generator().manual_seed(1)
    rows = []
    for what, n, k, m in PRODUCT_SHAPES:
        for count in (1, seeds):
            a, b = (
                torch.randn(count, n, k, generator=generator),
                torch.randn(count, k, m, generator=generator),
            )
            flops = 2 * count * n * k * m
            ours = seconds_per_call(lambda a=a, b=b: matmul(a, b), repeats)
            theirs = seconds_per_call(lambda a=a, b=b: torch.bmm(a, b), repeats)
            rows.append(
                [
                    f"{what}, [{count}, {n}, {k}] x [{count}, {k}, {m}]: fixed order / torch.bmm",
                    f"{flops / ours / 1e9:.1f} / {flops / theirs / 1e9:.1f} GFLOP/s ({theirs / ours:.2f}x)",
                ]
            )
    for row in rows:
        print(*row, sep=": ", flush=True)
    return rows


def arithmetic(args: argparse.Namespace) -> list[list[str]]:
    """tanh three ways, bmm, a head's weight gradient both ways, a ReLU gradient two ways, Adam two ways."""
    shape = (args.seeds, args.rows, args.width)
    generator = torch.Generator().manual_seed(0)
    x = 2 * torch.randn(*shape, generator=generator)
    weights = torch.randn(args.seeds, args.width, args.width, generator=generator)
    x_numpy, out = x.numpy(), np.empty(shape, dtype=np.float32)
    rows = []
    for name, call in [
        ("torch.tanh", lambda: torch.tanh(x)),
        ("np.tanh", lambda: np.tanh(x_numpy, out=out)),
        ("fast_tanh", lambda: tanh_array(x_numpy, out=out)),
    ]:
        per_element = seconds_per_call(call, args.repeats) / x.numel()
        rows.append([f"{name} {list(shape)}", f"{per_element * 1e9:.2f} ns an element"])
    exact = np.tanh(x_numpy.astype(np.float64))
    error = np.abs(tanh_array(x_numpy).astype(np.float64) - exact) / np.maximum(np.abs(exact), 1e-30)
    rows.append(["fast_tanh, largest relative error against float64 tanh", f"{error.max():.2e}"])
    bmm = seconds_per_call(lambda: torch.bmm(x, weights), args.repeats)
    flops = 2 * args.seeds * args.rows * args.width * args.width
    rows.append(
        [
            f"torch.bmm {list(shape)} x {[args.seeds, args.width, args.width]}",
            f"{flops / bmm / 1e9:.1f} GFLOP/s",
        ]
    )
    heads = torch.randn(args.seeds, args.rows, 2, generator=generator)
    for name, call in [
        ("x^T @ grad (autograd's)", lambda: torch.bmm(x.transpose(1, 2), heads)),
        ("grad^T @ x", lambda: torch.bmm(heads.transpose(1, 2), x)),
        ("grad^T @ x, fixed order (stacked_linear)", lambda: matmul(heads.transpose(1, 2), x)),
    ]:
        rows.append([f"head weight gradient, {name}", f"{seconds_per_call(call, args.repeats) * 1e3:.3f} ms"])
    y, grad = torch.relu(x[:1]), x[:1].flip(1)  # one seed's [rows, width]: DQN's single run
    for name, call in [
        ("torch.where (public fallback)", lambda: relu_gradient_by_where(grad, y)),
        ("threshold_backward (autograd's)", lambda: relu_gradient(grad, y)),
    ]:
        seconds = seconds_per_call(call, args.repeats * 20)
        rows.append([f"ReLU gradient, one seed {list(y.shape)}, {name}", f"{seconds * 1e6:.2f} us"])
    for fused in (False, None):
        seconds = seconds_per_call(adam_step(args.seeds, 9218, fused), args.repeats)
        name = "torch elementwise" if fused is False else "numba, one pass"
        rows.append([f"Adam step [{args.seeds}, 9218], {name}", f"{seconds * 1e3:.3f} ms"])
    for row in rows:
        print(*row, sep=": ", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--rows", type=int, default=128)
    parser.add_argument("--width", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--pixels", action="store_true", help="the pixel trunk and a pixel PPO update")
    parser.add_argument("--threads", type=int, default=1, help="torch's CPU threads (default: 1)")
    add_table_arguments(parser)
    args = parser.parse_args()
    measurement = Measurement(args)
    torch.set_num_threads(args.threads)
    capability = torch.backends.cpu.get_cpu_capability()
    print(f"cpu: {describe_cpu()}, torch CPU capability {capability}, {args.threads} torch thread(s)")
    if args.pixels:
        rows = pixels()
    else:
        rows = arithmetic(args) + products(args.seeds, args.repeats)
        rows += updates_by_hand(args.seeds, max(1, args.repeats // 5))
        rows += acting(args.seeds, args.repeats)
    notes = [f"torch CPU capability {capability}, {args.threads} torch thread(s)."]
    table = Table(["measure", "time"], rows, summary={"capability": capability}, notes=notes)
    print(table.markdown())
    measurement.finish(table)


if __name__ == "__main__":
    main()
