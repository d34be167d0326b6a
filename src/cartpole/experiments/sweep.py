"""``cartpole sweep``: tune an agent with Optuna, K seeds per trial, from one process to many machines.

Objective (minimized): the median over the trial's K seeds (``--seeds``, the same for every trial) of
the env steps to the first verified solve; a seed that does not solve within its budget counts as twice
the env steps it used. The K seeds train together, as one population (``--seeds``: batched, each seed
bit for bit its run alone). After every evaluation of any seed the trial reports a lower bound of that
median (each seed at its solve, or at the env steps it has used; seeds not yet evaluated at 0); the
pruner stops a trial as soon as that lower bound exceeds the median cost of the complete trials, so it
never stops a trial that would have ended better than that median.

Storage: by default a journal file, ``D/sweeps/NAME/journal.log`` (Optuna's JournalFileBackend, safe for
the J local workers); with ``--storage postgresql://user@host:port/db`` every machine that runs the same
command joins one study. ``--trials N`` is the number of finished (complete or pruned) trials the study
should hold: workers stop when it does, a re-run with a larger N adds trials, and an interrupted trial is
marked failed and replaced. The best trial is written as ``D/sweeps/NAME/best.toml``, a preset file.
"""

from __future__ import annotations

import contextlib
import functools
import json
import signal
import statistics
import sys
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import optuna

from cartpole.evaluation import EvalReport
from cartpole.experiments.best import best_value, write_best
from cartpole.experiments.compare import check_name
from cartpole.experiments.entries import ExperimentError
from cartpole.experiments.processes import Job, python_module, run_jobs
from cartpole.experiments.slots import Slot
from cartpole.experiments.space import load_space, preset_point, space_description
from cartpole.experiments.storage import (
    StorageLost,
    describe_url,
    driver_url,
    engine_options,
    lost_connection,
    missing_driver,
    retry_lost_connection,
    unreachable,
)
from cartpole.experiments.sweep_spec import SweepSpec
from cartpole.runs.atomic import write_json_atomic
from cartpole.training import Callback, TrainingLoop
from cartpole.training.budget import check_budget_unit, parse_budget

WORKER = "cartpole.experiments.sweep"
UNSOLVED_FACTOR = 2
"""A seed that never solves costs this many times the env steps it used."""
STUDY_ATTR = "cartpole"
STARTUP_TRIALS = 5
"""Random trials before TPE models the results (Optuna's default is 10: too many for short sweeps)."""
DONE_STATES = ("COMPLETE", "PRUNED")


def make_spec(
    runs_dir: Path,
    name: str,
    agent: str,
    preset: str | None,
    trials: int,
    seeds: list[int],
    env_id: str = "CartPole-v1",
    budget: str | None = None,
    space_file: str | None = None,
    storage: str | None = None,
    sampler_seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    tensorboard: bool = False,
) -> SweepSpec:
    """Check every input (one line each if wrong) before anything is written."""
    from cartpole.agents.registry import agent_names, get_agent
    from cartpole.envs import env_info
    from cartpole.experiments.entries import parse_entry

    check_name(name, "study")
    if agent not in agent_names():
        raise ExperimentError(f"unknown agent {agent!r}; choose one of: {', '.join(agent_names())}")
    if trials < 1:
        raise ExperimentError(f"--trials must be >= 1, got {trials}")
    if not seeds:
        raise ExperimentError("a trial needs at least one seed")
    if budget is not None:
        try:
            check_budget_unit(parse_budget(budget), agent, get_agent(agent).iteration)
        except ValueError as err:
            raise ExperimentError(str(err)) from None
    env_info(env_id, env_kwargs)
    if tensorboard:
        from cartpole.training.callbacks import require_tensorboard

        require_tensorboard()
    entry = parse_entry(f"{agent}:{preset or ''}", env_id)
    preset = str(Path(entry.preset).resolve()) if entry.preset.endswith(".toml") else entry.preset
    space, text = load_space(agent, preset, space_file)
    return SweepSpec(
        name=name,
        agent=agent,
        preset=preset,
        env_id=env_id,
        budget=budget,
        seeds_per_trial=len(seeds),
        seeds=list(seeds),
        trials=trials,
        space_text=text,
        storage=storage,
        folder=str(runs_dir / "sweeps" / name),
        sampler_seed=sampler_seed,
        env_kwargs=dict(env_kwargs or {}),
        space=space_description(space),
        tensorboard=tensorboard,
    )


