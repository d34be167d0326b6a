"""Honest evaluation: greedy actions, fresh seeds, one episode per env, Gymnasium's own rule.

``evaluate`` runs ``episodes`` greedy episodes of a policy, each from the start state that
Gymnasium's single env gives for ``reset(seed=seed + i)``, all stepped together in one vector env.
Each vector env plays exactly one episode, so short episodes cannot be over-represented in the mean
(the bias Stable-Baselines3's ``evaluate_policy`` guards against). The verdict follows Gymnasium's rule:
solved means a mean return >= the registry's ``reward_threshold`` over at least 100 episodes.
"""

from __future__ import annotations

import html
import sys
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from cartpole.envs import (
    EnvInfo,
    Simulator,
    as_env_info,
    describe_kwargs,
    judged_env,
    make_eval_envs,
    resolve_simulator,
)
from cartpole.envs.judged import cut_by_episode
from cartpole.envs.params import CartPoleParams
from cartpole.envs.shards import ShardedEnvs, gather_steps, step_playing

MIN_EPISODES_FOR_SOLVED = 100
"""Gymnasium's rule averages over 100 consecutive episodes; fewer cannot be called solved."""

MAX_EPISODES = 1_000_000
"""The most episodes one evaluation plays: its report keeps every episode's seed, return and length
(three numbers an episode), and CartPole's 500 steps each make it minutes of play already."""

MAX_ENVS_PER_BATCH = 1000


@runtime_checkable
class Policy(Protocol):
    """Anything that maps a batch of observations to a batch of greedy actions."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        """Actions (ints, shape [N]) for observations of shape [N, obs_dim]."""
        ...


@runtime_checkable
class ScoredPolicy(Policy, Protocol):
    """A policy that can also show its preference per action (Q-values or a linear score)."""

    def scores(self, observations: np.ndarray) -> np.ndarray:
        """Preferences of shape [N, n_actions]; ``act`` is their argmax."""
        ...


@runtime_checkable
class CartPolePlayer(Protocol):
    """A greedy actor (a policy, or a :data:`BlockActor`) that can also play whole episodes of our
    float64 CartPole itself, policy and physics in one compiled loop: an evaluation on ``"fast"``
    then hands it the start states instead of stepping the vector env (the same episodes, for a
    fraction of the CPU)."""

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        """The lengths ``[n]`` of the greedy episodes from start states ``states`` ``[n, 4]`` (float64)
        on cart-poles of ``params``, truncated at ``max_episode_steps``, episode e played by policy
        ``e // block_size``; None when this actor cannot play them itself."""
        ...


def act_once(policy: Policy, observation: np.ndarray) -> tuple[int, np.ndarray | None]:
    """The greedy action for one observation and, for a :class:`ScoredPolicy`, its scores (whose argmax
    is the action): one step of an episode that is drawn with the policy's preferences."""
    batch = np.asarray(observation, dtype=np.float32)[None]
    if isinstance(policy, ScoredPolicy):
        row = np.asarray(policy.scores(batch))[0]
        return int(row.argmax()), row
    return int(np.asarray(policy.act(batch)).reshape(-1)[0]), None


