"""DQN from pixels: the convolutional Q-network, seed independence and exact resume in the batched
engine, a replay that keeps each frame once as uint8, the new settings (conv_layers, frame_difference,
optimizer, max_grad_value) each changing what they say, and a pixel run's verdict from the CLI."""

from __future__ import annotations

import dataclasses
import io
import json
import math

import numpy as np
import pytest
import torch

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.frames import StackedFrames
from cartpole.agents.dqn.population import dqn_bytes_per_seed
from cartpole.agents.dqn.q_network import QNetworkPolicy, q_network_parameters
from cartpole.agents.dqn.replay import replay_bytes
from cartpole.agents.registry import build_population, get_agent, load_policy
from cartpole.cli.main import main
from cartpole.core.errors import ConfigError
from cartpole.envs import env_info
from cartpole.training.config import resolve_config

PIXELS = "cartpole/CartPolePixels-v1"
SHAPE = (4, 30, 100)
DQN = get_agent("dqn")

TINY = DQNConfig(
    hidden_sizes=(16,),
    conv_layers=((8, 8, 4), (8, 3, 1)),
    num_envs=4,
    buffer_size=300,
    batch_size=32,
    learning_starts=16,
    gradient_steps=1,
    epsilon_decay_steps=200,
)
"""A pixel DQN small enough for a few seconds of one core."""


def population(seeds: list[int], **changes):
    return build_population(DQN, dataclasses.replace(TINY, **changes), env_info(PIXELS), seeds, "cpu")


# --- the engine -------------------------------------------------------------------------------------

VARIANTS = [
    {},
    {"frame_difference": True, "optimizer": "rmsprop", "max_grad_value": 1.0, "double_dqn": False},
    {"dueling": True, "hidden_sizes": ()},
    {"n_step": 3},
]


@pytest.mark.independence
@pytest.mark.parametrize("changes", VARIANTS)
def test_a_pixel_seed_alone_is_bit_identical_to_the_seed_in_a_population(changes):
    alone, among = population([4], **changes), population([9, 4], **changes)
    for _ in range(12):
        left, right = alone.learn()[4], among.learn()[4]
        assert left.env_steps == right.env_steps and left.scalars == right.scalars
    assert left.scalars["train/gradient_steps"] > 0
    assert torch.equal(alone.net.flat[0], among.net.flat[1])
    assert not torch.equal(among.net.flat[0], among.net.flat[1])
    # The greedy actor of evaluations acts as the seed's own policy (a frozen torch copy) does.
    observations = alone.episodes.envs.observations()
    assert observations.dtype == np.uint8 and observations.shape == (4, *SHAPE)
    policy = alone.seed_policy(4)
    assert isinstance(policy, QNetworkPolicy) and policy.torch_net is not None
    act = among.greedy_actor([9, 4])
    both = np.concatenate([among.episodes.envs.observations()[:4], observations])
    assert np.array_equal(act(both, np.array([0, 1]))[4:], policy.act(observations))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_pixel_population_trains_on_cuda_and_its_checkpoints_load_on_the_cpu():
    on_gpu = build_population(DQN, TINY, env_info(PIXELS), [4, 9], "cuda")
    assert on_gpu.replay.frames is not None and on_gpu.replay.frames.frames.device.type == "cuda"
    for _ in range(12):
        result = on_gpu.learn()[4]
    assert result.scalars["train/gradient_steps"] > 0 and math.isfinite(result.scalars["train/loss"])
    observations = on_gpu.episodes.envs.observations()
    actions = on_gpu.greedy_actor([4])(observations[:4], np.array([0]))
    assert actions.shape == (4,) and set(actions.tolist()) <= {0, 1}
    tensors, data = through_a_checkpoint_file(*on_gpu.seed_state_dict(4, resume=True))
    assert all(t.device.type == "cpu" for t in tensors.values())
    on_cpu = build_population(DQN, TINY, env_info(PIXELS), [4], "cpu")
    on_cpu.load_seed_state_dict(4, tensors, data)
    assert torch.equal(on_cpu.net.flat[0], on_gpu.net.flat[0].cpu())
    rows = torch.arange(int(on_cpu.replay.size[0])).unsqueeze(0)
    read_on_gpu = on_gpu.replay.gather_images(rows.repeat(2, 1).cuda())
    for here, there in zip(on_cpu.replay.gather_images(rows), read_on_gpu, strict=True):
        assert torch.equal(here[0], there[0].cpu())
    on_cpu.learn()  # and it trains on from there


