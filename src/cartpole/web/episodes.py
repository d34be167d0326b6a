"""Episodes of a checkpoint's greedy policy, simulated on the server for the Watch page.

An episode starts where ``evaluate()`` starts for the same seed (Gymnasium's ``reset(seed=seed)``),
can run under changed physics, and can be "nudged": a push that adds to the pole's angular velocity
before a given step, so a viewer can see whether the policy recovers.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cartpole.agents.registry import load_policy
from cartpole.evaluation import Policy
from cartpole.web.physics import CartPoleSim, start_state

MAX_NUDGE = 10.0
"""Largest nudge, in rad/s added to the pole's angular velocity (a hard slap is about 2)."""


class PolicyCache:
    """Loaded policies by (path, modification time): a rewritten checkpoint is loaded again."""

    def __init__(self, size: int = 16):
        self.size = size
        self._items: OrderedDict[tuple[str, int], Policy] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, path: Path) -> Policy:
        key = (str(path), path.stat().st_mtime_ns)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        policy = load_policy(path)
        with self._lock:
            self._items[key] = policy
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return policy


@dataclass
class Episode:
    """Per-step arrays: ``states`` has one more row than ``actions`` (the start state first)."""

    env_id: str
    seed: int
    physics: dict[str, float]
    nudges: dict[int, float]
    states: list[list[float]] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    scores: list[list[float]] | None = None
    terminated: bool = False
    truncated: bool = False

    def to_dict(self, limits: dict[str, float], score_label: str | None) -> dict[str, Any]:
        return {
            "env_id": self.env_id,
            "seed": self.seed,
            "physics": self.physics,
            "nudges": [{"step": k, "theta_dot_change": v} for k, v in sorted(self.nudges.items())],
            "length": len(self.actions),
            "return": float(sum(self.rewards)),
            "terminated": self.terminated,
            "truncated": self.truncated,
            "states": self.states,
            "actions": self.actions,
            "rewards": self.rewards,
            "scores": self.scores,
            "score_label": score_label if self.scores is not None else None,
            "limits": limits,
        }


def play_episode(
    policy: Policy,
    env_id: str,
    seed: int,
    physics: dict[str, float] | None = None,
    nudges: dict[int, float] | None = None,
) -> tuple[Episode, CartPoleSim]:
    """Run ``policy`` greedily from ``seed``'s start state until the episode ends."""
    sim = CartPoleSim(env_id, physics)
    nudges = dict(nudges or {})
    episode = Episode(env_id, seed, sim.physics(), nudges)
    state = sim.reset(start_state(env_id, seed))
    scored = callable(getattr(policy, "scores", None))
    scores: list[list[float]] = []
    while True:
        if sim.steps in nudges:
            sim.nudge(nudges[sim.steps])
            state = sim.state
        episode.states.append(state.tolist())
        obs = state.astype(np.float32)[None]  # what the env would hand the policy
        if scored:
            row = np.asarray(policy.scores(obs))[0]  # type: ignore[attr-defined]
            action = int(row.argmax())  # ScoredPolicy contract: act is the argmax of scores
            scores.append([float(v) for v in row])
        else:
            action = int(np.asarray(policy.act(obs))[0])
        result = sim.step(action)
        state = result.state
        episode.actions.append(action)
        episode.rewards.append(result.reward)
        if result.terminated or result.truncated:
            episode.terminated, episode.truncated = result.terminated, result.truncated
            episode.states.append(state.tolist())
            break
    episode.scores = scores if scored else None
    return episode, sim


def sim_limits(sim: CartPoleSim) -> dict[str, float]:
    """What the page needs to draw the track and the failure angle."""
    return {
        "x_threshold": sim.x_threshold,
        "theta_threshold": sim.theta_threshold,
        "tau": sim.tau,
        "fps": round(1.0 / sim.tau, 6),
        "max_steps": float(sim.max_steps or 0),
    }
