"""Episodes of a checkpoint's greedy policy, simulated on the server for the Watch page.

An episode starts where ``evaluate()`` starts for the same seed (Gymnasium's ``reset(seed=seed)``),
can run under changed physics, and can be "nudged": a push that adds to the pole's angular velocity
before a given step, so a viewer can see whether the policy recovers. A run on a pixel env plays from
the same states, its policy seeing frame stacks drawn from them (:mod:`cartpole.web.agent_view`);
the episode then carries each step's frame, so the page can show what the agent saw.

Episodes are computed in a worker process (``EpisodeWorkers``), not on the server's event loop nor
in one of its threads: a 500-step episode holds the GIL for longer than the 5 ms (p99) within which
play sessions must answer each step meanwhile (``benchmarks/web_latency.py --watch-load`` checks it).
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import torch

from cartpole.agents.registry import open_policy
from cartpole.envs import env_info
from cartpole.envs.fast import CartPoleStepper
from cartpole.evaluation import Policy, ScoredPolicy, act_once
from cartpole.web.agent_view import FrameStacker, PixelView, ViewError, view_json
from cartpole.web.physics import ACTION_LABELS, CartPoleSim, GymSim, PhysicsError, scene_of, start_state

MAX_NUDGE = 10.0
"""Largest nudge, in rad/s added to the pole's angular velocity (a hard slap is about 2)."""

UNLIMITED_STEPS = 100_000
"""Where an episode of an env without a time limit stops (no CartPole id lacks one)."""

WORKER_NICENESS = 10
"""How much lower a worker's CPU priority is than the server's: episodes are batch work, while play
steps wait on the event loop, so on a busy machine the server runs first."""

SAME_START_SECONDS = 1.0
"""Start times of one process, as two processes compute them, differ by less than this (they are the
boot time plus the start's offset, and the boot time moves with the system clock)."""


class PolicyCache:
    """Loaded policies by (path, modification time): a rewritten checkpoint is loaded again."""

    def __init__(self, size: int = 16):
        self.size = size
        self._items: OrderedDict[tuple[str, int, str | None], Policy] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, path: Path, env_id: str | None = None) -> Policy:
        """The policy of ``path``; with ``env_id``, CheckpointError unless it fits that env's
        observations and actions."""
        key = (str(path), path.stat().st_mtime_ns, env_id)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        policy = open_policy(path, env_id).policy
        with self._lock:
            self._items[key] = policy
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return policy


@dataclass
class Episode:
    """Per-step arrays: ``states`` has one more row than ``actions`` (the start state first). A
    state is what the scene's drawing needs: the env's own ``state`` (CartPole's x, x_dot, theta,
    theta_dot; Acrobot's two link angles and their speeds; MountainCar's position and velocity)."""

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
    view: dict[str, Any] | None = None
    """A pixel agent's view (:func:`~cartpole.web.agent_view.view_json`: one frame per state);
    None for agents that see states."""

    def to_dict(self, limits: dict[str, float], score_label: str | None) -> dict[str, Any]:
        scene = scene_of(self.env_id) or "cartpole"
        return {
            "env_id": self.env_id,
            "scene": scene,
            "action_labels": ACTION_LABELS[scene],
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
            "view": self.view,
        }


def play_episode(
    policy: Policy,
    env_id: str,
    seed: int,
    physics: dict[str, float] | None = None,
    nudges: dict[int, float] | None = None,
) -> tuple[Episode, CartPoleSim]:
    """Run ``policy`` greedily from ``seed``'s start state until the episode ends.

    Returns the episode and the simulator it ran on (for its physics and limits). Every CartPole id
    has a time limit; were there none, the episode would stop, truncated, after ``UNLIMITED_STEPS``.
    On a pixel env the policy sees frame stacks drawn from the states (under the episode's physics,
    as the env draws them), and the episode keeps each state's frame. PhysicsError where the frames
    cannot show the physics (a pole too long for them).
    """
    sim = CartPoleSim(env_id, physics)
    view = PixelView.of(env_id)
    stacker = pixel_stacker(view, sim) if view else None
    nudges = dict(nudges or {})
    limit = sim.max_steps or UNLIMITED_STEPS
    states = np.empty((limit + 1, 4))
    states[0] = start_state(env_id, seed)
    actions = np.empty(limit, dtype=np.int64)
    scored = callable(getattr(policy, "scores", None))
    scores = np.empty((limit, env_info(env_id).n_actions)) if scored else None
    observe = stacker_observer(stacker) if stacker else None
    length, terminated = _play_greedily(policy, sim.stepper, nudges, states, actions, scores, observe)
    if stacker is not None:
        stacker.push(states[length])  # the last state's frame too: one frame per state shown
    # Lists once, at the end: per-step conversions cost as much as the physics.
    episode = Episode(
        env_id,
        seed,
        sim.physics(),
        nudges,
        states=states[: length + 1].tolist(),
        actions=actions[:length].tolist(),
        rewards=[1.0] * length,  # +1 per step, the terminating one included (as Gymnasium)
        scores=None if scores is None else scores[:length].tolist(),
        terminated=terminated,
        truncated=length >= limit,  # as TimeLimit: both flags can be set on the last step
        view=view_json(stacker.view, stacker.frames) if stacker else None,
    )
    return episode, sim