# ----------------------------------------------------------------------------------------------
# Storage and study
# ----------------------------------------------------------------------------------------------


def open_storage(spec: SweepSpec, attempts: int = 5) -> Any:
    """Optuna storage of the sweep: the journal file, or the database at ``spec.storage``."""
    import time

    import optuna
    from sqlalchemy.exc import OperationalError, SQLAlchemyError

    if spec.storage is None:
        from optuna.storages.journal import JournalFileBackend

        spec.path.mkdir(parents=True, exist_ok=True)
        return optuna.storages.JournalStorage(JournalFileBackend(str(spec.path / "journal.log")))
    backend, where = describe_url(spec.storage)
    url, engine = driver_url(spec.storage), engine_options(spec.storage)
    for attempt in range(attempts):
        try:
            with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna, and what we need
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return ReconnectingStorage(url, engine_kwargs=engine, heartbeat_interval=30, grace_period=120)
        except ImportError as err:  # Optuna re-raises the driver's ModuleNotFoundError as ImportError
            raise missing_driver(spec.storage, err) from None
        except OperationalError as err:  # no server there, or a wrong host, port, user or database
            raise unreachable(spec.storage, err) from None
        except SQLAlchemyError as err:
            reason = str(getattr(err, "orig", None) or err).strip().splitlines()[0]
            if attempt == attempts - 1:  # e.g. two machines creating the tables at the same moment
                raise ExperimentError(f"the {backend} study storage at {where} failed: {reason}") from None
            time.sleep(1.0 + attempt)
    raise AssertionError("unreachable")


class ReconnectingStorage(optuna.storages.RDBStorage):
    """Optuna's RDBStorage, each of whose calls is tried again while it loses its connection (a
    database server restarting): a line each time, for a few minutes
    (:func:`~cartpole.experiments.storage.retry_lost_connection`), so that neither the sweep nor its
    workers fail their trials for it. Each call is one transaction of Optuna's."""


_INSIDE = threading.local()
"""Whether this thread is inside a retried call already (whose own calls then are not retried apart)."""


def _reconnecting(name: str) -> Callable[..., Any]:
    method = getattr(optuna.storages.RDBStorage, name)
    what = name.strip("_").replace("_", " ") + " in the study"

    @functools.wraps(method)
    def call(self: ReconnectingStorage, *args: Any, **kwargs: Any) -> Any:
        if getattr(_INSIDE, "call", False):
            return method(self, *args, **kwargs)
        _INSIDE.call = True
        try:
            return retry_lost_connection(what, lambda: method(self, *args, **kwargs))
        finally:
            _INSIDE.call = False

    return call


RETRIED_CALLS = (
    "create_new_study", "delete_study", "set_study_user_attr", "set_study_system_attr",
    "get_study_id_from_name", "get_study_name_from_id", "get_study_directions", "get_study_user_attrs",
    "get_study_system_attrs", "get_trial_user_attrs", "get_trial_system_attrs", "get_all_studies",
    "create_new_trial", "set_trial_param", "get_trial_param", "set_trial_state_values",
    "set_trial_intermediate_value", "set_trial_user_attr", "set_trial_system_attr",
    "get_trial_id_from_study_id_trial_number", "get_trial", "get_all_trials", "get_best_trial",
    "record_heartbeat", "_create_new_trial", "_get_best_trial_id", "_get_stale_trial_ids", "_get_trials",
    "_set_trial_param",
)  # fmt: skip
"""RDBStorage's calls on the database (Optuna 5), its private ones that Optuna's cache calls included."""
for _name in RETRIED_CALLS:
    setattr(ReconnectingStorage, _name, _reconnecting(_name))