def through_a_checkpoint_file(tensors: dict[str, torch.Tensor], data: dict) -> tuple[dict, dict]:
    """What a checkpoint holds after ``torch.save`` and a ``weights_only`` load (data as JSON)."""
    buffer = io.BytesIO()
    torch.save(tensors, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True), json.loads(json.dumps(data))


@pytest.mark.parametrize("changes", [VARIANTS[0], VARIANTS[1], VARIANTS[3]])
def test_a_pixel_run_stopped_and_resumed_is_the_run_never_stopped(changes):
    whole, first = population([3], **changes), population([3], **changes)
    steps = [whole.learn()[3].scalars for _ in range(24)]
    for _ in range(12):
        first.learn()
    tensors, data = through_a_checkpoint_file(*first.seed_state_dict(3, resume=True))
    assert tensors["replay.frames"].dtype == torch.uint8
    assert tensors["replay.frame_index"].shape == (2, first.replay.size[0], SHAPE[0])
    resumed = population([3], **changes)
    resumed.load_seed_state_dict(3, tensors, data)
    assert [resumed.learn()[3].scalars for _ in range(12)] == steps[12:]
    assert torch.equal(resumed.net.flat, whole.net.flat)
    assert torch.equal(resumed.net.target, whole.net.target)
    rows = torch.arange(int(whole.replay.size[0])).unsqueeze(0)
    for resumed_pixels, whole_pixels in zip(
        resumed.replay.gather_images(rows), whole.replay.gather_images(rows), strict=True
    ):
        assert torch.equal(resumed_pixels, whole_pixels)


def test_a_checkpoint_whose_replay_holds_frame_stacks_is_refused_in_one_line():
    """Checkpoints written before the replay kept each frame once hold both stacks of every row."""
    first = population([3])
    for _ in range(6):
        first.learn()
    tensors, data = first.seed_state_dict(3, resume=True)
    size = int(first.replay.size[0])
    tensors = {k: v for k, v in tensors.items() if k not in ("replay.frames", "replay.frame_index")}
    stacks = torch.zeros(size, *SHAPE, dtype=torch.uint8)
    tensors |= {"replay.observations": stacks, "replay.next_observations": stacks}
    with pytest.raises(ConfigError, match="cannot be resumed; train again with --from-scratch") as info:
        population([3]).load_seed_state_dict(3, tensors, data)
    assert "\n" not in str(info.value)


def test_a_seed_leaving_the_population_keeps_the_others_replay():
    among, alone = population([9, 4]), population([4])
    for _ in range(8):
        among.learn()
        alone.learn()
    among.remove([9])
    for _ in range(6):
        assert among.learn()[4].scalars == alone.learn()[4].scalars
    assert torch.equal(among.net.flat, alone.net.flat)


# --- the settings -----------------------------------------------------------------------------------


def test_the_replay_keeps_each_frame_once_as_uint8_and_the_memory_estimate_counts_them():
    env, sizes = env_info(PIXELS), (5_000, 20_000)
    pops = [population([0], buffer_size=n) for n in sizes]
    configs = [dataclasses.replace(TINY, buffer_size=n) for n in sizes]
    frame = math.prod(SHAPE[1:])
    for pop, config in zip(pops, configs, strict=True):
        assert pop.replay.frames is not None and pop.replay.frames.frames.dtype == torch.uint8
        assert pop.replay.nbytes == replay_bytes(config, env)
        assert pop.replay.nbytes < config.buffer_size * 2 * frame  # under 2 frames a row, not 2 x 4
        assert pop.replay.nbytes <= dqn_bytes_per_seed(config, env)
    # What 15,000 more transitions cost, in the estimate and in the store: within 1%.
    estimated = dqn_bytes_per_seed(configs[1], env) - dqn_bytes_per_seed(configs[0], env)
    measured = pops[1].replay.nbytes - pops[0].replay.nbytes
    assert measured <= estimated <= 1.01 * measured
    # n-step windows hold each env's last frame stacks, as uint8 too.
    windows = population([0, 1], n_step=3).windows
    assert windows is not None and windows.observations.dtype == np.uint8
    held = sum(a.nbytes for a in (windows.observations, windows.actions, windows.rewards, windows.count))
    n_step = dataclasses.replace(TINY, n_step=3)
    replays = replay_bytes(n_step, env) - replay_bytes(TINY, env)  # n-step rows: more frames looked up
    assert dqn_bytes_per_seed(n_step, env) - dqn_bytes_per_seed(TINY, env) == held // 2 + replays
    big, replay = pops[1], pops[1].replay
    # It holds the frame stacks the envs showed, unchanged: obs, and next obs.
    shown = big.episodes.envs.observations().copy()
    big.learn()
    observations, next_observations = replay.gather_images(torch.arange(4).unsqueeze(0))
    assert np.array_equal(observations[0].numpy(), shown)
    assert np.array_equal(next_observations[0].numpy(), big.episodes.envs.observations())