def pixel_stacker(view: PixelView, sim: CartPoleSim) -> FrameStacker:
    """The frame stacker of a pixel episode on ``sim``: drawn with its physics (the pole's length
    shows), as the env's ``set_params`` draws; PhysicsError where the frames cannot show them."""
    try:
        return FrameStacker(view, sim.stepper.params)
    except ViewError as err:
        raise PhysicsError(str(err)) from err


Observer = Callable[[int, np.ndarray], np.ndarray]
"""(step, state) -> the observation the policy sees at that step."""


def stacker_observer(stacker: FrameStacker) -> Observer:
    """A pixel env's observations: the stack is filled at step 0 and pushed at every later step."""

    def observe(step: int, state: np.ndarray) -> np.ndarray:
        return stacker.reset(state) if step == 0 else stacker.push(state)

    return observe


def play_gym_episode(policy: Policy, env_id: str, seed: int) -> tuple[Episode, dict[str, float]]:
    """``policy`` greedily on Gymnasium's own ``env_id`` from ``reset(seed=seed)`` (as ``evaluate()``
    starts it) until the episode ends: for the envs besides CartPole that Watch draws. Returns the
    episode (the env's state at each step, for the drawing) and the limits the drawing needs."""
    sim = GymSim(env_id)
    scored = isinstance(policy, ScoredPolicy)
    try:
        states, actions, rewards, scores = [sim.reset(seed).tolist()], [], [], []
        while not sim.done:
            action, row = act_once(policy, sim.observation)
            if row is not None:
                scores.append(row.astype(float).tolist())
            result = sim.step(action)
            states.append(result.state.tolist())
            actions.append(action)
            rewards.append(result.reward)
        limits = sim.limits()
    finally:
        sim.close()
    episode = Episode(env_id, seed, {}, {}, states, actions, rewards, scores if scored else None)
    episode.terminated, episode.truncated = result.terminated, result.truncated
    return episode, limits


def _play_greedily(
    policy: Policy,
    stepper: CartPoleStepper,
    nudges: dict[int, float],
    states: np.ndarray,
    actions: np.ndarray,
    scores: np.ndarray | None,
    observe: Observer | None = None,
) -> tuple[int, bool]:
    """Fill ``states[1:]``, ``actions`` and ``scores`` (when given: the policy's, whose argmax is the
    action) step by step from ``states[0]``, until termination or the arrays are full.

    Returns (steps played, terminated). Each nudge is added to ``states[t]`` before the policy sees it;
    the policy sees the state itself, or ``observe(t, state)`` when given (a pixel env's frames).
    """
    for t in range(len(actions)):
        state = states[t]
        if t in nudges:
            state[3] += nudges[t]
        observation = state if observe is None else observe(t, state)
        action, row = act_once(policy, observation)  # the float32 observation the env would hand it
        if scores is not None and row is not None:
            scores[t] = row  # float32 to float64 is exact: the JSON shows the policy's own values
        actions[t] = action
        if stepper.step(state, action, out=states[t + 1]):
            return t + 1, True
    return len(actions), False


def sim_limits(sim: CartPoleSim) -> dict[str, float]:
    """What the page needs to draw the track and the failure angle."""
    return {
        "x_threshold": sim.x_threshold,
        "theta_threshold": sim.theta_threshold,
        "tau": sim.tau,
        "fps": round(1.0 / sim.tau, 6),
        "max_steps": float(sim.max_steps or 0),
    }


# ---------------------------------------------------------------------------------------------------
# Off the event loop
# ---------------------------------------------------------------------------------------------------


class EpisodesBusy(RuntimeError):
    """Too many episode requests are waiting already; the client should retry shortly."""


_worker_policies: PolicyCache | None = None
"""The worker process's own cache of loaded policies (each worker has one; the server has none)."""


def episode_body(
    checkpoint: str,
    env_id: str,
    seed: int,
    physics: dict[str, float],
    nudges: dict[int, float],
    score_label: str,
    header: dict[str, Any],
) -> bytes:
    """In a worker: the greedy episode of the checkpoint at path ``checkpoint`` as the API's JSON body,
    ``header`` (run, checkpoint, agent) first. Encoded here, not on the server's event loop: encoding a
    500-step episode would hold up every play session meanwhile. CheckpointError and PhysicsError
    reach the caller."""
    global _worker_policies
    if _worker_policies is None:
        _worker_policies = PolicyCache()
    policy = _worker_policies.get(Path(checkpoint), env_id)
    if scene_of(env_id) == "cartpole":
        episode, sim = play_episode(policy, env_id, seed, physics, nudges)
        limits = sim_limits(sim)
    else:
        episode, limits = play_gym_episode(policy, env_id, seed)
    body = header | episode.to_dict(limits, score_label)
    return json.dumps(body, allow_nan=False, separators=(",", ":")).encode()