def open_study(spec: SweepSpec, storage: Any) -> Any:
    """The sweep's study, created if new; ExperimentError if it exists for another sweep."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:  # load first: creating an existing study would still append to a journal
        study = optuna.load_study(
            study_name=spec.name, storage=storage, sampler=sampler_for(spec, 0), pruner=BoundPruner()
        )
    except KeyError:
        study = optuna.create_study(
            study_name=spec.name,
            storage=storage,
            direction="minimize",
            load_if_exists=True,  # another machine may create it at the same moment
            sampler=sampler_for(spec, 0),
            pruner=BoundPruner(),
        )
        if not study.get_trials(deepcopy=False):  # a new study starts from the preset itself
            study.enqueue_trial(preset_point(spec.agent, spec.preset, spec.params()), skip_if_exists=True)
    recorded = study.user_attrs.get(STUDY_ATTR)
    if recorded is None:
        study.set_user_attr(STUDY_ATTR, spec.identity)
        recorded = spec.identity
    if recorded != json.loads(json.dumps(spec.identity)):
        differs = [k for k in spec.identity if recorded.get(k) != json.loads(json.dumps(spec.identity[k]))]
        what = ", ".join(f"{k} {recorded.get(k)!r}" for k in differs if k != "space")
        if "space" in differs:
            what = (what + ", " if what else "") + "another search space"
        raise ExperimentError(
            f"study {spec.name} in {spec.storage_label} exists for {what}; use another --study name"
        )
    return study


class BoundPruner(optuna.pruners.BasePruner):
    """Prune when a trial's reported lower bound of its cost exceeds the median cost of complete trials.

    Optuna's MedianPruner compares a trial's best intermediate value, which for a rising lower bound is
    its first one, so it would never prune; this rule fits a bound.
    """

    def __init__(self, startup_trials: int = 3):
        self.startup_trials = startup_trials

    def prune(self, study: Any, trial: Any) -> bool:
        from optuna.trial import TrialState

        step = trial.last_step
        if step is None:
            return False
        complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        if len(complete) < self.startup_trials:
            return False
        return bool(trial.intermediate_values[step] > statistics.median(t.value for t in complete))


def sampler_for(spec: SweepSpec, trial_number: int) -> Any:
    """TPE seeded per trial: the same study gives the same suggestions, whichever worker runs a trial."""
    import optuna

    return optuna.samplers.TPESampler(
        seed=spec.sampler_seed + trial_number, constant_liar=True, n_startup_trials=STARTUP_TRIALS
    )


def count_trials(study: Any) -> dict[str, int]:
    counts: dict[str, int] = {}
    for trial in study.get_trials(deepcopy=False):
        counts[trial.state.name] = counts.get(trial.state.name, 0) + 1
    return counts


def fail_abandoned_trials(study: Any) -> int:
    """Mark RUNNING trials failed: called only when no worker of this study can be running them."""
    from optuna.trial import TrialState

    abandoned = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    for trial in abandoned:
        study._storage.set_trial_state_values(trial._trial_id, state=TrialState.FAIL)
    return len(abandoned)


# ----------------------------------------------------------------------------------------------
# One worker: trials until the study holds enough
# ----------------------------------------------------------------------------------------------


class Surplus(Exception):
    """Another worker took the last trial this one would have run."""


class Interrupted(Exception):
    """Ctrl-C (or SIGTERM) stopped the trial; it is marked failed and will be replaced."""


class PruneReporter(Callback):
    """After each evaluation of any of the trial's seeds (trained together): report the lower bound of
    the trial's cost, the median of the seeds' running costs (env steps so far, or at the solve); once
    the pruner says so, every unsolved seed stops at its next evaluation."""

    def __init__(self, trial: Any, seeds: int):
        self.trial, self.seeds = trial, seeds
        self.running: dict[int, float] = {}
        """Each evaluated seed's cost so far, by its loop."""
        self.reports = 0
        self.pruned = False

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        state = loop.state
        self.running[id(loop)] = float((state.solved_at_step if state.solved else state.env_steps) or 0)
        bound = [*self.running.values()] + [0.0] * (self.seeds - len(self.running))
        self.reports += 1
        self.trial.report(float(statistics.median(bound)), self.reports)
        if not self.pruned and not state.solved and self.trial.should_prune():
            self.pruned = True
        return state.solved or not self.pruned


