"""CartPole from pixels with the actor-critic agents: the convolutional trunk, seed independence in
the batched engine, the pixel envs they train on, honest verdicts on Gymnasium's own pictures, and
one-line refusals from the agents that have no convolutional network (DQN's pixels:
tests/test_dqn_pixels.py)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from cartpole.agents.actor_critic.a2c import A2CConfig
from cartpole.agents.actor_critic.network import (
    CONV_LAYERS,
    ActorCritic,
    CategoricalPolicy,
    TorchActor,
    parameter_count,
)
from cartpole.agents.actor_critic.ppo import PPOConfig, ppo_bytes_per_seed
from cartpole.agents.actor_critic.reinforce import ReinforceConfig
from cartpole.agents.registry import build_population, get_agent, load_policy
from cartpole.cli.main import main
from cartpole.envs import env_info
from cartpole.envs.pixels import GymnasiumPixels, render_frames
from cartpole.envs.seed_envs import PixelSeedEnvs, make_seed_envs
from cartpole.evaluation import evaluate, start_states

PIXELS = "cartpole/CartPolePixels-v1"
SHAPE = (4, 30, 100)


# --- the network ------------------------------------------------------------------------------------


def test_env_info_describes_images_by_shape():
    info = env_info(PIXELS)
    assert info.obs_shape == SHAPE and info.is_image and info.obs_dim == math.prod(SHAPE)
    assert info.pixels_of == "CartPole-v1" and not info.is_cartpole
    flat = env_info("CartPole-v1")
    assert flat.obs_shape == (4,) and not flat.is_image and flat.pixels_of is None


def test_an_image_trunk_starts_with_the_conv_layers_and_its_parameters_are_named_so():
    model = ActorCritic(SHAPE, 2, (64,), shared_trunk=False, generator=torch.Generator().manual_seed(0))
    shapes = {name: tuple(p.shape) for name, p in model.named_parameters()}
    (f1, k1, _), (f2, k2, _) = CONV_LAYERS
    for trunk in ("actor_trunk", "critic_trunk"):
        assert shapes[f"{trunk}.1.weight"] == (f1, 4, k1, k1)
        assert shapes[f"{trunk}.3.weight"] == (f2, f1, k2, k2)
        assert shapes[f"{trunk}.6.weight"] == (64, 32 * 4 * 22)  # 30x100 -> 6x24 -> 4x22
    assert sum(p.numel() for p in model.parameters()) == parameter_count(SHAPE, 2, (64,), False)
    shared = ActorCritic(SHAPE, 2, (64,), shared_trunk=True)
    assert not any(name.startswith("critic_trunk") for name, _ in shared.named_parameters())
    assert sum(p.numel() for p in shared.parameters()) == parameter_count(SHAPE, 2, (64,), True)


def test_the_conv_layers_are_initialized_orthogonally_from_the_generator():
    def build(seed: int) -> ActorCritic:
        return ActorCritic(SHAPE, 2, (64,), generator=torch.Generator().manual_seed(seed))

    model = build(3)
    for trunk in (model.actor_trunk, model.critic_trunk):
        for layer in (trunk[1], trunk[3]):
            rows = layer.weight.detach().reshape(layer.weight.shape[0], -1)  # filters x inputs
            assert torch.allclose(rows @ rows.T, 2.0 * torch.eye(rows.shape[0]), atol=1e-4)  # gain sqrt(2)
            assert torch.count_nonzero(layer.bias) == 0
    assert torch.equal(build(3).actor_trunk[1].weight, model.actor_trunk[1].weight)
    assert not torch.equal(build(4).actor_trunk[1].weight, model.actor_trunk[1].weight)


def test_the_network_scales_uint8_pixels_itself_and_its_policy_acts_through_torch():
    model = ActorCritic(SHAPE, 2, (64,), generator=torch.Generator().manual_seed(1))
    pixels = torch.randint(0, 256, (5, *SHAPE), dtype=torch.uint8, generator=torch.Generator().manual_seed(2))
    logits, values = model(pixels)
    assert logits.shape == (5, 2) and values.shape == (5,)
    assert torch.equal(logits, model(pixels.float())[0])  # uint8 or float gray levels: the same
    policy = CategoricalPolicy(model)
    assert isinstance(policy.logits, TorchActor)
    actions = policy.act(pixels.numpy())
    assert actions.shape == (5,) and np.array_equal(actions, logits.argmax(dim=1).numpy())
    with torch.no_grad():
        model.policy_head.bias.add_(100.0)  # the policy is a frozen copy
    assert np.array_equal(policy.act(pixels.numpy()), actions)


# --- the engine -------------------------------------------------------------------------------------

TINY = PPOConfig(
    num_envs=4, n_steps=16, minibatch_size=16, n_epochs=2, hidden_sizes=(16,), shared_trunk=False
)
"""Rows of every batch a multiple of 4 ((16 + 1) x 4 for the values): see StackedActorCritic."""
TINY_CONFIGS = {
    "ppo": TINY,
    "a2c": A2CConfig(num_envs=4, n_steps=8, hidden_sizes=(16,), shared_trunk=True),
    "reinforce": ReinforceConfig(num_envs=4, hidden_sizes=(16,)),
}


@pytest.mark.independence
@pytest.mark.parametrize("agent", sorted(TINY_CONFIGS))
def test_a_pixel_seed_alone_is_bit_identical_to_the_seed_in_a_population(agent):
    spec, env = get_agent(agent), env_info(PIXELS)
    alone = build_population(spec, TINY_CONFIGS[agent], env, [4], "cpu")
    among = build_population(spec, TINY_CONFIGS[agent], env, [9, 4], "cpu")
    for _ in range(3):
        left, right = alone.learn()[4], among.learn()[4]
        assert left.env_steps == right.env_steps and left.scalars == right.scalars
    assert torch.equal(alone.model.flat[0], among.model.flat[1])
    assert not torch.equal(among.model.flat[0], among.model.flat[1])
    observations = alone.episodes.envs.observations()
    assert observations.dtype == np.uint8 and observations.shape == (4, *SHAPE)
    # The stacked greedy actor acts as the seed's own policy does.
    act = among.greedy_actor([4])
    assert np.array_equal(act(observations, np.array([0])), alone.seed_policy(4).act(observations))


@pytest.mark.parametrize("shared_trunk", [False, True])
def test_an_update_sees_the_logits_and_values_of_each_seeds_own_network(shared_trunk):
    """The batched forward pass of an update (channels-last, a shared trunk run once for both heads)
    computes what each seed's nn.Module computes."""
    config = PPOConfig(num_envs=4, n_steps=4, hidden_sizes=(16,), shared_trunk=shared_trunk)
    population = build_population(get_agent("ppo"), config, env_info(PIXELS), [3, 5], "cpu")
    pixels = torch.randint(
        0, 256, (2, 6, *SHAPE), dtype=torch.uint8, generator=torch.Generator().manual_seed(2)
    )
    logits, values = population.model.forward_for_update(pixels)
    for row in range(2):
        own_logits, own_values = population.model.unstack(row)(pixels[row])
        torch.testing.assert_close(logits[row], own_logits, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(values[row], own_values, rtol=1e-5, atol=1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("agent", sorted(TINY_CONFIGS))
def test_a_pixel_population_trains_on_cuda_and_its_checkpoints_load_on_the_cpu(agent):
    spec, env = get_agent(agent), env_info(PIXELS)
    on_gpu = build_population(spec, TINY_CONFIGS[agent], env, [4, 9], "cuda")
    assert on_gpu.model.flat.device.type == "cuda"
    for _ in range(3):
        assert on_gpu.learn()[4].env_steps > 0
    observations = on_gpu.episodes.envs.observations()
    actions = on_gpu.greedy_actor([4])(observations[:4], np.array([0]))
    tensors, data = on_gpu.seed_state_dict(4, resume=True)
    assert all(t.device.type == "cpu" for t in tensors.values())
    on_cpu = build_population(spec, TINY_CONFIGS[agent], env, [4], "cpu")
    on_cpu.load_seed_state_dict(4, tensors, data)
    assert torch.equal(on_cpu.model.flat[0], on_gpu.model.flat[0].cpu())
    assert actions.shape == (4,) and set(actions.tolist()) <= {0, 1}


def test_pixel_seed_envs_draw_frame_stacks_and_resume_them():
    envs = make_seed_envs(env_info(PIXELS), "fast", [1, 2], 3)
    assert isinstance(envs, PixelSeedEnvs)
    for _ in range(5):
        observations, *_ = envs.step(np.ones(6, dtype=np.int64))
    assert observations.shape == (6, *SHAPE) and observations.dtype == np.uint8
    assert not np.array_equal(observations[:, 0], observations[:, -1])  # the stack moves
    saved = json.loads(json.dumps(envs.seed_state(1)))
    again = make_seed_envs(env_info(PIXELS), "fast", [1, 2], 3)
    again.load_seed_state(1, saved)
    assert np.array_equal(again.observations()[3:], observations[3:])
    actions = np.zeros(6, dtype=np.int64)
    assert np.array_equal(again.step(actions)[0][3:], envs.step(actions)[0][3:])


def test_the_memory_estimate_counts_the_pixels():
    flat, pixels = env_info("CartPole-v1"), env_info(PIXELS)
    small = ppo_bytes_per_seed(TINY, pixels)
    assert small > ppo_bytes_per_seed(TINY, flat)
    longer = PPOConfig(**{**TINY.__dict__, "n_steps": 1024})
    # at least the uint8 pixels of the longer rollout (and their conv activations)
    assert ppo_bytes_per_seed(longer, pixels) - small >= (1024 - 16) * 2 * math.prod(SHAPE)


# --- evaluation -------------------------------------------------------------------------------------


class FirstLook:
    """A policy that pushes left and keeps the first observations it is shown."""

    def __init__(self) -> None:
        self.first: np.ndarray | None = None

    def act(self, observations: np.ndarray) -> np.ndarray:
        if self.first is None:
            self.first = np.asarray(observations).copy()
        return np.zeros(len(observations), dtype=np.int64)


@pytest.mark.parametrize("simulator", ["fast", "gymnasium"])
def test_evaluations_of_pixels_start_where_gymnasiums_cartpole_starts(simulator):
    seeds = [2**32 + 7, 2**32 + 8, 2**32 + 9]
    policy = FirstLook()
    evaluate(policy, PIXELS, len(seeds), seed=seeds[0], simulator=simulator)
    assert policy.first is not None and policy.first.shape == (3, *SHAPE) and policy.first.dtype == np.uint8
    if simulator == "fast":  # our renderer's frames of Gymnasium's start states, the stack filled with them
        frames = render_frames(start_states("CartPole-v1", seeds))
        assert np.array_equal(policy.first, np.repeat(frames[:, None], SHAPE[0], axis=1))
    else:  # Gymnasium's own pictures of its reset(seed=s)
        for seed, seen in zip(seeds, policy.first, strict=True):
            env = GymnasiumPixels(gym.make("CartPole-v1", render_mode="rgb_array"))
            try:
                assert np.array_equal(seen, env.reset(seed=seed)[0])
            finally:
                env.close()


def test_train_and_eval_a_pixel_ppo_judge_it_on_gymnasiums_pictures(tmp_path, monkeypatch, capfd):
    """Trained and judged from pixels; on images `cartpole train` leaves torch's thread count as
    it is (torch's own default: one per core), and that many processes draw the verdict's pictures,
    without SDL's complaint about a missing desktop session (capfd: the workers write to this
    process's stderr)."""
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.delenv("SDL_VIDEODRIVER", raising=False)
    runs = tmp_path / "runs"
    args = ["train", "ppo", "--env", PIXELS, "--preset", "pixels", "--seed", "3", "--budget", "512"]
    settings = ["n_steps=16", "num_envs=4", "minibatch_size=64", "eval_every=100000"]
    torch.set_num_threads(2)
    drawn_here = count_gymnasium_pictures(monkeypatch)
    code = main([*args, "--runs-dir", str(runs), "--quiet", *[x for s in settings for x in ("--set", s)]])
    err = capfd.readouterr().err
    assert code == 0, err
    assert torch.get_num_threads() == 2 and drawn_here() == 0  # 2 worker processes drew them
    assert "XDG_RUNTIME_DIR" not in err
    (run,) = runs.iterdir()
    verdict = json.loads((run / "eval.json").read_text())
    assert (verdict["env_id"], verdict["simulator"], verdict["episodes"]) == (PIXELS, "gymnasium", 100)
    assert isinstance(load_policy(run), CategoricalPolicy)
    seen: list[tuple[tuple[int, ...], np.dtype]] = []
    original = TorchActor.__call__

    def recording(self: TorchActor, observations: np.ndarray) -> np.ndarray:
        seen.append((np.asarray(observations).shape[1:], np.asarray(observations).dtype))
        return original(self, observations)

    monkeypatch.setattr(TorchActor, "__call__", recording)
    capfd.readouterr()
    assert main(["eval", str(run), "--episodes", "3", "--json"]) == 0
    report = json.loads(capfd.readouterr().out)
    assert (report["env_id"], report["simulator"], report["episodes"]) == (PIXELS, "gymnasium", 3)
    assert all(shape == SHAPE for shape, _ in seen)  # frame stacks, never states
    assert sum(dtype == np.uint8 for _, dtype in seen) >= 3  # the episodes' frames (uint8, unscaled)


def count_gymnasium_pictures(monkeypatch: pytest.MonkeyPatch) -> Callable[[], int]:
    """Counts the pictures Gymnasium's CartPole draws in this process from now on."""
    from gymnasium.envs.classic_control.cartpole import CartPoleEnv

    drawn = 0
    original = CartPoleEnv.render

    def render(self: CartPoleEnv) -> Any:
        nonlocal drawn
        drawn += 1
        return original(self)

    monkeypatch.setattr(CartPoleEnv, "render", render)
    return lambda: drawn


# --- agents without a convolutional network --------------------------------------------------------


@pytest.mark.parametrize("agent", ["cem", "random-search", "hill-climbing"])
def test_agents_without_a_conv_network_refuse_pixels_in_one_line(agent, tmp_path, capsys):
    runs = tmp_path / "runs"
    code = main(["train", agent, "--env", PIXELS, "--runs-dir", str(runs), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{agent} has no convolutional network yet" in err and "ppo" in err and PIXELS in err
    assert "dqn" in err  # DQN learns from pixels too (tests/test_dqn_pixels.py)
    assert not runs.exists() or not any(Path(runs).iterdir())


@pytest.mark.slow  # about 30 s: three short pixel runs, each with its verdict on Gymnasium's pictures
def test_a_pixel_run_stopped_and_resumed_trains_the_rows_of_a_run_never_stopped(tmp_path):
    """Resume restores the frame stacks too: the interrupted run's training rows are the whole run's."""
    from cartpole.training import resume, train

    settings = {
        "num_envs": 4,
        "n_steps": 16,
        "minibatch_size": 64,
        "hidden_sizes": (16, 16),
        "eval_every": 10**9,
    }
    whole = train(
        "ppo", PIXELS, seed=3, preset="pixels", overrides=settings, budget="768", runs_dir=tmp_path / "a"
    )
    interrupted = train(
        "ppo", PIXELS, seed=3, preset="pixels", overrides=settings, budget="320", runs_dir=tmp_path / "b"
    )
    run = interrupted.run
    config = run.config()  # as if the 320-step run had been interrupted on the way to 768
    config["budget"] = whole.run.config()["budget"]
    run.write_config(config)
    run.write_status(run.status() | {"state": "interrupted"})
    finished = resume(run.path)

    def train_rows(rows: list[dict]) -> list[dict]:
        return [
            {k: v for k, v in r.items() if k not in ("time", "time/sps")}
            for r in rows
            if "train/updates" in r
        ]

    assert len(train_rows(whole.run.metrics())) >= 10
    assert train_rows(run.metrics()) == train_rows(whole.run.metrics())
    assert (
        finished.state.env_steps == whole.state.env_steps and finished.state.episodes == whole.state.episodes
    )


def test_pictures_are_drawn_by_as_many_processes_as_torch_threads_at_most_four():
    from cartpole.training.engine import MAX_PICTURE_WORKERS, picture_workers

    assert MAX_PICTURE_WORKERS == 4
    torch.set_num_threads(3)
    assert picture_workers() == 3
    torch.set_num_threads(16)  # each worker holds its own imports: a big machine gets 4, not 16
    assert picture_workers() == 4