@dataclass(frozen=True)
class EvalReport:
    """The outcome of ``evaluate``: every episode, the summary, and the verdict."""

    env_id: str
    simulator: str
    returns: list[float]
    lengths: list[int]
    seeds: list[int]
    threshold: float | None
    max_episode_steps: int | None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """The env's kwargs (``--env-kwargs``): a verdict on a changed env names them."""
    wrappers: list[str] = field(default_factory=list)
    """The wrappers the policy played through (``module:Class(kwargs)``); the returns are the env's own."""
    simulator_only: list[str] = field(default_factory=list)
    """The kwargs that Gymnasium's own env does not take (CartPole's physics constants): the
    episodes were played on our simulator, whatever was asked."""
    training_only: list[str] = field(default_factory=list)
    """The kwargs that are ``gymnasium.make``'s own arguments (``max_episode_steps``): training took
    them, the episodes here were played without them (the registry's time limit)."""
    cut_by: dict[str, int] = field(default_factory=dict)
    """Episodes a wrapper ended before the env did, by the wrapper (:mod:`cartpole.envs.judged`):
    such an episode is not the env's, so a report with any calls nothing solved."""
    mean: float = field(init=False)
    std: float = field(init=False)
    min: float = field(init=False)
    max: float = field(init=False)
    solved: bool = field(init=False)

    def __post_init__(self) -> None:
        returns = np.asarray(self.returns, dtype=np.float64)
        object.__setattr__(self, "mean", float(returns.mean()))
        object.__setattr__(self, "std", float(returns.std()))
        object.__setattr__(self, "min", float(returns.min()))
        object.__setattr__(self, "max", float(returns.max()))
        solved = (
            self.threshold is not None
            and self.episodes >= MIN_EPISODES_FOR_SOLVED
            and not self.cut_by
            and self.mean >= self.threshold
        )
        object.__setattr__(self, "solved", bool(solved))

    @property
    def episodes(self) -> int:
        return len(self.returns)

    @property
    def verdict(self) -> str:
        """One line: solved or not, by which rule, on which env (with its kwargs and wrappers) and
        simulator."""
        where = f"{self.env_label}, {self.simulator} simulator"
        if self.simulator_only:
            where += f": Gymnasium's {self.env_id} does not take {', '.join(self.simulator_only)}"
        if self.training_only:
            limit = (
                f"the registry's {self.max_episode_steps}-step limit" if self.max_episode_steps else "none"
            )
            where += f"; {', '.join(self.training_only)} for training only: judged with {limit}"
        summary = f"mean {self.mean:.1f} ± {self.std:.1f} over {self.episodes} episodes"
        if self.cut_by:
            cuts = ", ".join(f"{label} ended {count}" for label, count in self.cut_by.items())
            return (
                f"NO VERDICT: {summary}; {cuts} of them before the env did, and Gymnasium's rule counts "
                f"the env's whole episodes (with negative rewards a cut episode scores higher) ({where})"
            )
        if self.threshold is None:
            return f"NO VERDICT: {summary}; {self.env_id} registers no reward_threshold ({where})"
        rule = f"{self.threshold:g}"
        if self.episodes < MIN_EPISODES_FOR_SOLVED:
            return (
                f"CANNOT CALL SOLVED: {summary}; the rule needs >= {MIN_EPISODES_FOR_SOLVED} "
                f"episodes with mean >= {rule} ({where})"
            )
        if self.solved:
            return f"SOLVED: {summary} >= {rule} ({where})"
        return f"NOT SOLVED: {summary} < {rule} ({where})"

    @property
    def env_label(self) -> str:
        """The env with its kwargs and wrappers: ``CartPole-v1 (sutton_barto_reward=true)``."""
        parts = [describe_kwargs(self.env_kwargs)] if self.env_kwargs else []
        if self.wrappers:
            parts.append("wrappers: " + ", ".join(self.wrappers) + "; the env's own reward")
        return self.env_id + (f" ({'; '.join(parts)})" if parts else "")

    def _repr_html_(self) -> str:
        """The verdict as Jupyter shows it: the line, colored by the outcome, and the spread."""
        color = "#17804a" if self.solved else "#b03a2e"
        spread = f"min {self.min:.0f}, max {self.max:.0f}, {self.episodes} episodes from seed {self.seeds[0]}"
        return (
            f'<div><b style="color:{color}">{html.escape(self.verdict)}</b>'
            f"<br><small>{html.escape(spread)}</small></div>"
        )

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["episodes"] = self.episodes
        data["verdict"] = self.verdict
        return data

    @classmethod
    def played(
        cls,
        env: EnvInfo,
        simulator: str,
        returns: list[float],
        lengths: list[int],
        seeds: list[int],
        cut_by: Sequence[str | None] = (),
    ) -> EvalReport:
        """The report of episodes played on ``env`` (as configured; as a verdict plays it:
        :func:`~cartpole.envs.judged_env`) on ``simulator`` (the one that really ran them: see
        :func:`~cartpole.envs.resolve_simulator`); ``cut_by``: for each episode, the wrapper that
        ended it before the env did, if any."""
        judged = judged_env(env)
        return cls(
            env_id=env.env_id,
            simulator=resolve_simulator(judged, simulator),
            returns=returns,
            lengths=lengths,
            seeds=seeds,
            threshold=judged.reward_threshold,
            max_episode_steps=judged.max_episode_steps,
            env_kwargs=dict(env.kwargs),
            wrappers=[wrapper.label for wrapper in env.wrappers],
            simulator_only=list(env.simulator_only),
            training_only=list(env.training_only),
            cut_by=dict(Counter(label for label in cut_by if label is not None)),
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EvalReport:
        keys = (
            "env_id",
            "simulator",
            "returns",
            "lengths",
            "seeds",
            "threshold",
            "max_episode_steps",
        )
        optional = {
            k: data[k]
            for k in ("env_kwargs", "wrappers", "simulator_only", "training_only", "cut_by")
            if k in data
        }  # newer than the rest
        return cls(**{k: data[k] for k in keys}, **optional)


def start_states(env_id: str, seeds: list[int]) -> np.ndarray:
    """The exact start states Gymnasium's single CartPole env gives for ``reset(seed=s)``."""
    env = gym.make(env_id.removeprefix("cartpole/"))
    try:
        states = []
        for seed in seeds:
            env.reset(seed=seed)
            states.append(np.array(env.unwrapped.state, dtype=np.float64))  # type: ignore[attr-defined]
        return np.stack(states)
    finally:
        env.close()


def _reset_to_seeds(env: gym.vector.VectorEnv | ShardedEnvs, info: EnvInfo, seeds: list[int]) -> np.ndarray:
    """Reset ``env`` so that env i starts where Gymnasium's single env does for ``seeds[i]``."""
    if isinstance(env, ShardedEnvs):  # Gymnasium's pictures, drawn by worker processes
        return env.reset(seed=seeds)[0]
    if isinstance(env, gym.vector.SyncVectorEnv):  # single envs (wrapped, or any but CartPole): env i
        return env.reset(seed=list[int | None](seeds))[0]  # seeded with seeds[i], as the single env
    base = env.unwrapped
    if info.pixels_of and hasattr(base, "restart_at"):  # our pixel renderer: Gymnasium's states, drawn
        env.reset(seed=seeds[0])
        return np.asarray(base.restart_at(start_states(info.pixels_of, seeds)))
    if not info.is_cartpole:  # Gymnasium's own pixels too: each of its envs is seeded as the single env
        observations, _ = env.reset(seed=seeds)  # type: ignore[arg-type]  # env i seeded with seeds[i]
        return observations
    env.reset(seed=seeds[0])
    states = start_states(info.env_id, seeds)
    if hasattr(base, "set_state"):  # our fast simulator
        base.set_state(states)
    else:  # Gymnasium's CartPoleVectorEnv keeps its state as [4, num_envs] float64
        base.state = states.T.copy()  # type: ignore[attr-defined]
    return states.astype(np.float32)  # CartPole's observation is its state, as float32


BlockActor = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Many policies' greedy actions at once: ``act(observations, blocks)`` maps the rows of blocks
``blocks`` (rising block indices ``[k]``; block b's rows are the episodes of policy b) to actions."""

KEEP_ACTING_FRACTION = 0.75
""":func:`play_greedy_blocks` stops acting for blocks whose episodes have all ended once this
fraction or fewer of the blocks it acts for are still playing (not at every ended block, so the
actor re-packs its weights a few times per evaluation, not once per block)."""


def play_greedy_episodes(
    act: Callable[[np.ndarray], np.ndarray],
    env: str | EnvInfo,
    seeds: list[int],
    simulator: Simulator,
    workers: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Play one episode from each of ``seeds`` (the start state Gymnasium's single env gives for
    it), all at once in one vector env, with ``act`` mapping observations ``[n, obs_dim]`` to
    actions ``[n]``; the returns and lengths ``[n]``. ``workers``: see :func:`play_greedy_blocks`."""
    return play_greedy_blocks(
        lambda observations, _: act(observations), env, seeds, simulator, len(seeds), workers
    )


def play_greedy_blocks(
    act: BlockActor,
    env: str | EnvInfo,
    seeds: list[int],
    simulator: Simulator,
    block_size: int,
    workers: int = 1,
    cut_by: list[str | None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`play_greedy_episodes` for many policies: the episodes come in blocks of
    ``block_size`` (block b: ``seeds[b * block_size:(b + 1) * block_size]``, played by policy b), and
    ``act`` serves every block (see :data:`BlockActor`). Once most blocks have ended all their
    episodes, ``act`` is asked only for the blocks still playing, so a policy whose episodes end
    early costs no more forward passes than it would alone. The returns and lengths ``[n]``.

    ``workers`` > 1: Gymnasium's pictures (a pixel env on ``"gymnasium"``, slow to draw: see
    benchmarks/README.md#renderer) are drawn by that many processes
    (:func:`~cartpole.envs.make_eval_envs`); the episodes are the same, and meanwhile a torch policy
    acts on one thread (:func:`_one_torch_thread_while_workers_draw`).

    ``cut_by``, when given, receives for each episode the wrapper that ended it before the env did
    (None: the env ended it; :mod:`cartpole.envs.judged`)."""
    n = len(seeds)
    if n % block_size:
        raise ValueError(f"{n} episodes do not split into blocks of {block_size}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    info = as_env_info(env)
    envs = make_eval_envs(info, n, simulator=simulator, workers=workers)
    try:
        with _one_torch_thread_while_workers_draw(envs):
            played = _play_blocks(act, envs, info, seeds, block_size)
        if cut_by is not None:
            cut_by += cut_by_episode(envs.envs) if isinstance(envs, gym.vector.SyncVectorEnv) else [None] * n
        return played
    finally:
        envs.close()


@contextmanager
def _one_torch_thread_while_workers_draw(env: gym.vector.VectorEnv | ShardedEnvs) -> Iterator[None]:
    """While worker processes draw the pictures (:class:`ShardedEnvs`), this process acts on one
    torch thread, then gets its thread count back. The workers hold the cores: a second thread of
    the policy's small forward pass waits for a core at each of its barriers (and spins on one when
    done), so the workers, which wait for the actions, wait for it too. Torch is not imported here:
    where no policy has loaded it, there is nothing to set."""
    torch = sys.modules.get("torch")
    if torch is None or not isinstance(env, ShardedEnvs):
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _play_blocks(
    act: BlockActor, env: gym.vector.VectorEnv | ShardedEnvs, info: EnvInfo, seeds: list[int], block_size: int
) -> tuple[np.ndarray, np.ndarray]:
    """The loop of :func:`play_greedy_blocks` on its envs."""
    n = len(seeds)
    observations = _reset_to_seeds(env, info, seeds)
    if (lengths := _played_by_the_actor(act, env, block_size)) is not None:
        return lengths.astype(np.float64), lengths  # +1 a step, the last included
    returns = np.zeros(n, dtype=np.float64)
    lengths = np.zeros(n, dtype=np.int64)
    running = np.ones(n, dtype=bool)
    acting = np.arange(n // block_size)
    rows = np.arange(n)
    while running.any():
        playing = np.flatnonzero(running.reshape(-1, block_size).any(axis=1))
        if len(playing) <= KEEP_ACTING_FRACTION * len(acting):
            acting = playing
            rows = (acting[:, None] * block_size + np.arange(block_size)).reshape(-1)
        if len(rows) == n:
            actions = np.asarray(act(observations, acting), dtype=np.int64).reshape(n)
        else:
            actions = np.zeros(n, dtype=np.int64)  # envs of ended blocks: stepped, not counted
            actions[rows] = np.asarray(act(observations[rows], acting)).reshape(-1)
        if isinstance(env, ShardedEnvs):
            observations, rewards, terminated, truncated = env.step_playing(actions, running, observations)
        elif isinstance(env, gym.vector.SyncVectorEnv):
            steps = step_playing(env.envs, actions, running)
            observations, rewards, terminated, truncated = gather_steps(observations, steps)
        else:
            observations, rewards, terminated, truncated, _ = env.step(actions)
        returns += np.where(running, rewards, 0.0)
        lengths += running
        running &= ~(terminated | truncated)
    return returns, lengths


def _played_by_the_actor(
    act: BlockActor, env: gym.vector.VectorEnv | ShardedEnvs, block_size: int
) -> np.ndarray | None:
    """The episodes' lengths when ``act`` plays them itself (a :class:`CartPolePlayer`) from the
    start states of ``env``: our float64 CartPole, unwrapped, with Gymnasium's +1 reward; else None."""
    from cartpole.envs.fast import CartPoleVectorEnv  # here: importing cartpole loads no simulator

    if not isinstance(act, CartPolePlayer) or type(env) is not CartPoleVectorEnv:
        return None
    if env.dtype != np.float64 or env.sutton_barto_reward:
        return None
    lengths = act.play_cartpole(env.get_state(), env.params, env.max_episode_steps, block_size)
    return None if lengths is None else np.asarray(lengths, dtype=np.int64)


class _PolicyActor:
    """One policy as a :data:`BlockActor` of one block, which plays whole episodes itself when the
    policy can (:class:`CartPolePlayer`)."""

    def __init__(self, policy: Policy):
        self.policy = policy

    def __call__(self, observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        return self.policy.act(observations)

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        if not isinstance(self.policy, CartPolePlayer):
            return None
        return self.policy.play_cartpole(states, params, max_episode_steps, block_size)


def evaluate(
    policy: Policy,
    env: str | EnvInfo = "CartPole-v1",
    episodes: int = MIN_EPISODES_FOR_SOLVED,
    seed: int | None = None,
    *,
    simulator: Simulator = "gymnasium",
    workers: int = 1,
) -> EvalReport:
    """Play ``episodes`` greedy episodes from seeds ``seed, seed + 1, ...`` and judge them.

    With ``seed=None`` a fresh seed is drawn from the OS, above every training seed.
    ``simulator="gymnasium"`` (default) uses Gymnasium's own env, so the verdict does not rest on our
    physics; ``"fast"`` uses our simulator for CartPole (same start states, same equations).
    ``workers``: how many processes draw Gymnasium's pictures for a pixel env (see
    :func:`play_greedy_blocks`). ``env``: an id, or an env as configured (:func:`~cartpole.envs.env_info`
    with kwargs and wrappers): the policy plays through its wrappers, but the returns are the env's
    own reward over its own episodes (:mod:`cartpole.envs.judged`), so no wrapper changes the rule
    (an episode a wrapper ends early leaves no verdict), and ``gymnasium.make``'s own arguments among
    its kwargs (``max_episode_steps``) are left out: the registry's time limit judges.
    """
    if not 1 <= episodes <= MAX_EPISODES:
        raise ValueError(f"episodes must be between 1 and {MAX_EPISODES:,}, got {episodes:,}")
    info = as_env_info(env)
    if seed is None:
        from cartpole.core.seeding import fresh_eval_seed

        seed = fresh_eval_seed()
    used = resolve_simulator(info, simulator)
    seeds = [seed + i for i in range(episodes)]
    returns: list[float] = []
    lengths: list[int] = []
    cut_by: list[str | None] = []
    for start in range(0, episodes, MAX_ENVS_PER_BATCH):
        batch = seeds[start : start + MAX_ENVS_PER_BATCH]
        batch_returns, batch_lengths = play_greedy_blocks(
            _PolicyActor(policy), info, batch, used, len(batch), workers, cut_by
        )
        returns += batch_returns.tolist()
        lengths += batch_lengths.tolist()
    return EvalReport.played(info, used, returns, lengths, seeds, cut_by)
