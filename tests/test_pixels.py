"""CartPole from pixels: our frames against Gymnasium's own pictures, and the envs around them."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # pygame without a display

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from numpy.typing import NDArray

import cartpole  # noqa: F401  (the import registers the envs)
from cartpole.core.errors import ConfigError
from cartpole.envs.fast import CartPoleEnv, CartPoleParams, CartPoleVectorEnv
from cartpole.envs.pixels import (
    DEFAULT_FRAME_SIZE,
    DEFAULT_STACK,
    CartPolePixelsEnv,
    CartPolePixelsVectorEnv,
    GymnasiumPixels,
    PixelRenderer,
    preprocess_frames,
    render_frames,
    screen_window,
)

pytest.importorskip("pygame")

# What "the same frame" means (gray levels, 0-255): the renderer models pygame's anti-aliased polygon
# outlines instead of drawing them, so edge pixels differ by a few levels; measured at the default
# size: mean 0.015-0.02, max 9 within the termination bounds and 12 beyond them (pole corners, and
# the pole's edge where the cart leaves the screen).
MEAN_TOLERANCE = 0.1
MAX_TOLERANCE = 16
MOST_TOLERANCE = 4  # all but 0.1% of the pixels
X_THRESHOLD, THETA_THRESHOLD = 2.4, 12 * 2 * np.pi / 360


@pytest.fixture(scope="module")
def gymnasium_env() -> Iterator[gym.Env[NDArray[np.float32], int]]:
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    yield env
    env.close()


def pictures(env: gym.Env[NDArray[np.float32], int], states: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Gymnasium's own rgb_array pictures of ``states``."""
    unwrapped: Any = env.unwrapped
    out = []
    for state in states:
        unwrapped.state = state
        out.append(np.asarray(env.render(), dtype=np.uint8))
    return np.stack(out)


def random_states(seed: int, n: int, beyond: float) -> NDArray[np.float64]:
    """``n`` states with |x| and |theta| up to ``beyond`` times the termination bounds."""
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [
            rng.uniform(-beyond * X_THRESHOLD, beyond * X_THRESHOLD, n),
            rng.normal(0.0, 1.0, n),
            rng.uniform(-beyond * THETA_THRESHOLD, beyond * THETA_THRESHOLD, n),
            rng.normal(0.0, 1.0, n),
        ]
    )


def assert_same_frames(ours: NDArray[np.uint8], reference: NDArray[np.uint8]) -> None:
    diff = np.abs(ours.astype(np.int16) - reference.astype(np.int16))
    assert diff.mean() < MEAN_TOLERANCE, diff.mean()
    assert diff.max() <= MAX_TOLERANCE, (diff.max(), np.unravel_index(diff.argmax(), diff.shape))
    assert (diff > MOST_TOLERANCE).mean() < 1e-3, (diff > MOST_TOLERANCE).mean()


@pytest.mark.parametrize(("seed", "beyond"), [(0, 1.0), (1, 1.0), (2, 1.25), (3, 1.6)])
@pytest.mark.parametrize("frame_size", [DEFAULT_FRAME_SIZE, (40, 60), (16, 64)])
def test_frames_match_gymnasiums_pictures(
    gymnasium_env: gym.Env[NDArray[np.float32], int],
    seed: int,
    beyond: float,
    frame_size: tuple[int, int],
) -> None:
    states = random_states(seed, 60, beyond)
    reference = preprocess_frames(pictures(gymnasium_env, states), frame_size)
    assert_same_frames(render_frames(states, frame_size), reference)


def test_frames_follow_the_pole_length_and_track_width(
    gymnasium_env: gym.Env[NDArray[np.float32], int],
) -> None:
    params = CartPoleParams(length=0.45, x_threshold=2.0)
    unwrapped: Any = gymnasium_env.unwrapped
    unwrapped.length, unwrapped.x_threshold = params.length, params.x_threshold
    try:
        states = random_states(4, 30, 1.0) * np.array([2.0 / 2.4, 1, 1, 1])
        reference = preprocess_frames(pictures(gymnasium_env, states))
    finally:
        unwrapped.length, unwrapped.x_threshold = 0.5, 2.4
    assert_same_frames(PixelRenderer(params=params).render(states), reference)
    with pytest.raises(ConfigError, match="pole"):
        PixelRenderer(params=CartPoleParams(length=1.5))  # its tip would leave the frame's band


