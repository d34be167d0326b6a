"""The engine: every run trains as a population, a single run being a population of one.

Each seed is an ordinary run: its own run folder (config, status, metrics, checkpoints, verdict),
written by the standard callbacks (:func:`cartpole.training.setup.make_callbacks`), so ``cartpole
runs``, ``eval``, ``plot`` and ``serve`` read it whatever the population. Only the learning is
shared: one :class:`~cartpole.agents.population.Population` steps every seed per ``learn()``, and the
periodic evaluations of all the seeds due at a step play together (:class:`PopulationEvaluations`).
A seed that stops (verified solve with stop-when-solved, or its budget) leaves the batch at once;
training ends when every seed has stopped. The final verdicts (100 greedy episodes per seed on
Gymnasium's own env, seeds from :func:`final_eval_seed`) run as one batched evaluation.
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np

from cartpole.agents.learner import LearnResult
from cartpole.agents.population import Population
from cartpole.core.names import CheckpointName, RunState, StopReason
from cartpole.core.seeding import describe_seeds, final_eval_seed
from cartpole.envs import EnvInfo, Simulator, check_simulator
from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, Policy, play_greedy_blocks
from cartpole.runs import LiveStatus, RunDir, load_checkpoint
from cartpole.training.budget import Budget
from cartpole.training.callbacks import MetricsCallback, screened_reports, status_fields, write_verdict
from cartpole.training.config import TrainSettings
from cartpole.training.loop import Callback, LoopState, TrainingLoop, failure_detail
from cartpole.training.setup import RunSetup, make_callbacks

FLUSH_SECONDS = 5.0
"""How often each seed of a population writes its metric rows and status (a single run: every
second). A hundred seeds writing every second spend more on files than on bookkeeping; the status
thread's heartbeat still shows each run alive, and ``latest`` still writes the rows first."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, *([signal.SIGBREAK] if hasattr(signal, "SIGBREAK") else []))
"""Ctrl-C, a kill, and on Windows Ctrl-Break (how the web app stops a training there)."""


@contextmanager
def signal_handler(handler: Any) -> Iterator[None]:
    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


class Interrupted(Exception):
    """A stop signal arrived while the final verdicts were being judged."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted ({signal.Signals(signum).name})")
        self.signum = signum


@contextmanager
def interrupt_on_signals() -> Iterator[None]:
    """While judging the verdicts, SIGINT/SIGTERM abandon them at once (raise :class:`Interrupted`)."""

    def handler(signum: int, frame: Any) -> None:
        raise Interrupted(signum)

    with signal_handler(handler):
        yield


def went_past_best(run: RunDir, state: LoopState) -> bool:
    """Whether training went on after the kept best checkpoint (it did not stop at a solve)."""
    if state.stop_reason is StopReason.SOLVED:
        return False
    return load_checkpoint(run.checkpoint_path(CheckpointName.BEST)).meta.get("step") != state.env_steps


class SeedLearner:
    """One seed of a population behind the ``Learner`` protocol: what callbacks and checkpoints use."""

    def __init__(self, population: Population, seed: int):
        self.population, self.seed = population, seed

    def policy(self) -> Policy:
        return self.population.seed_policy(self.seed)

    def state_dict(self, resume: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        return self.population.seed_state_dict(self.seed, resume)

    def load_state_dict(self, tensors: dict[str, Any], data: dict[str, Any]) -> None:
        self.population.load_seed_state_dict(self.seed, tensors, data)


class PopulationEvaluations:
    """The periodic evaluations of all seeds due at one step, played together.

    As :func:`~cartpole.training.callbacks.screened_evaluation` plays them for one seed (the same
    episode seeds; the same screen, full evaluation and confirmation, decided by the same
    :func:`~cartpole.training.callbacks.screened_reports`), but every due
    seed's episodes run in one vector env, with one batched forward pass of all their networks per
    env step. ``prepare`` runs before the seeds' loops see the step; each seed's evaluation
    callback then takes its report (``evaluator``) instead of evaluating alone.
    """

    def __init__(self, population: Population, env: EnvInfo, settings: TrainSettings):
        self.population, self.env, self.settings = population, env, settings
        self.waiting: dict[int, EvalReport] = {}

    def evaluator(self, seed: int) -> Callable[[TrainingLoop], EvalReport | None]:
        """Seed ``seed``'s report of this step, if one was prepared for it."""
        return lambda loop: self.waiting.pop(seed, None)

    def prepare(self, active: dict[int, Member], results: dict[int, LearnResult]) -> None:
        """Evaluate every seed whose loop will want an evaluation once it counts ``results``."""
        due = []
        for seed, result in results.items():
            state = active[seed].loop.state
            if state.env_steps + result.env_steps - state.last_eval_step >= self.settings.eval_every:
                due.append((seed, state.evaluations))
        self.waiting = self.screened(due) if due else {}

    def clear(self) -> None:
        self.waiting = {}

    def screened(self, due: list[tuple[int, int]]) -> dict[int, EvalReport]:
        """Reports of the ``(seed, evaluation index)`` pairs in ``due``
        (:func:`~cartpole.training.callbacks.screened_reports`)."""
        return screened_reports(due, self.play, self.env, self.settings)

    def play(
        self, seeds: list[int], first_seeds: list[int], episodes: int, simulator: Simulator
    ) -> list[EvalReport]:
        """Seed i's greedy policy plays episodes from ``first_seeds[i], first_seeds[i] + 1, ...``."""
        episode_seeds = [[first + i for i in range(episodes)] for first in first_seeds]
        flat = [s for row in episode_seeds for s in row]
        cut_by: list[str | None] = []
        returns, lengths = play_greedy_blocks(
            self.population.greedy_actor(seeds),
            self.env,
            flat,
            simulator,
            episodes,
            picture_workers(),
            cut_by,
        )
        return [
            EvalReport.played(
                self.env,
                simulator,
                returns[i * episodes : (i + 1) * episodes].tolist(),
                lengths[i * episodes : (i + 1) * episodes].tolist(),
                row,
                cut_by[i * episodes : (i + 1) * episodes],
            )
            for i, row in enumerate(episode_seeds)
        ]