@contextlib.contextmanager
def stop_flag() -> Iterator[list[int]]:
    """SIGINT/SIGTERM outside training only note the request (training has its own handler)."""
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield received
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def trial_cost(
    spec: SweepSpec, trial: Any, params: dict[str, Any], stop: list[int], device: str = "cpu"
) -> float:
    """Train the trial's K seeds as one population on ``device`` (noted in the trial's ``device``
    attribute); the median cost, or TrialPruned / Interrupted."""
    import optuna

    from cartpole.training.session import train_population

    if stop:
        raise Interrupted
    reporter = PruneReporter(trial, spec.seeds_per_trial)
    trial.set_user_attr("device", device)
    outcome = train_population(
        spec.agent,
        spec.trial_seeds,
        spec.env_id,
        preset=spec.preset,
        overrides=params | ({"env_kwargs": spec.env_kwargs} if spec.env_kwargs else {}),
        budget=spec.budget,
        runs_dir=spec.path / "runs",
        device=device,
        quiet=True,
        command=["cartpole", "sweep", spec.agent, "--study", spec.name, f"(trial {trial.number})"],
        tensorboard=spec.tensorboard,
        callbacks=[reporter],
    )
    for seed, run in outcome.runs.items():
        trial.set_user_attr(f"run_seed{seed}", str(run.path))
    if outcome.signal is not None:
        stop.append(outcome.signal)
        raise Interrupted
    costs = []
    for seed, state in outcome.states.items():
        solved_at = state.solved_at_step
        cost = float(solved_at if solved_at is not None else UNSOLVED_FACTOR * state.env_steps)
        costs.append(cost)
        trial.set_user_attr(f"cost_seed{seed}", cost)
    if reporter.pruned:
        raise optuna.TrialPruned(f"pruned after {reporter.reports} evaluations")
    return float(statistics.median(costs))


def run_worker(spec: SweepSpec, device: str = "cpu") -> int:
    """Run trials on ``device`` until the study holds ``spec.trials`` finished ones; 130 if interrupted."""
    from optuna.trial import TrialState

    study = open_study(spec, open_storage(spec))
    params = spec.params()
    live = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING, TrialState.WAITING)

    def objective(trial: optuna.Trial) -> float:
        ahead = [t for t in study.get_trials(deepcopy=False, states=live) if t.number < trial.number]
        if len(ahead) >= spec.trials:
            trial.set_user_attr("surplus", True)
            raise Surplus
        study.sampler = sampler_for(spec, trial.number)
        chosen = {name: p.suggest(trial) for name, p in params.items()}
        try:
            return trial_cost(spec, trial, chosen, stop, device)
        except Interrupted:
            trial.set_user_attr("interrupted", True)
            raise

    with stop_flag() as stop:
        while not stop:
            done = study.get_trials(deepcopy=False, states=live[:3])
            if len(done) >= spec.trials:
                return 0
            before = len(study.get_trials(deepcopy=False))
            study.optimize(objective, n_trials=1, catch=(Surplus, Interrupted))
            last = max(study.get_trials(deepcopy=False)[before:], key=lambda t: t.number, default=None)
            if last is not None and last.user_attrs.get("surplus"):
                return 0
    return 130