@pytest.mark.parametrize("n_step", [1, 3])
def test_the_frames_read_back_are_the_stacks_written_through_episode_ends_and_full_rings(n_step):
    """Each frame once, found by content: every row reads back the stacks it was given, bit for bit,
    after many episodes (a reset fills a stack with one frame) and after both rings went round."""
    pop = population([0, 1], buffer_size=300, n_step=n_step)
    written: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    original = StackedFrames.write

    def recording(self, seed_rows, slots, env_columns, observations, next_observations, live_rows):
        for k, (seed, slot) in enumerate(zip(seed_rows.tolist(), slots.tolist(), strict=True)):
            written[seed, slot] = (observations[k].copy(), next_observations[k].copy())
        original(self, seed_rows, slots, env_columns, observations, next_observations, live_rows)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(StackedFrames, "write", recording)
        for _ in range(200):
            pop.learn()
    replay = pop.replay
    assert replay.frames is not None and (replay.size == 300).all()
    assert (replay.frames.serial > replay.frames.frame_capacity).all()  # the frame ring went round too
    observations, next_observations = replay.gather_images(torch.arange(300).repeat(2, 1))
    for (seed, slot), (obs, next_obs) in written.items():
        assert np.array_equal(observations[seed, slot].numpy(), obs)
        assert np.array_equal(next_observations[seed, slot].numpy(), next_obs)


def test_conv_layers_make_the_network():
    env = env_info(PIXELS)
    default, deeper = population([0]), population([0], conv_layers=((8, 5, 2), (8, 5, 2), (8, 5, 2)))
    for pop, layers in ((default, TINY.conv_layers), (deeper, ((8, 5, 2),) * 3)):
        config = dataclasses.replace(TINY, conv_layers=layers)
        assert pop.net.size == q_network_parameters(config, env)
        convs = [
            shape for name, shape in pop.net.shapes.items() if name.startswith("conv.") and len(shape) == 4
        ]
        channels = [SHAPE[0]] + [filters for filters, _, _ in layers[:-1]]
        assert convs == [(f, c, k, k) for (f, k, _), c in zip(layers, channels, strict=True)]
    assert default.net.size != deeper.net.size


def stacks_differing_in(frame: int) -> np.ndarray:
    """Two frame stacks, equal but for frame ``frame`` (0: oldest, 3: newest)."""
    rng = np.random.default_rng(0)
    stack = rng.integers(0, 256, SHAPE, dtype=np.uint8)
    other = stack.copy()
    other[frame] = rng.integers(0, 256, SHAPE[1:], dtype=np.uint8)
    return np.stack([stack, other])


@pytest.mark.parametrize("frame_difference", [False, True])
def test_frame_difference_shows_the_net_only_the_last_two_frames(frame_difference):
    policy = population([0], frame_difference=frame_difference).seed_policy(0)

    def differ(frame: int) -> bool:
        q = policy.scores(stacks_differing_in(frame))
        return not np.array_equal(q[0], q[1])

    assert differ(2) and differ(3)  # the frame before the last, and the last
    assert differ(0) is not frame_difference  # an older frame: seen only in the whole stack
    assert differ(1) is not frame_difference