@dataclass
class Member:
    """One seed's run: its setup, status and loop."""

    setup: RunSetup
    status: LiveStatus
    loop: TrainingLoop

    @property
    def seed(self) -> int:
        return self.setup.seed


@dataclass
class PopulationOutcome:
    """What a population session produced, per seed."""

    runs: dict[int, RunDir]
    states: dict[int, LoopState]
    reports: dict[int, EvalReport]
    """Final verdicts (empty when interrupted)."""
    seconds: float
    signal: int | None = None
    last_reports: dict[int, EvalReport] = field(default_factory=dict)
    """The last policies on their verdicts' episodes, for seeds that trained on past their best."""


def run_members(
    population: Population,
    setups: list[RunSetup],
    states: dict[int, LoopState],
    quiet: bool,
    stream: TextIO | None,
    extra: Sequence[Callback] = (),
) -> PopulationOutcome:
    """Train every member until each has stopped, then give all the verdicts in one batch.

    ``status.json`` of each says "running" (with a heartbeat) until its ``latest.pt`` and verdict are
    on disk; only then "finished". A kill, a signal or an error before that leaves runs that
    ``--resume`` accepts: they train on, or, when training was complete, only give the verdict.
    One member (a single run) shows the run's own progress bar and writes its files every second;
    a population shows one progress line for all and writes every few seconds.
    """
    started = time.perf_counter()
    received: list[int] = []
    members: list[Member] = []
    single = len(setups) == 1
    evaluations = PopulationEvaluations(population, setups[0].env, setups[0].settings)
    with ExitStack() as stack:
        for setup in setups:
            status = stack.enter_context(LiveStatus(setup.run))
            callbacks = make_callbacks(
                setup,
                status,
                quiet or not single,
                extra,
                evaluator=evaluations.evaluator(setup.seed),
                flush_seconds=MetricsCallback.FLUSH_SECONDS if single else FLUSH_SECONDS,
            )
            loop = TrainingLoop(SeedLearner(population, setup.seed), callbacks, states.get(setup.seed))
            members.append(Member(setup, status, loop))
        progress = PopulationProgress(
            len(members), setups[0].budget, None if quiet or single else (stream or sys.stderr)
        )
        active: dict[int, Member] = {}
        try:
            with signal_handler(lambda signum, frame: received.append(signum)):
                for member in members:
                    member.loop.start(started)
                    active[member.seed] = member
                end_stopped(population, active, time.perf_counter())
                while active and not received:
                    results = population.learn()
                    evaluations.prepare(active, results)
                    now = time.perf_counter()
                    for seed, result in results.items():
                        active[seed].loop.advance(result, now)
                    evaluations.clear()
                    end_stopped(population, active, now)
                    progress.update(members, now - started)
            if received:
                return interrupt(population, members, active, received[0], started)
            with interrupt_on_signals():
                reports, lasts = final_verdicts(members)
        except Interrupted as stop:
            return interrupt_verdicts(members, stop, started)
        except BaseException as error:
            fail_every_member(members, active, error)
            raise
        for member in members:
            report = reports[member.seed]
            member.status.write(
                RunState.FINISHED, status_fields(member.loop.state) | {"solved": report.solved}
            )
        progress.finish(members, reports, time.perf_counter() - started)
        return PopulationOutcome(
            runs={m.seed: m.setup.run for m in members},
            states={m.seed: m.loop.state for m in members},
            reports=reports,
            seconds=time.perf_counter() - started,
            last_reports=lasts,
        )