# ----------------------------------------------------------------------------------------------
# The sweep: J workers, progress, best.toml
# ----------------------------------------------------------------------------------------------


def write_spec(spec: SweepSpec) -> Path:
    path = spec.path / "sweep.json"
    spec.path.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, asdict(spec))
    return path


@contextlib.contextmanager
def local_lock(spec: SweepSpec) -> Iterator[bool]:
    """Whether this is the only ``cartpole sweep`` of this study on this machine (a lock file)."""
    from filelock import FileLock, Timeout

    lock = FileLock(str(spec.path / ".sweep.lock"))
    try:
        lock.acquire(timeout=0)
    except Timeout:
        yield False
        return
    try:
        yield True
    finally:
        lock.release()


def prepare_sweep(spec: SweepSpec, workers: int | Sequence[Slot]) -> Any:
    """Check the worker count, the storage and the study (ExperimentError, nothing written); the study."""
    if isinstance(workers, int) and workers < 1:
        raise ExperimentError(f"--workers must be >= 1, got {workers}")
    return open_study(spec, open_storage(spec))


def run_sweep(
    spec: SweepSpec,
    study: Any,
    workers: int | Sequence[Slot],
    progress: Callable[[dict[str, int], Any], None] | None,
) -> Any:
    """Run a worker process in each slot of ``workers`` (a count: CPU slots) on the prepared ``study``,
    then write best.toml; the study.

    KeyboardInterrupt stops every worker (each marks its trial failed) and propagates after best.toml.
    """
    spec_path = write_spec(spec)
    with local_lock(spec) as alone:
        if alone and spec.storage is None:
            fail_abandoned_trials(study)  # left RUNNING by a killed sweep: nobody else can own them
        jobs = [
            Job(python_module(WORKER, str(spec_path)), spec.path / "logs" / f"worker{i}.log", i)
            for i in range(workers if isinstance(workers, int) else len(workers))
        ]
        problems: list[str] = []

        def on_done(job: Job, code: int) -> None:
            if code not in (0, 130, -2):
                problems.append(f"worker {job.key} failed (exit {code}); see {job.log}")

        clock = {"ticks": 0}

        def tick() -> None:
            clock["ticks"] += 1
            if progress and clock["ticks"] % 5 == 0:
                progress(count_trials(study), best_value(study))

        try:
            run_jobs(jobs, workers, on_done, tick)
        except Exception as err:
            if lost_connection(err):  # its workers stopped, each marking its trial failed where it can
                raise StorageLost.of(err, "follow the study") from None
            raise
        finally:
            try:
                if progress:
                    progress(count_trials(study), best_value(study))
                write_best(spec, study)
            except Exception as err:  # the study out of reach: best.toml waits for a re-run
                if not lost_connection(err):
                    raise
    if problems:
        raise SweepFailed("; ".join(problems))
    return study


class SweepFailed(Exception):
    """A worker process failed (not bad input: its log says why)."""


def main(argv: list[str]) -> int:
    """Worker entry: ``python -m cartpole.experiments.sweep SWEEP.json [--device cpu|cuda]``, training
    on that device (default: cpu) on ``cartpole train``'s default torch thread count. It stops as on
    Ctrl-C when its parent asks or is gone (:func:`~cartpole.experiments.processes.follow_parent`); 130
    when stopped."""
    from cartpole.experiments.processes import follow_parent
    from cartpole.training.threads import default_torch_threads, torch_threads

    try:
        follow_parent()  # inside: a stop asked for already interrupts as soon as it returns
        spec = SweepSpec(**json.loads(Path(argv[0]).read_text(encoding="utf-8")))
        device = argv[argv.index("--device") + 1] if "--device" in argv else "cpu"
        with torch_threads(default_torch_threads(spec.env_id)):
            return run_worker(spec, device)
    except ExperimentError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # stopped before its trials began (stop_flag notes a later stop)
        return 130


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