def _start_worker(server_pid: int, server_started: float) -> None:
    """In each worker, first: give the CPU to the server first, and exit when the server is gone,
    however it ended (a pool's workers outlive a killed parent otherwise)."""
    lower_priority()
    torch.set_num_threads(1)  # a policy's forward pass is one row: more threads only spin
    threading.Thread(
        target=_exit_with, args=(server_pid, server_started), name="exit-with-server", daemon=True
    ).start()


def lower_priority() -> None:
    """This process's niceness raised by :data:`WORKER_NICENESS`; on Windows, which has no niceness,
    the below-normal priority class. Where the OS refuses, the priority stays as it was."""
    with suppress(OSError, psutil.Error):
        if sys.platform == "win32":
            psutil.Process().nice(psutil.BELOW_NORMAL_PRIORITY_CLASS)
        else:
            os.nice(WORKER_NICENESS)


def wait_for_end(pid: int, started: float, period: float = 0.5) -> None:
    """Return once process ``pid``, started at ``started`` (its ``psutil.Process.create_time()``),
    has ended: it is gone, a zombie, or its pid names another process now. Asked of psutil, not of
    ``os.getppid()``, which on Windows does not change when the parent dies. What the OS will not
    tell (AccessDenied) counts as still there."""
    try:
        process = psutil.Process(pid)  # from here on, is_running() sees a reuse of the pid
        with suppress(psutil.AccessDenied):
            if abs(process.create_time() - started) > SAME_START_SECONDS:  # another process has the pid
                return
        while not _ended(process):
            time.sleep(period)
    except psutil.NoSuchProcess:  # a zombie too (ZombieProcess)
        return


def _ended(process: psutil.Process) -> bool:
    if not process.is_running():
        return True
    with suppress(psutil.AccessDenied):
        return bool(process.status() == psutil.STATUS_ZOMBIE)
    return False


def _exit_with(server_pid: int, server_started: float) -> None:
    wait_for_end(server_pid, server_started)
    os._exit(0)


def _warm_worker() -> None:
    """Import the agents and compile the simulator's kernels in the worker before the first episode."""
    from cartpole.agents.registry import agents

    agents()
    sim = CartPoleSim("CartPole-v1")
    sim.reset(start_state("CartPole-v1", 0))
    sim.step(0)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def stop_signals_ignored() -> Iterator[None]:
    """SIGINT and SIGTERM ignored meanwhile, so that the worker processes spawned meanwhile start
    ignoring them (an ignored signal stays ignored through exec, and Python keeps it so), as
    multiprocessing's resource tracker does: a Ctrl+C or a service manager's SIGTERM to the whole
    process group then stops the server alone, whose exit ends its workers (their pool's shutdown,
    or :func:`_exit_with`), and no worker dies mid-import with a traceback or leaves its pool's
    semaphores to the tracker's warning. Signal handlers belong to the main thread: elsewhere (an
    app under a test client) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class EpisodeWorkers:
    """A bounded pool of worker processes that compute episodes for the Watch page.

    At most ``processes`` episodes run at once and at most ``max_waiting`` wait for one; more get
    ``EpisodesBusy``. The pool starts on first use (or ``start()``) and is started again if a worker
    dies. Processes are spawned, not forked: the server has threads running. Apps in one process
    share one pool (``shared()``): a worker costs an interpreter with torch loaded.
    """

    _shared: EpisodeWorkers | None = None

    @classmethod
    def shared(cls) -> EpisodeWorkers:
        """The pool of this process."""
        if cls._shared is None:
            cls._shared = cls()
        return cls._shared

    def __init__(self, processes: int = 1, max_waiting: int = 32):
        self.processes = processes
        self.max_waiting = max_waiting
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._pending = 0

    def start(self) -> None:
        """Start the workers now and warm them up (in the background: this does not wait)."""
        with stop_signals_ignored():  # submit spawns the workers
            pool = self._executor()
            for _ in range(self.processes):
                pool.submit(_warm_worker)

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    async def episode(
        self,
        checkpoint: Path,
        env_id: str,
        seed: int,
        physics: dict[str, float],
        nudges: dict[int, float],
        score_label: str,
        header: dict[str, Any],
    ) -> bytes:
        """``episode_body`` computed in a worker; the event loop goes on serving meanwhile."""
        if self._pending >= self.processes + self.max_waiting:
            raise EpisodesBusy(f"{self._pending} episodes are being computed; try again in a moment")
        self._pending += 1
        try:
            args = (str(checkpoint), env_id, seed, physics, nudges, score_label, header)
            try:
                with stop_signals_ignored():  # a new pool spawns its workers in submit
                    pool = self._executor()
                    future = pool.submit(episode_body, *args)
                return await asyncio.wrap_future(future)
            except BrokenProcessPool as err:
                with self._lock:
                    if self._pool is pool:
                        self._pool = None
                raise EpisodesBusy("the episode worker stopped; it is restarted: try again") from err
        finally:
            self._pending -= 1

    def _executor(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                context = multiprocessing.get_context("spawn")
                server = (os.getpid(), psutil.Process().create_time())
                self._pool = ProcessPoolExecutor(
                    self.processes, context, initializer=_start_worker, initargs=server
                )
            return self._pool
