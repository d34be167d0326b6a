"""Replays of runs on envs that Watch does not draw (a user's ``module:Id`` env, LunarLander): a GIF of
one greedy episode from the env's own ``rgb_array`` frames, played as its verdict plays it (the run's
env kwargs and wrappers, the env's own reward in the caption), made by :mod:`cartpole.recording`."""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from cartpole.agents.registry import open_policy
from cartpole.recording import render_episodes, write_video

REPLAY_STEPS = 300
"""A replay shows at most this many steps of its episode (a GIF of every frame of a 1,000-step
episode would take many seconds to encode and tens of MB)."""


class ReplayBusy(RuntimeError):
    """A replay is being made already; the client should retry shortly."""


class Replays:
    """Makes one replay at a time, in a thread, so that the server goes on answering meanwhile."""

    def __init__(self) -> None:
        self._lock = asyncio.Lock()

    async def gif(self, checkpoint: Path, seed: int) -> bytes:
        """The GIF of ``checkpoint``'s greedy episode from ``reset(seed=seed)``; ReplayBusy while
        another is made; CheckpointError, RecordingError or UnsupportedEnvError when it cannot be."""
        if self._lock.locked():
            raise ReplayBusy("a replay is being made: retry in a moment")
        async with self._lock:
            return await asyncio.to_thread(replay_gif, checkpoint, seed)


def replay_gif(checkpoint: Path, seed: int) -> bytes:
    """:meth:`Replays.gif`'s work."""
    opened = open_policy(checkpoint)
    recording = render_episodes(opened.policy, opened.env, 1, seed, max_steps=REPLAY_STEPS)
    with tempfile.TemporaryDirectory() as folder:
        path = write_video(recording.frames, Path(folder) / "replay.gif", recording.fps)
        return path.read_bytes()


__all__ = ["REPLAY_STEPS", "ReplayBusy", "Replays", "replay_gif"]
