"""Train a population of seeds in one process: ``cartpole train ppo --seeds 0-99``.

Each seed is an ordinary run: its own run folder (config, status, metrics, checkpoints, verdict),
written by the same callbacks a single run uses (:func:`cartpole.training.session.make_callbacks`),
so ``cartpole runs``, ``eval`` and ``plot`` read it unchanged. Only the learning is shared: one
:class:`~cartpole.agents.population.Population` steps every seed's envs and updates every seed's
network (or scores every seed's generation) per ``learn()``, and the periodic evaluations of all the
seeds due at a step play together (:class:`PopulationEvaluations`). A seed that stops (verified
solve with stop-when-solved, or its budget) leaves the batch at once; the population ends when
every seed has stopped. The final verdicts (100 greedy episodes per seed on Gymnasium's own env,
seeds from :func:`final_eval_seed`) run as one batched evaluation on one Gymnasium vector env.

The config records ``population`` (an id and the seeds): ``--resume`` of any member continues every
unfinished member of its population.
"""

from __future__ import annotations

import re
import signal
import sys
import time
import uuid
from collections import Counter
from collections.abc import Callable
from contextlib import ExitStack, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cartpole.agents.actor_critic import stacked_greedy_actor
from cartpole.agents.learner import LearnResult
from cartpole.agents.population import Population, bytes_per_seed, make_population
from cartpole.agents.registry import POPULATION_AGENTS, get_agent
from cartpole.core.errors import InputError
from cartpole.core.memory import SHARE, fits_in_memory
from cartpole.core.names import CheckpointName, RunState, StopReason
from cartpole.core.seeding import MAX_TRAIN_SEED, eval_seed, final_eval_seed
from cartpole.envs import EnvInfo, Simulator, check_simulator, env_info
from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, Policy, play_greedy_blocks
from cartpole.runs import LiveStatus, RunDir, displayed_state, load_checkpoint
from cartpole.training.budget import Budget, parse_budget
from cartpole.training.callbacks import require_tensorboard, status_fields
from cartpole.training.config import TrainSettings, resolve_config
from cartpole.training.loop import LoopState, TrainingLoop, failure_detail
from cartpole.training.session import (
    RESUMABLE_STOPS,
    STOP_SIGNALS,
    AlreadyFinished,
    RunSetup,
    check_latest_exists,
    load_latest,
    make_callbacks,
    resolve_device,
    run_record,
    went_past_best,
)

MAX_SEEDS = 4096
"""More seeds than this in one process: split them (each seed holds a run folder and a status thread)."""

FLUSH_SECONDS = 5.0
"""How often each seed of a population writes its metric rows and status (a single run: every
second). A hundred seeds writing every second spend more on files than on bookkeeping; the status
thread's heartbeat still shows each run alive, and ``latest`` still writes the rows first."""

# ----------------------------------------------------------------------------------------------
# --seeds
# ----------------------------------------------------------------------------------------------

_RANGE = re.compile(r"^(\d+)-(\d+)$")


def parse_seeds(text: str) -> list[int]:
    """``0-99`` (inclusive range) or ``3,5,8`` or a mix (``0-9,20``); InputError on anything else:
    empty, malformed, reversed ranges, duplicates, seeds out of range."""
    hint = "use a range (0-99), a list (3,5,8) or both (0-9,20)"
    if not text.strip():
        raise InputError(f"--seeds is empty; {hint}")
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        match = _RANGE.match(part)
        if match:
            low, high = int(match.group(1)), int(match.group(2))
            if low > high:
                raise InputError(f"--seeds range {part!r} is reversed; write {high}-{low}")
            if len(seeds) + high - low + 1 > MAX_SEEDS:
                raise InputError(
                    f"--seeds asks for more than {MAX_SEEDS} seeds; split them into several runs"
                )
            seeds += range(low, high + 1)
        elif part.isdigit():
            seeds.append(int(part))
        else:
            raise InputError(f"--seeds {text!r}: {part!r} is not a seed or a range; {hint}")
        if len(seeds) > MAX_SEEDS:
            raise InputError(f"--seeds asks for more than {MAX_SEEDS} seeds; split them into several runs")
    duplicates = sorted(seed for seed, count in Counter(seeds).items() if count > 1)
    if duplicates:
        raise InputError(f"--seeds lists seed {duplicates[0]} more than once; each seed trains once")
    too_big = [s for s in seeds if s > MAX_TRAIN_SEED]
    if too_big:
        raise InputError(f"seed {too_big[0]} is out of range; seeds are 0 to {MAX_TRAIN_SEED}")
    return seeds


