"""What a pixel agent sees, on the Watch page's episodes: its frame stacks drawn from the episode's own
states, exactly as its env draws and stacks them, sent as one base64 frame per state."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from cartpole.envs.params import CartPoleParams
from cartpole.envs.pixels import render_frames
from cartpole.web.agent_view import PixelView, decode_frames, stacks_of, view_json
from cartpole.web.episodes import play_episode
from cartpole.web.physics import PhysicsError, scene_of, start_state

sys.path.insert(0, str(Path(__file__).parent))
from conftest_web import PIXELS, local_client, make_pixel_run


class DarkSide:
    """A stub pixel policy: pushes toward the side of its newest frame that holds more dark pixels
    (where the pole leans), and records every observation it is given."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)

    def scores(self, observations: np.ndarray) -> np.ndarray:
        batch = np.asarray(observations)
        assert batch.shape[1:] == (4, 30, 100), batch.shape  # frame stacks, never states
        self.seen.extend(batch)
        darkness = 255.0 - batch[:, -1].astype(np.float64)
        left, right = darkness[:, :, :50].sum(axis=(1, 2)), darkness[:, :, 50:].sum(axis=(1, 2))
        return np.stack([left, right], axis=1) / 1e4


def test_a_pixel_episode_carries_the_frame_of_each_of_its_states():
    policy = DarkSide()
    episode, _ = play_episode(policy, PIXELS, seed=5)
    assert episode.view is not None
    assert (episode.view["stack"], episode.view["height"], episode.view["width"]) == (4, 30, 100)
    frames = decode_frames(episode.view)
    states = np.asarray(episode.states)
    assert len(frames) == len(states) == len(episode.actions) + 1
    assert np.array_equal(frames, render_frames(states))  # each step's newest frame, from its state
    # What the policy saw at step t is frames t-3..t, the first frame standing in before step 0.
    seen = np.stack(policy.seen)
    assert np.array_equal(seen, stacks_of(frames, 4)[: len(episode.actions)])
    assert all(np.array_equal(f, frames[0]) for f in seen[0])
    assert [np.array_equal(f, frames[0]) for f in seen[1][:3]] == [True, True, True]
    assert np.array_equal(seen[1][3], frames[1])
    assert episode.scores is not None and len(episode.scores) == len(episode.actions)


def test_the_stacks_are_the_ones_the_pixel_env_hands_its_agent():
    episode, _ = play_episode(DarkSide(), PIXELS, seed=7)
    stacks = stacks_of(decode_frames(episode.view or {}), 4)
    env = gym.make(PIXELS)
    try:
        observation, _ = env.reset(seed=7)  # the same start state as Gymnasium's reset(seed=7)
        assert np.array_equal(observation, stacks[0])
        for t, action in enumerate(episode.actions):
            observation, _, terminated, truncated, _ = env.step(action)
            assert np.array_equal(observation, stacks[t + 1]), t
        assert (terminated, truncated) == (episode.terminated, episode.truncated)
    finally:
        env.close()


def test_nudges_and_changed_physics_show_in_the_frames_as_the_env_would_draw_them():
    physics = {"length": 0.3, "gravity": 12.0}
    episode, _ = play_episode(DarkSide(), PIXELS, seed=2, physics=physics, nudges={1: 2.0})
    frames = decode_frames(episode.view or {})
    drawn = render_frames(np.asarray(episode.states), params=CartPoleParams(length=0.3, gravity=12.0))
    assert np.array_equal(frames, drawn)
    assert not np.array_equal(frames, render_frames(np.asarray(episode.states)))  # a shorter pole
    with pytest.raises(PhysicsError, match="cannot show a pole of half-length 2 m"):
        play_episode(DarkSide(), PIXELS, seed=2, physics={"length": 2.0})


def test_state_agents_get_no_view(balancer):
    episode, _ = play_episode(balancer, "CartPole-v1", seed=0)
    assert episode.view is None
    assert episode.to_dict({}, None)["view"] is None


def test_a_pixel_env_is_drawn_and_started_as_its_cartpole():
    assert scene_of(PIXELS) == "cartpole" and PixelView.of("CartPole-v1") is None
    assert np.array_equal(start_state(PIXELS, 11), start_state("CartPole-v1", 11))


def test_a_full_episodes_view_stays_near_two_megabytes():
    frames = list(np.random.default_rng(0).integers(0, 256, (501, 30, 100), dtype=np.uint8))
    text = json.dumps(view_json(PixelView(4, (30, 100)), frames))
    assert len(text) < 2.1e6
    assert np.array_equal(decode_frames(json.loads(text)), np.stack(frames))


def test_the_api_serves_a_pixel_runs_episode_with_its_view(tmp_path: Path):
    name = make_pixel_run(tmp_path)
    with local_client(tmp_path) as client:
        row = next(r for r in client.get("/api/runs").json()["runs"] if r["name"] == name)
        assert row["watchable"] is True
        url = f"/api/runs/{name}/checkpoints/best/episode"
        response = client.get(url, params={"seed": 4, "length": 0.4, "nudge_at": 1, "nudge": 1.5})
        assert response.status_code == 200, response.text
        body = response.json()
        assert (body["env_id"], body["scene"]) == (PIXELS, "cartpole")
        assert body["limits"]["x_threshold"] == pytest.approx(2.4) and body["limits"]["max_steps"] == 500
        frames = decode_frames(body["view"])
        drawn = render_frames(np.asarray(body["states"]), params=CartPoleParams(length=0.4))
        assert np.array_equal(frames, drawn) and body["nudges"] == [{"step": 1, "theta_dot_change": 1.5}]
        assert body["scores"] and len(body["scores"][0]) == 2  # the policy's action probabilities
        refused = client.get(url, params={"length": 3.0})
        assert refused.status_code == 422 and "shorter pole" in refused.json()["detail"]