def test_optimizer_and_max_grad_value_change_the_update():
    def first_update(**changes) -> tuple[torch.Tensor, float]:
        pop = population([0], learning_starts=4, lr=1e-3, **changes)
        before = pop.net.flat.clone()
        while pop.learn()[0].scalars["train/gradient_steps"] < 1:
            pass
        return (pop.net.flat - before).abs(), float(pop.net.grad.abs().max())

    adam, adam_grad = first_update()
    rmsprop, _ = first_update(optimizer="rmsprop")
    # Adam's first step moves a weight by lr at most; RMSprop's by lr / sqrt(1 - alpha) = 10 lr.
    assert adam.max() <= 1.001e-3 < 5e-3 < rmsprop.max() <= 1.001e-2
    _, clamped = first_update(max_grad_value=adam_grad / 10)
    assert clamped == pytest.approx(adam_grad / 10, rel=1e-6)  # the largest values clamped


@pytest.mark.parametrize(
    ("env_id", "overrides", "message"),
    [
        ("CartPole-v1", {"frame_difference": True}, "frame_difference needs image observations"),
        (PIXELS, {"conv_layers": ((16, 50, 1),)}, "conv_layers [[16, 50, 1]] shrink"),
        (PIXELS, {"conv_layers": ((16, 8),)}, "conv_layers must be [filters, kernel size, stride]"),
        (PIXELS, {"conv_layers": ((16, 0, 1),)}, "conv_layers must be"),
        (PIXELS, {"optimizer": "sgd"}, "optimizer must be one of adam, rmsprop"),
        (PIXELS, {"max_grad_value": 0.0}, "max_grad_value must be > 0"),
    ],
)
def test_bad_pixel_settings_are_refused_in_one_line(env_id, overrides, message):
    with pytest.raises(ConfigError) as info:
        build_population(DQN, dataclasses.replace(TINY, **overrides), env_info(env_id), [0], "cpu")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_frame_difference_on_a_flat_env_is_refused_before_a_run_folder(tmp_path, capsys):
    runs = tmp_path / "runs"
    args = ["train", "dqn", "--env", "CartPole-v1", "--set", "frame_difference=true"]
    assert main([*args, "--runs-dir", str(runs), "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "frame_difference needs image observations" in lines[0], lines
    assert not runs.exists() or not any(runs.iterdir())


def test_the_pixel_presets_resolve():
    config, settings = resolve_config("dqn", DQNConfig, "tutorial-pytorch-pixels")
    assert config.frame_difference and config.conv_layers == ((16, 5, 2), (32, 5, 2), (32, 5, 2))
    assert (config.optimizer, config.lr, config.batch_size, config.gamma) == ("rmsprop", 0.01, 128, 0.999)
    assert config.hidden_sizes == () and config.max_grad_value == 1.0 and settings.budget == "50ep"
    pixels, settings = resolve_config("dqn", DQNConfig, "pixels")
    assert pixels.double_dqn and pixels.dueling and settings.budget == "85k"
    assert (pixels.buffer_size, pixels.lr_schedule, pixels.schedule_steps) == (100_000, "linear", 85_000)
    assert pixels.lr == 2e-3
    assert (pixels.n_step, pixels.gamma, settings.eval_every) == (3, 0.985, 2000)
    assert settings.confirm_solves
    assert dqn_bytes_per_seed(pixels, env_info(PIXELS)) < 1.5e9


# --- the CLI ----------------------------------------------------------------------------------------


def test_train_the_tutorials_pixel_dqn_and_get_a_verdict(tmp_path, capsys):
    runs = tmp_path / "runs"
    args = ["train", "dqn", "--env", PIXELS, "--preset", "tutorial-pytorch-pixels", "--budget", "200"]
    quick = ["--set", "batch_size=32"]  # its 128-row batches take a second a dozen on one core
    code = main([*args, *quick, "--seed", "0", "--runs-dir", str(runs), "--quiet"])
    assert code == 0, capsys.readouterr().err
    (run,) = runs.iterdir()
    verdict = json.loads((run / "eval.json").read_text())
    assert (verdict["env_id"], verdict["simulator"], verdict["episodes"]) == (PIXELS, "gymnasium", 100)
    policy = load_policy(run)
    assert isinstance(policy, QNetworkPolicy) and policy.torch_net is not None
    stacks = stacks_differing_in(3)
    assert policy.act(stacks).shape == (2,) and policy.scores(stacks).shape == (2, 2)