def end_stopped(population: Population, active: dict[int, Member], now: float) -> None:
    """End the loops of members that have stopped (their callbacks save ``latest``, judge the last
    policy), then drop them from the population's batch."""
    stopped = [seed for seed, m in active.items() if m.loop.state.stop_reason is not None]
    for seed in stopped:
        active.pop(seed).loop.end(now)
    if stopped and active:
        population.remove(stopped)


def fail_every_member(members: list[Member], active: dict[int, Member], error: BaseException) -> None:
    """An error ended the population: every seed's status says so (a full disk: "failed: disk full"),
    those training save ``latest`` where they still can, and none is left showing "running"."""
    now = time.perf_counter()
    detail = failure_detail(error)
    for member in members:
        if member.loop.state.stop_reason is None or member.seed in active:
            member.loop.state.stop(StopReason.FAILED, detail)
        if member.seed in active:
            with suppress(Exception):  # save latest where the state still allows it
                member.loop.end(now)
        fields = status_fields(member.loop.state)
        if member.loop.state.stop_reason is not StopReason.FAILED:  # it had stopped; then saving failed
            fields["stop_detail"] = f"{detail}, after {member.loop.state.stop_detail}"
        with suppress(OSError):
            member.status.write(RunState.FAILED, fields)


def interrupt(
    population: Population, members: list[Member], active: dict[int, Member], signum: int, started: float
) -> PopulationOutcome:
    """A stop signal: every member still training saves ``latest`` and is marked interrupted."""
    now = time.perf_counter()
    detail = f"interrupted ({signal.Signals(signum).name})"
    for member in active.values():
        member.loop.state.stop(StopReason.INTERRUPTED, detail)
        member.loop.end(now)
        member.status.write(RunState.INTERRUPTED, status_fields(member.loop.state))
    for member in members:
        if member.seed not in active:  # stopped before the signal: training complete, verdict missing
            member.status.write(RunState.INTERRUPTED, status_fields(member.loop.state))
    return PopulationOutcome(
        runs={m.seed: m.setup.run for m in members},
        states={m.seed: m.loop.state for m in members},
        reports={},
        seconds=now - started,
        signal=signum,
    )


def interrupt_verdicts(members: list[Member], stop: Interrupted, started: float) -> PopulationOutcome:
    """A stop signal while judging: training is complete and saved; the verdicts are left to a resume."""
    for member in members:
        state = member.loop.state
        state.stop_detail = f"{state.stop_detail}; verdict {stop}"
        member.status.write(RunState.INTERRUPTED, status_fields(state))
    return PopulationOutcome(
        runs={m.seed: m.setup.run for m in members},
        states={m.seed: m.loop.state for m in members},
        reports={},
        seconds=time.perf_counter() - started,
        signal=stop.signum,
    )


# ----------------------------------------------------------------------------------------------
# The final verdicts, batched
# ----------------------------------------------------------------------------------------------


def final_verdicts(members: list[Member]) -> tuple[dict[int, EvalReport], dict[int, EvalReport]]:
    """Each member's kept best checkpoint on ``max(eval_episodes, 100)`` greedy episodes from seeds
    ``final_eval_seed(seed) + i`` (seeds no training or evaluation used, derived from the run's seed,
    so the same run gives the same verdict; ``cartpole eval`` judges it again on any other seeds),
    all members in one vector env. Written to each ``eval.json`` (and with TensorBoard, its metrics);
    and for members that trained on past their best (no stop at a solve), the last policy
    (``latest.pt``) on the same episodes, written to ``last_eval.json`` (not a verdict: shown when it
    disagrees). Returns both, by seed."""
    reports = play_final_episodes(members, CheckpointName.BEST)
    for member in members:
        member.setup.run.write_eval(reports[member.seed].to_dict())
        if member.setup.tensorboard:  # the metrics of the run's hyperparameters in TensorBoard
            write_verdict(member.setup.run, reports[member.seed], member.loop.state.env_steps)
    went_on = [m for m in members if went_past_best(m.setup.run, m.loop.state)]
    lasts = play_final_episodes(went_on, CheckpointName.LATEST) if went_on else {}
    for member in went_on:
        step = {"step": member.loop.state.env_steps}
        member.setup.run.write_last_eval(lasts[member.seed].to_dict() | step)
    return reports, lasts


MAX_PICTURE_WORKERS = 4
"""The most processes that draw Gymnasium's pictures in one evaluation: each holds its own imports
(numba's compiler among them) and envs, so more would cost memory that a few already save little of."""


def picture_workers() -> int:
    """How many processes draw Gymnasium's pictures in a pixel env's evaluations: as many as the
    threads torch computes with (the CLI's ``--torch-threads``, read here), at most
    :data:`MAX_PICTURE_WORKERS`. While they draw, the policy acts on one of those threads
    (:func:`~cartpole.evaluation.play_greedy_blocks`): the workers use the cores."""
    import torch

    return min(torch.get_num_threads(), MAX_PICTURE_WORKERS)