def test_the_pole_angle_and_cart_position_show() -> None:
    upright = render_frames(np.zeros((1, 4)))[0].astype(int)
    for state in ([0, 0, 0.1, 0], [0, 0, -0.1, 0], [0.05, 0, 0, 0], [0, 1, 0, 1]):
        frame = render_frames(np.array([state]))[0].astype(int)
        changed = np.abs(frame - upright).sum()
        if state[1]:  # velocities do not show in one frame
            assert changed == 0
        else:
            assert changed > 500, (state, changed)
    left, right = render_frames(np.array([[0, 0, -0.1, 0], [0, 0, 0.1, 0]])).astype(int)
    assert np.abs(left - right).sum() > 2000
    # The pole leans the way theta says: right of the pivot for theta > 0 in the upper rows.
    upper = slice(0, DEFAULT_FRAME_SIZE[0] // 3)
    columns = np.arange(DEFAULT_FRAME_SIZE[1])
    ink_right = (255 - right[upper]).sum(axis=0) @ columns / (255 - right[upper]).sum()
    ink_left = (255 - left[upper]).sum(axis=0) @ columns / (255 - left[upper]).sum()
    assert ink_right > DEFAULT_FRAME_SIZE[1] / 2 > ink_left


def test_preprocess_frames_is_gray_and_a_box_average_as_pillow_computes_them(
    gymnasium_env: gym.Env[NDArray[np.float32], int],
) -> None:
    from PIL import Image

    rgb = pictures(gymnasium_env, random_states(5, 4, 1.0))
    # Whole screen pixels per output pixel: Pillow's box filter takes a screen pixel whole or not at
    # all, where ours weighs it by the part of it inside the output pixel.
    for frame_size in (DEFAULT_FRAME_SIZE, (40, 60), (50, 100)):
        top, bottom = screen_window(frame_size)
        ours = preprocess_frames(rgb, frame_size)
        for picture, frame in zip(rgb, ours, strict=True):
            gray = Image.fromarray(picture).convert("L")
            reference = gray.resize(frame_size[::-1], Image.Resampling.BOX, box=(0, top, 600, bottom))
            # Pillow rounds twice (after the gray, after the average): at most one level apart.
            assert np.abs(frame.astype(int) - np.asarray(reference, dtype=int)).max() <= 1
    assert screen_window((40, 60)) == (0.0, 400.0)  # full-screen aspect: the whole picture
    top, bottom = screen_window(DEFAULT_FRAME_SIZE)
    assert bottom - top == 180 and top <= 172 and bottom >= 315  # the pole's tip to the cart's bottom
    with pytest.raises(ValueError, match="shape"):
        preprocess_frames(rgb[0])


@pytest.mark.parametrize("frame_size", [DEFAULT_FRAME_SIZE, (40, 60)])
def test_frames_of_whole_screen_pixels_are_their_blocks_mean_gray_rounded_half_up(frame_size) -> None:
    """Where an output pixel covers whole screen pixels, a frame is exactly the mean gray level of
    each block, halves rounded up (also on noise, on blocks whose mean is exactly a half, and on
    pictures laid out column by column in memory)."""
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (2, 400, 600, 3), dtype=np.uint8)
    halves = np.indices((400, 600)).sum(axis=0) % 2  # a checkerboard of gray 0 and 1: means of 0.5
    rgb = np.concatenate([noise, np.repeat(halves[None, :, :, None], 3, axis=3).astype(np.uint8)])
    height, width = frame_size
    top, pixel = int(screen_window(frame_size)[0]), 600 // width
    gray = rgb.astype(np.int64) @ np.array([299, 587, 114])
    blocks = gray[:, top : top + height * pixel].reshape(3, height, pixel, width, pixel).sum(axis=(2, 4))
    expected = (2 * blocks + 1000 * pixel * pixel) // (2000 * pixel * pixel)
    frames = preprocess_frames(rgb, frame_size)
    assert np.array_equal(frames, expected) and (frames[2] == 1).all()
    by_columns = np.ascontiguousarray(rgb.transpose(0, 2, 1, 3)).transpose(0, 2, 1, 3)  # any layout
    assert np.array_equal(preprocess_frames(by_columns, frame_size), expected)


def test_vector_env_observations_and_stacks() -> None:
    envs = CartPolePixelsVectorEnv(num_envs=5, stack=3, frame_size=(24, 80))
    assert envs.observation_space.shape == (5, 3, 24, 80)
    assert envs.single_observation_space == gym.spaces.Box(0, 255, (3, 24, 80), dtype=np.uint8)
    observations, info = envs.reset(seed=0)
    assert observations.dtype == np.uint8 and observations in envs.observation_space
    assert info == {}
    first = render_frames(envs.states, (24, 80))
    np.testing.assert_array_equal(observations, np.repeat(first[:, None], 3, axis=1))  # filled
    previous = observations
    actions = np.array([0, 1, 0, 1, 1])
    for _ in range(3):
        observations, *_ = envs.step(actions)
        assert observations in envs.observation_space
        np.testing.assert_array_equal(observations[:, :-1], previous[:, 1:])  # oldest first
        np.testing.assert_array_equal(observations[:, -1], render_frames(envs.states, (24, 80)))
        previous = observations
    envs.close()


