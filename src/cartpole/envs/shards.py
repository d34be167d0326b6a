"""Envs whose steps are costly (Gymnasium's pictures), stepped by worker processes.

:class:`ShardedEnvs` splits ``num_envs`` single Gymnasium envs into ``workers`` shards, one worker
process each; a step steps only the envs still playing, each shard in its own process, all at once.
Every env is stepped exactly as it is alone (its own seed and state), so the results are those of
the same envs stepped one by one in this process; only the wall time changes.

Why by hand: Gymnasium's ``AsyncVectorEnv`` gives each env a process of its own (a verdict plays a
hundred envs at once) and steps them all, ended or not; threads cannot share the work, because
pygame's polygon drawing (SDL_gfx, under Gymnasium's ``render``) keeps shared state and draws wrong
pictures when two threads draw at once.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections.abc import Callable, Sequence
from contextlib import suppress
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np

EnvMaker = Callable[[], gym.Env[Any, Any]]
"""Makes one env; picklable (a module-level function, or a ``functools.partial`` of one): the
workers are started fresh (``spawn``) and make their envs themselves."""


Steps = dict[int, tuple[Any, float, bool, bool]]
"""What the envs that played gave, by env index: observation, reward, terminated, truncated."""


class WorkerError(RuntimeError):
    """An env failed in a worker process; the message is the worker's exception."""


def _serve(connection: Connection, make: EnvMaker, count: int) -> None:
    """A worker: ``count`` envs from ``make``, reset and stepped on request until "close", or
    until the parent is gone (killed, or interrupted while this worker answered: it closed its
    end). Ctrl-C is the parent's to handle: it closes the workers."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    envs = [make() for _ in range(count)]
    try:
        _answer_requests(connection, envs)
    except (EOFError, OSError):  # the parent is gone: nobody is left to answer
        pass
    finally:
        for env in envs:
            env.close()


def _answer_requests(connection: Connection, envs: list[gym.Env[Any, Any]]) -> None:
    while True:
        command, payload = connection.recv()
        if command == "close":
            return
        try:
            answer = ("ok", _answer(envs, command, payload))
        except Exception as err:  # an env's own error: raised in the parent
            answer = ("error", f"{type(err).__name__}: {err}")
        connection.send(answer)


def _answer(envs: list[gym.Env[Any, Any]], command: str, payload: Any) -> Any:
    if command == "reset":  # payload: a seed per env
        return np.stack([env.reset(seed=int(seed))[0] for env, seed in zip(envs, payload, strict=True)])
    actions, playing = payload
    return step_playing(envs, actions, playing)


def step_playing(envs: Sequence[gym.Env[Any, Any]], actions: np.ndarray, playing: np.ndarray) -> Steps:
    """Step only the envs that are ``playing``, one at a time (as ``SyncVectorEnv.step`` steps them,
    without its autoreset): those that ended stand still, which saves what their steps would cost
    (Gymnasium's pictures are slow to draw: benchmarks/README.md#renderer)."""
    steps = {i: envs[i].step(actions[i]) for i in map(int, np.flatnonzero(playing))}
    return {
        i: (observation, float(reward), bool(ended), bool(cut))
        for i, (observation, reward, ended, cut, _) in steps.items()
    }


def gather_steps(
    observations: np.ndarray, steps: Steps
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``steps`` as arrays ``[n]``: observations, rewards, terminations and truncations; an env that
    did not play keeps its row of ``observations``, with no reward."""
    observations = np.array(observations, copy=True)
    n = len(observations)
    rewards, terminated, truncated = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    for i, (observation, reward, ended, cut) in steps.items():
        observations[i], rewards[i], terminated[i], truncated[i] = observation, reward, ended, cut
    return observations, rewards, terminated, truncated


class ShardedEnvs:
    """``num_envs`` envs from ``make`` in ``workers`` processes (see the module's docstring)."""

    def __init__(self, make: EnvMaker, num_envs: int, workers: int) -> None:
        if num_envs < 1 or workers < 1:
            raise ValueError(f"num_envs and workers must be >= 1, got {num_envs} and {workers}")
        self.num_envs = num_envs
        self.shards = np.array_split(np.arange(num_envs), min(workers, num_envs))
        context = multiprocessing.get_context("spawn")  # not fork: this process may run torch's threads
        self._connections: list[Connection] = []
        self._processes: list[multiprocessing.process.BaseProcess] = []
        for shard in self.shards:
            ours, theirs = context.Pipe()
            process = context.Process(target=_serve, args=(theirs, make, len(shard)), daemon=True)
            process.start()
            theirs.close()
            self._connections.append(ours)
            self._processes.append(process)

    def _ask(self, command: str, payloads: list[Any]) -> list[Any]:
        for connection, payload in zip(self._connections, payloads, strict=True):
            connection.send((command, payload))
        answers = []
        for connection in self._connections:
            try:
                status, answer = connection.recv()
            except (EOFError, OSError):  # it died, or never started (e.g. spawn could not import)
                raise WorkerError("an env worker process ended unexpectedly") from None
            if status != "ok":
                raise WorkerError(answer)
            answers.append(answer)
        return answers

    def reset(self, *, seed: list[int]) -> tuple[np.ndarray, dict[str, Any]]:
        """Env i reset with ``seed[i]``, as ``SyncVectorEnv.reset(seed=[...])`` does; the
        observations ``[n, ...]``."""
        if len(seed) != self.num_envs:
            raise ValueError(f"{self.num_envs} envs need {self.num_envs} seeds, got {len(seed)}")
        seeds = np.asarray(seed)
        return np.concatenate(self._ask("reset", [seeds[shard] for shard in self.shards])), {}

    def step_playing(
        self, actions: np.ndarray, playing: np.ndarray, observations: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step the envs that are ``playing`` (the others stand still, keeping their ``observations``
        rows); observations, rewards, terminations and truncations ``[n]``."""
        payloads = [(actions[shard], playing[shard]) for shard in self.shards]
        answers = self._ask("step", payloads)
        steps = {
            int(shard[i]): step
            for shard, answer in zip(self.shards, answers, strict=True)
            for i, step in answer.items()
        }
        return gather_steps(observations, steps)

    def close(self) -> None:
        """Stop the workers (they close their envs)."""
        for connection in self._connections:
            with suppress(OSError):  # a worker that is gone already
                connection.send(("close", None))
            connection.close()
        for process in self._processes:
            process.join(timeout=10)
            if process.is_alive():
                process.kill()


__all__ = ["EnvMaker", "ShardedEnvs", "Steps", "WorkerError", "gather_steps", "step_playing"]