def play_final_episodes(members: list[Member], checkpoint: CheckpointName) -> dict[int, EvalReport]:
    """Each member's ``checkpoint`` policy on its verdict's episodes, all members in one vector env."""
    first = members[0].setup
    episodes = max(first.settings.eval_episodes, MIN_EPISODES_FOR_SOLVED)
    simulator = check_simulator(first.settings.final_simulator)
    policies = [
        m.setup.spec.policy_from_checkpoint(load_checkpoint(m.setup.run.checkpoint_path(checkpoint)))
        for m in members
    ]
    episode_seeds = [[final_eval_seed(m.seed) + i for i in range(episodes)] for m in members]
    act = first.spec.policies_actor(policies, first.env.obs_dim)

    flat_seeds = [s for row in episode_seeds for s in row]
    cut_by: list[str | None] = []
    returns, lengths = (
        x.reshape(len(members), episodes)
        for x in play_greedy_blocks(
            act, first.env, flat_seeds, simulator, episodes, picture_workers(), cut_by
        )
    )
    return {
        member.seed: EvalReport.played(
            first.env,
            simulator,
            returns[i].tolist(),
            lengths[i].tolist(),
            episode_seeds[i],
            cut_by[i * episodes : (i + 1) * episodes],
        )
        for i, member in enumerate(members)
    }


# ----------------------------------------------------------------------------------------------
# Progress
# ----------------------------------------------------------------------------------------------


class PopulationProgress:
    """A line every few seconds: seeds solved, seeds still training, the slowest seed's steps."""

    SECONDS = 5.0

    def __init__(self, seeds: int, budget: Budget, stream: TextIO | None):
        self.seeds, self.budget, self.stream = seeds, budget, stream
        self.last = time.perf_counter()

    def update(self, members: list[Member], elapsed: float) -> None:
        now = time.perf_counter()
        if self.stream is None or now - self.last < self.SECONDS:
            return
        self.last = now
        print(f"[{elapsed:7.1f}s] {self.describe(members, elapsed)}", file=self.stream, flush=True)

    def describe(self, members: list[Member], elapsed: float) -> str:
        states = [m.loop.state for m in members]
        solved = sum(s.solved for s in states)
        training = [s for s in states if s.stop_reason is None]
        total = sum(s.env_steps for s in states)
        limit = f"/{self.budget.env_steps:,}" if self.budget.env_steps else ""
        slowest = min((s.env_steps for s in training), default=max(s.env_steps for s in states))
        return (
            f"solved {solved}/{self.seeds} seeds, {len(training)} training, "
            f"slowest seed {slowest:,}{limit} steps, {total / max(elapsed, 1e-9):,.0f} steps/s"
        )

    def finish(self, members: list[Member], reports: dict[int, EvalReport], elapsed: float) -> None:
        if self.stream is None:
            return
        verified = sum(r.solved for r in reports.values())
        print(
            f"[{elapsed:7.1f}s] done: {verified}/{self.seeds} seeds verified solved on fresh episodes; "
            f"{self.describe(members, elapsed)}",
            file=self.stream,
            flush=True,
        )


def population_summary(outcome: PopulationOutcome) -> list[str]:
    """Lines for the CLI: where the runs are, how many solved, the solve steps."""
    seeds = sorted(outcome.runs)
    folder = outcome.runs[seeds[0]].path.parent
    lines = [f"{len(seeds)} runs in {folder}/ (seeds {describe_seeds(seeds)}), {outcome.seconds:.1f} s"]
    solved_at = [s.solved_at_step for s in outcome.states.values() if s.solved_at_step is not None]
    if solved_at:
        lines.append(
            f"solved in training: {len(solved_at)}/{len(seeds)}, "
            f"median {int(np.median(solved_at)):,} env steps"
        )
    if outcome.reports:
        verified = sum(r.solved for r in outcome.reports.values())
        lines.append(
            f"verdicts: {verified}/{len(seeds)} SOLVED on 100 fresh episodes of Gymnasium's env each "
            "(each seed's kept best checkpoint)"
        )
        lasts = {s: outcome.runs[s].last_eval_report() for s in seeds if s in outcome.reports}
        disagree = [s for s, last in lasts.items() if last and last["solved"] != outcome.reports[s].solved]
        if disagree:
            lines.append(
                f"the last policy disagrees with the verdict for {len(disagree)} seed(s), "
                f"e.g. seed {disagree[0]} (its last_eval.json)"
            )
    return lines


__all__ = [
    "STOP_SIGNALS",
    "Interrupted",
    "PopulationEvaluations",
    "PopulationOutcome",
    "population_summary",
    "run_members",
    "went_past_best",
]