def test_vector_env_autoresets_and_restarts_the_stack() -> None:
    envs = CartPolePixelsVectorEnv(num_envs=4, max_episode_steps=6)
    observations, _ = envs.reset(seed=1)
    actions = np.array([0, 0, 1, 1])
    done = np.zeros(4, dtype=bool)
    for step in range(20):
        observations, rewards, terminated, truncated, _ = envs.step(actions)
        newest = observations[:, -1]
        if done.any():  # the autoreset step: a new episode, its stack filled with its first frame
            assert (rewards[done] == 0).all() and not (terminated | truncated)[done].any()
            np.testing.assert_array_equal(
                observations[done], np.repeat(newest[done][:, None], DEFAULT_STACK, axis=1)
            )
        if step < 5:
            assert not truncated.any()
        done = terminated | truncated
    assert envs.unwrapped.max_episode_steps == 6
    envs.close()


def test_vector_env_is_the_state_simulator_seen_in_pixels() -> None:
    """Same seeds, same episodes: rewards, flags and states of CartPoleVectorEnv, step for step."""
    pixels = CartPolePixelsVectorEnv(num_envs=16, max_episode_steps=50)
    states = CartPoleVectorEnv(num_envs=16, max_episode_steps=50)
    pixels.reset(seed=7)
    states.reset(seed=7)
    rng = np.random.default_rng(0)
    for _ in range(120):
        actions = rng.integers(0, 2, 16)
        _, pixel_rewards, pixel_terminated, pixel_truncated, _ = pixels.step(actions)
        observations, rewards, terminated, truncated, _ = states.step(actions)
        np.testing.assert_array_equal(pixel_rewards, rewards)
        np.testing.assert_array_equal(pixel_terminated, terminated)
        np.testing.assert_array_equal(pixel_truncated, truncated)
        np.testing.assert_array_equal(pixels.states.astype(np.float32), observations)
    assert isinstance(pixels.simulator, CartPoleVectorEnv)


def test_vector_env_is_deterministic_under_reset_seed() -> None:
    def episode(seed: int) -> list[NDArray[np.uint8]]:
        envs = CartPolePixelsVectorEnv(num_envs=3)
        out = [envs.reset(seed=seed)[0]]
        for t in range(30):
            out.append(envs.step(np.array([t % 2, 1, 0]))[0])
        return out

    first, again, other = episode(3), episode(3), episode(4)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert any((a != b).any() for a, b in zip(first, other, strict=True))


@pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")  # v0, as Gymnasium's own
def test_make_and_make_vec_after_import() -> None:
    for version, reference in (("v1", "CartPole-v1"), ("v0", "CartPole-v0")):
        spec = gym.spec(f"cartpole/CartPolePixels-{version}")
        assert spec.max_episode_steps == gym.spec(reference).max_episode_steps
        assert spec.reward_threshold == gym.spec(reference).reward_threshold
    env = gym.make("cartpole/CartPolePixels-v1", stack=2, frame_size=(40, 60))
    observation, _ = env.reset(seed=0)
    assert observation.shape == (2, 40, 60) and observation in env.observation_space
    assert isinstance(env.unwrapped, CartPolePixelsEnv)
    env.close()
    envs = gym.make_vec("cartpole/CartPolePixels-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(envs.unwrapped, CartPolePixelsVectorEnv)
    assert envs.unwrapped.max_episode_steps == 200
    observations, _ = envs.reset(seed=0)
    assert observations.shape == (3, DEFAULT_STACK, *DEFAULT_FRAME_SIZE)
    envs.close()


@pytest.mark.filterwarnings("ignore:.*alternative render modes:UserWarning")
def test_single_env_passes_check_env_and_renders() -> None:
    check_env(CartPolePixelsEnv(stack=2))
    check_env(gym.make("cartpole/CartPolePixels-v1", render_mode="rgb_array").unwrapped)
    env = CartPolePixelsEnv(render_mode="rgb_array", stack=3)
    observation, _ = env.reset(seed=0)
    assert env.state is not None
    np.testing.assert_array_equal(observation, np.repeat(render_frames(env.state[None]), 3, axis=0))
    following, *_ = env.step(1)
    np.testing.assert_array_equal(following[:-1], observation[1:])
    np.testing.assert_array_equal(following[-1], render_frames(env.state[None])[0])
    picture = env.render()
    assert picture is not None and picture.shape == (400, 600, 3)  # Gymnasium's own, at full size
    assert_same_frames(following[-1:], preprocess_frames(picture[None]))
    env.close()


def test_single_env_plays_the_state_simulators_episodes() -> None:
    pixels, states = CartPolePixelsEnv(), CartPoleEnv()
    pixels.reset(seed=11)
    states.reset(seed=11)
    for t in range(40):
        _, reward, terminated, truncated, _ = pixels.step(t % 3 == 0)
        assert (reward, terminated, truncated) == states.step(int(t % 3 == 0))[1:4]
        np.testing.assert_array_equal(pixels.state, states.state)
        if terminated:
            break


def test_gymnasium_wrapper_sees_the_same_frames() -> None:
    """Gymnasium's CartPole-v1 through its own pictures, and ours through the renderer, same seed."""
    reference = GymnasiumPixels(gym.make("CartPole-v1", render_mode="rgb_array"))
    ours = CartPolePixelsEnv()  # float64: the same start states and trajectories as Gymnasium's
    assert reference.observation_space == ours.observation_space
    theirs, _ = reference.reset(seed=5)
    mine, _ = ours.reset(seed=5)
    assert theirs in reference.observation_space
    frames_theirs, frames_mine = [theirs], [mine]
    for t in range(25):
        theirs, _, terminated, truncated, _ = reference.step(t % 2)
        mine, *_ = ours.step(t % 2)
        assert theirs in reference.observation_space
        frames_theirs.append(theirs)
        frames_mine.append(mine)
        if terminated or truncated:
            break
    assert_same_frames(np.concatenate(frames_mine), np.concatenate(frames_theirs))
    reference.close()
    with pytest.raises(ConfigError, match="rgb_array"):
        GymnasiumPixels(gym.make("CartPole-v1"))


BAD_FRAME_SIZES = [(15, 60), (201, 600), (40, 700), (30, 30), (16, 100), (30.0, 100), "30x100", (30,), None]


@pytest.mark.parametrize("frame_size", BAD_FRAME_SIZES)
def test_bad_frame_sizes_are_config_errors(frame_size: Any) -> None:
    allowed = r"frame_size must be \(height, width\) in pixels with 16 <= height <= 200"
    for make in (
        lambda: CartPolePixelsVectorEnv(num_envs=-1, frame_size=frame_size),  # checked before num_envs
        lambda: CartPolePixelsEnv(frame_size=frame_size),
        lambda: GymnasiumPixels(gym.make("CartPole-v1"), frame_size=frame_size),
        lambda: gym.make("cartpole/CartPolePixels-v1", frame_size=frame_size),
        lambda: PixelRenderer(frame_size),
    ):
        with pytest.raises(ConfigError, match=allowed) as caught:
            make()
        assert "\n" not in str(caught.value)


@pytest.mark.parametrize("stack", [0, 9, -1, 2.0, True, "4"])
def test_bad_stack_depths_are_config_errors(stack: Any) -> None:
    for make in (
        lambda: CartPolePixelsVectorEnv(num_envs=-1, stack=stack),
        lambda: CartPolePixelsEnv(stack=stack),
        lambda: gym.make_vec(
            "cartpole/CartPolePixels-v1", num_envs=2, vectorization_mode="vector_entry_point", stack=stack
        ),
    ):
        with pytest.raises(ConfigError, match="stack must be an integer from 1 to 8"):
            make()


def test_edge_sizes_are_allowed() -> None:
    for frame_size, stack in (((16, 64), 1), ((200, 600), 8), ((40, 60), 2)):
        envs = CartPolePixelsVectorEnv(num_envs=2, frame_size=frame_size, stack=stack)
        observations, _ = envs.reset(seed=0)
        assert observations.shape == (2, stack, *frame_size)


def test_training_a_pixel_env_without_a_conv_network_is_refused_in_one_line(tmp_path, capsys):
    """Only the actor-critic agents and DQN have a convolutional network: asking a linear agent to
    learn from pixels is bad input, said in one line before a run folder exists
    (tests/test_pixel_agents.py and tests/test_dqn_pixels.py train the ones that can)."""
    from cartpole.cli.main import main

    runs = tmp_path / "runs"
    assert (
        main(["train", "cem", "--env", "cartpole/CartPolePixels-v1", "--runs-dir", str(runs), "--quiet"]) == 2
    )
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "cem has no convolutional network yet" in lines[0], lines
    assert not runs.exists()