def check_memory(needed: int, seeds: int) -> None:
    """InputError, before anything is allocated, when ``needed`` bytes will not fit."""
    fits, free = fits_in_memory(needed)
    if not fits and free is not None:
        raise InputError(
            f"{seeds} seeds would take about {needed / 2**30:.1f} GiB but {free / 2**30:.1f} GiB is "
            f"available; use fewer seeds (about {int(seeds * SHARE * free / needed)} fit)"
        )


def check_population_agent(agent: str) -> None:
    if agent not in POPULATION_AGENTS:
        raise InputError(
            f"--seeds trains a population in one process, which only {', '.join(POPULATION_AGENTS)} offers; "
            f"train {agent} one seed at a time with --seed N"
        )


# ----------------------------------------------------------------------------------------------
# One seed, as the shared callbacks see it
# ----------------------------------------------------------------------------------------------


class SeedLearner:
    """One seed of a population behind the ``Learner`` protocol: what callbacks and checkpoints use.

    ``learn`` is the population's business (all seeds at once), so it is not offered here.
    """

    def __init__(self, population: Population, seed: int):
        self.population, self.seed = population, seed

    def learn(self) -> Any:
        raise RuntimeError("a population seed learns through its population's learn()")

    def policy(self) -> Policy:
        return self.population.seed_policy(self.seed)

    def state_dict(self, resume: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        return self.population.seed_state_dict(self.seed, resume)

    def load_state_dict(self, tensors: dict[str, Any], data: dict[str, Any]) -> None:
        self.population.load_seed_state_dict(self.seed, tensors, data)


class SeedLoop(TrainingLoop):
    """A seed's :class:`TrainingLoop`, advanced one population step at a time instead of ``run()``:
    the same counters and callback calls, in the same order."""

    def start(self, clock_start: float) -> None:
        self.clock_start = clock_start - self.state.elapsed
        for cb in self.callbacks:
            cb.on_start(self)

    def advance(self, result: LearnResult, now: float) -> None:
        if not self.count_result(result, now - self.clock_start):
            self.state.stop(StopReason.CALLBACK, "stopped by a callback")

    def end(self, now: float) -> None:
        self.state.elapsed = now - self.clock_start
        for cb in self.callbacks:
            cb.on_end(self)


class PopulationEvaluations:
    """The periodic evaluations of all seeds due at one step, played together.

    As :func:`~cartpole.training.callbacks.screened_evaluation` plays them for one seed (the same
    episode seeds, the same screen, the same full evaluation when the screen passes), but every due
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
        """Reports of the ``(seed, evaluation index)`` pairs in ``due``: screens on the fast
        simulator, then the full evaluation for the seeds whose screen reached the threshold."""
        settings, threshold = self.settings, self.env.reward_threshold
        screens = self.play(
            [seed for seed, _ in due],
            [eval_seed(seed, 2 * index) for seed, index in due],
            settings.eval_screen_episodes,
            "fast",
        )
        reports = {seed: report for (seed, _), report in zip(due, screens, strict=True)}
        passed = [
            (seed, index) for seed, index in due if threshold is not None and reports[seed].mean >= threshold
        ]
        if passed:
            full = self.play(
                [seed for seed, _ in passed],
                [eval_seed(seed, 2 * index + 1) for seed, index in passed],
                settings.eval_episodes,
                check_simulator(settings.eval_simulator),
            )
            reports.update(zip([seed for seed, _ in passed], full, strict=True))
        return reports

    def play(
        self, seeds: list[int], first_seeds: list[int], episodes: int, simulator: Simulator
    ) -> list[EvalReport]:
        """Seed i's greedy policy plays episodes from ``first_seeds[i], first_seeds[i] + 1, ...``."""
        episode_seeds = [[first + i for i in range(episodes)] for first in first_seeds]
        flat = [s for row in episode_seeds for s in row]
        returns, lengths = play_greedy_blocks(
            self.population.greedy_actor(seeds), self.env.env_id, flat, simulator, episodes
        )
        return [
            EvalReport(
                env_id=self.env.env_id,
                simulator=simulator,
                returns=returns[i * episodes : (i + 1) * episodes].tolist(),
                lengths=lengths[i * episodes : (i + 1) * episodes].tolist(),
                seeds=row,
                threshold=self.env.reward_threshold,
                max_episode_steps=self.env.max_episode_steps,
            )
            for i, row in enumerate(episode_seeds)
        ]


@dataclass
class Member:
    """One seed's run: its setup, status and loop."""

    setup: RunSetup
    status: LiveStatus
    loop: SeedLoop

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


# ----------------------------------------------------------------------------------------------
# Train and resume
# ----------------------------------------------------------------------------------------------


def train_population(
    agent: str,
    seeds: list[int],
    env_id: str = "CartPole-v1",
    *,
    preset: str = "default",
    overrides: dict[str, Any] | None = None,
    budget: Budget | str | None = None,
    runs_dir: Path | str = "runs",
    device: str = "auto",
    stop_when_solved: bool | None = None,
    quiet: bool = True,
    command: list[str] | None = None,
    stream: TextIO | None = None,
    tensorboard: bool = False,
) -> PopulationOutcome:
    """Train ``agent`` with every seed of ``seeds`` in one process; a run folder per seed.

    With ``tensorboard`` each seed's metrics also go to ``<run>/tensorboard/`` (the tensorboard extra).
    """
    check_population_agent(agent)
    if tensorboard:
        require_tensorboard()  # before a run folder is made
    if not seeds:
        raise InputError("no seeds to train")
    if len(set(seeds)) != len(seeds):
        raise InputError("each seed may appear once in a population")
    spec = get_agent(agent)
    env = env_info(env_id)
    config, settings = resolve_config(agent, spec.config_cls, preset, overrides)
    if stop_when_solved is not None:
        settings.stop_when_solved = stop_when_solved
    if isinstance(budget, str):
        budget = parse_budget(budget)
    budget = budget or parse_budget(settings.budget)
    device = population_device(device)
    check_memory(bytes_per_seed(config, env) * len(seeds), len(seeds))
    population = make_population(agent, config, env, seeds, device)
    population_record = {"id": uuid.uuid4().hex[:12], "seeds": list(seeds)}
    runs_path = Path(runs_dir)
    with ExitStack() as stack:
        setups = []
        for seed in seeds:
            run = RunDir.create(runs_path, env_id, agent, seed)
            stack.enter_context(run.lock())
            record = run_record(
                agent, env_id, seed, preset, config, settings, overrides, budget, device, command
            ) | {"population": population_record, "tensorboard": tensorboard}
            run.write_config(record)
            setups.append(RunSetup.from_record(run, record))
        return run_population(population, setups, {}, quiet, stream)


def population_device(device: str) -> str:
    """``cpu`` for ``auto``: a population runs on a GPU only when asked (``--device cuda``). Its envs
    step on the CPU whatever the device, so ``auto`` does not assume that a GPU pays;
    ``benchmarks/population.py --device cuda`` measures whether it does."""
    return "cpu" if device == "auto" else resolve_device(device)


def population_members(run_path: Path | str) -> list[RunDir]:
    """The run folders of the population that ``run_path`` belongs to (beside it, same id)."""
    run = RunDir.open(Path(run_path))
    record = run.config()
    population = record.get("population")
    if not population:
        return [run]
    members = []
    for path in sorted(run.path.parent.iterdir()):
        try:
            other = RunDir.open(path).config()
        except InputError:
            continue
        if (other.get("population") or {}).get("id") == population["id"]:
            members.append(RunDir(path))
    return members


def is_population_run(run_path: Path | str) -> bool:
    return bool(RunDir.open(Path(run_path)).config().get("population"))


def resume_population(
    run_path: Path | str,
    *,
    quiet: bool = True,
    stream: TextIO | None = None,
    device: str = "auto",
    from_scratch: bool = False,
) -> PopulationOutcome:
    """Continue every unfinished member of ``run_path``'s population from its ``latest.pt``, on
    ``device`` (the population's rule: ``auto`` is the CPU). LostProgress, before anything changes,
    if a member that has trained lost its ``latest.pt``, unless ``from_scratch``."""
    device = population_device(device)
    runs = [
        run for run in population_members(run_path) if displayed_state(run.status()) is not RunState.FINISHED
    ]
    if not runs:
        name = Path(run_path).name
        raise AlreadyFinished(f"every run of {name}'s population has finished; nothing to resume")
    with ExitStack() as stack:
        for run in runs:
            stack.enter_context(run.lock())
        setups = [RunSetup.from_record(run, run.config()) for run in runs]
        for run in runs:
            check_latest_exists(run, run.status(), from_scratch)
        first = setups[0]
        population = make_population(
            first.spec.name, first.config, first.env, [s.seed for s in setups], device
        )
        states: dict[int, LoopState] = {}
        for setup in setups:
            latest = setup.run.checkpoint_path(CheckpointName.LATEST)
            if not latest.exists():
                setup.run.truncate_metrics_after(0)
                continue  # killed before its first latest: starts over, the same run
            checkpoint = load_latest(latest)
            population.load_seed_state_dict(setup.seed, checkpoint.tensors, checkpoint.meta["learner"])
            state = LoopState.from_dict(checkpoint.meta["loop"])
            if state.stop_reason in RESUMABLE_STOPS:
                state.clear_stop()
            states[setup.seed] = state
            setup.run.truncate_metrics_after(state.env_steps)
        if not quiet:
            steps = [states[s.seed].env_steps if s.seed in states else 0 for s in setups]
            where = f"{min(steps):,}" if min(steps) == max(steps) else f"{min(steps):,} to {max(steps):,}"
            print(
                f"resuming {len(setups)} seed(s) of the population from env step {where} "
                "(each seed's checkpoints/latest.pt)",
                file=stream or sys.stderr,
            )
        return run_population(population, setups, states, quiet, stream)


def run_population(
    population: Population,
    setups: list[RunSetup],
    states: dict[int, LoopState],
    quiet: bool,
    stream: TextIO | None,
) -> PopulationOutcome:
    """Train every member until each has stopped, then give all the verdicts in one batch."""
    started = time.perf_counter()
    received: list[int] = []
    members: list[Member] = []
    evaluations = PopulationEvaluations(population, setups[0].env, setups[0].settings)
    with ExitStack() as stack:
        for setup in setups:
            status = stack.enter_context(LiveStatus(setup.run))
            callbacks = make_callbacks(
                setup, status, True, evaluator=evaluations.evaluator(setup.seed), flush_seconds=FLUSH_SECONDS
            )
            loop = SeedLoop(SeedLearner(population, setup.seed), callbacks, states.get(setup.seed))
            members.append(Member(setup, status, loop))
        progress = PopulationProgress(
            len(members), setups[0].budget, None if quiet else (stream or sys.stderr)
        )
        previous = {s: signal.signal(s, lambda signum, frame: received.append(signum)) for s in STOP_SIGNALS}
        active: dict[int, Member] = {}
        try:
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
        except BaseException as error:
            fail_every_member(members, active, error)
            raise
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
        reports = final_verdicts(members)
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
            with suppress(Exception):  # as a single run does: save latest if the state allows
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


# ----------------------------------------------------------------------------------------------
# The final verdicts, batched
# ----------------------------------------------------------------------------------------------


def final_verdicts(members: list[Member]) -> dict[int, EvalReport]:
    """Each member's kept best checkpoint on ``max(eval_episodes, 100)`` greedy episodes from seeds
    ``final_eval_seed(seed) + i``: the verdict :func:`cartpole.training.session.final_verdict` gives
    a single run, for all members in one vector env. Written to each ``eval.json``; and for members
    that trained on past their best (no stop at a solve), the last policy (``latest.pt``) on the same
    episodes, written to ``last_eval.json`` as :func:`~cartpole.training.session.last_policy_score`
    does for a single run."""
    reports = play_final_episodes(members, CheckpointName.BEST)
    for member in members:
        member.setup.run.write_eval(reports[member.seed].to_dict())
    went_on = [m for m in members if went_past_best(m.setup.run, m.loop.state)]
    if went_on:
        lasts = play_final_episodes(went_on, CheckpointName.LATEST)
        for member in went_on:
            step = {"step": member.loop.state.env_steps}
            member.setup.run.write_last_eval(lasts[member.seed].to_dict() | step)
    return reports


def play_final_episodes(members: list[Member], checkpoint: CheckpointName) -> dict[int, EvalReport]:
    """Each member's ``checkpoint`` policy on its verdict's episodes, all members in one vector env."""
    first = members[0].setup
    episodes = max(first.settings.eval_episodes, MIN_EPISODES_FOR_SOLVED)
    simulator = check_simulator(first.settings.eval_simulator)
    policies = [
        m.setup.spec.policy_from_checkpoint(load_checkpoint(m.setup.run.checkpoint_path(checkpoint)))
        for m in members
    ]
    episode_seeds = [[final_eval_seed(m.seed) + i for i in range(episodes)] for m in members]

    def act_one_by_one(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        rows = np.split(observations, len(blocks))  # policy b acts on block b's rows
        return np.concatenate([policies[b].act(mine) for b, mine in zip(blocks, rows, strict=True)])

    act = stacked_greedy_actor(list(policies), first.env.obs_dim) or act_one_by_one

    flat_seeds = [s for row in episode_seeds for s in row]
    returns, lengths = (
        x.reshape(len(members), episodes)
        for x in play_greedy_blocks(act, first.env.env_id, flat_seeds, simulator, episodes)
    )
    reports = {}
    for i, member in enumerate(members):
        report = EvalReport(
            env_id=first.env.env_id,
            simulator=simulator,
            returns=returns[i].tolist(),
            lengths=lengths[i].tolist(),
            seeds=episode_seeds[i],
            threshold=first.env.reward_threshold,
            max_episode_steps=first.env.max_episode_steps,
        )
        reports[member.seed] = report
    return reports


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
    lines = [f"{len(seeds)} runs in {folder}/ (seeds {seeds[0]}..{seeds[-1]}), {outcome.seconds:.1f} s"]
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
    "MAX_SEEDS",
    "PopulationOutcome",
    "check_population_agent",
    "is_population_run",
    "parse_seeds",
    "population_summary",
    "resume_population",
    "train_population",
]
