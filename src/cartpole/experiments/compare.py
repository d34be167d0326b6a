"""``cartpole compare``: N seeds of each entry, J at a time, summarized with honest statistics.

Layout of ``D/experiments/NAME/``::

    experiment.json        what was asked (env, budget); a re-run must ask the same
    records/<entry>__s<seed>.json   one per run: its run folder, when it solved, what it used, its verdict
    runs/                  the ordinary run folders (``cartpole runs --runs-dir D/experiments/NAME/runs``)
    logs/                  each worker's output
    report.json, report.md, curves.png, solve_steps.png

Re-running the same command resumes: finished runs are kept, interrupted ones resume from their
``latest.pt``, and new seeds are added when ``--seeds`` grows. An entry whose agent batches its seeds
(:meth:`~cartpole.agents.registry.AgentSpec.batches`) runs its pending seeds as one job: one process,
ordinary run folders, a record each.
"""

from __future__ import annotations

import re
import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from cartpole.agents.registry import get_agent
from cartpole.core.file_names import is_portable_name
from cartpole.experiments.entries import Entry, ExperimentError
from cartpole.experiments.pause_points import pause_at
from cartpole.experiments.processes import Job, python_module, run_job_source, run_jobs
from cartpole.experiments.shared import SETUP_FLAGS, Claim, RowState, SharedComparison, new_owner
from cartpole.experiments.slots import Slot
from cartpole.experiments.storage import StorageLost, lost_connection, reason_of, retry_lost_connection
from cartpole.experiments.worker import FINISHED, Task, read_record
from cartpole.runs.atomic import write_json_atomic
from cartpole.runs.run_dir import read_json
from cartpole.training.budget import check_budget_unit, parse_budget

KILLED_RETRIES = 2
"""Times a shared comparison's machine claims again the runs of a worker killed by a signal."""
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
WORKER = "cartpole.experiments.worker"


def check_name(name: str, what: str) -> str:
    """``name``, the folder name of an experiment or a study, if every OS accepts it; ExperimentError
    otherwise (refused, not changed: the person finds it again under the name they gave)."""
    if not NAME.match(name):
        raise ExperimentError(f"{what} name {name!r}: use letters, digits, '.', '_' and '-'")
    if not is_portable_name(name):
        raise ExperimentError(
            f"{what} name {name!r} is not a folder name on Windows (it ends in '.', or is a device name "
            "such as NUL or COM1): choose another"
        )
    return name


def check_jobs(jobs: int | Sequence[Slot]) -> None:
    if isinstance(jobs, int) and jobs < 1:
        raise ExperimentError(f"--jobs must be >= 1, got {jobs}")


@dataclass
class Experiment:
    """An experiment folder and what it runs."""

    folder: Path
    entries: list[Entry]
    seeds: list[int]
    env_id: str
    budget: str | None
    command: list[str] = field(default_factory=list)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """``--env-kwargs``: every entry's env made with them (over its preset's own ``env_kwargs``)."""
    tensorboard: bool = False
    """``--tensorboard``: the runs this command trains also log TensorBoard events in their folders."""

    @classmethod
    def open(
        cls,
        runs_dir: Path,
        name: str,
        entries: list[Entry],
        seeds: list[int],
        env_id: str = "CartPole-v1",
        budget: str | None = None,
        command: list[str] | None = None,
        env_kwargs: dict[str, Any] | None = None,
        tensorboard: bool = False,
    ) -> Experiment:
        """Check the request, and that it matches what ``NAME`` was run with before."""
        if not seeds:
            raise ExperimentError("an experiment needs at least one seed")
        if tensorboard:
            from cartpole.training.callbacks import require_tensorboard

            require_tensorboard()  # in one line, before any worker starts
        if budget is not None:
            try:
                parsed = parse_budget(budget)
                for entry in entries:  # a budget in generations means nothing to a gradient agent
                    check_budget_unit(parsed, entry.agent, get_agent(entry.agent).iteration)
            except ValueError as err:
                raise ExperimentError(str(err)) from None
        from cartpole.envs import env_info

        env_info(env_id, env_kwargs)  # an unsupported env is bad input before anything is written
        folder = runs_dir / "experiments" / check_name(name, "experiment")
        experiment = cls(
            folder,
            entries,
            list(seeds),
            env_id,
            budget,
            env_kwargs=dict(env_kwargs or {}),
            tensorboard=tensorboard,
        )
        experiment.command = command or []
        experiment.check_same_setup()
        return experiment

    @classmethod
    def from_folder(cls, runs_dir: Path, name: str) -> Experiment:
        """The experiment ``name`` as its folder holds it (for ``--report``): its setup from
        experiment.json, its entries and seeds from its records; ExperimentError if there is none."""
        folder = runs_dir / "experiments" / check_name(name, "experiment")
        try:
            setup = read_json(folder / "experiment.json")
        except FileNotFoundError:
            raise ExperimentError(f"no experiment named {name!r} in {runs_dir / 'experiments'}") from None
        except (OSError, ValueError) as err:
            raise ExperimentError(f"{folder / 'experiment.json'} is unreadable ({err})") from None
        entries: list[Entry] = []
        seeds: set[int] = set()
        for path in sorted((folder / "records").glob("*.json")):
            record = read_record(path)
            if not record or "agent" not in record or "seed" not in record:
                continue
            entry = Entry(str(record["agent"]), str(record.get("preset", "default")))
            if entry not in entries:
                entries.append(entry)
            seeds.add(int(record["seed"]))
        experiment = cls(folder, entries, sorted(seeds), str(setup.get("env_id")), setup.get("budget"))
        experiment.command = list(setup.get("command") or [])
        experiment.env_kwargs = dict(setup.get("env_kwargs") or {})
        return experiment

    @property
    def setup(self) -> dict[str, Any]:
        """What every run of the experiment shares; a re-run with other values would mix results.
        (``env_kwargs`` only when given, so experiments from before them are joined as before.)"""
        kwargs = {"env_kwargs": self.env_kwargs} if self.env_kwargs else {}
        return {"env_id": self.env_id, "budget": self.budget} | kwargs

    def check_same_setup(self) -> None:
        path = self.folder / "experiment.json"
        if not path.is_file():
            return
        try:
            before = read_json(path)
        except (OSError, ValueError) as err:
            raise ExperimentError(f"{path} is unreadable ({err}); use another --name") from None
        for key, value in (self.setup | {"env_kwargs": self.env_kwargs}).items():
            if (before.get(key) or ({} if key == "env_kwargs" else None)) != value:
                flag = SETUP_FLAGS[key]
                raise ExperimentError(
                    f"experiment {self.folder.name} was run with {flag} {before.get(key)}, not {value}; "
                    "use the same value or another --name"
                )

    def record_path(self, entry: Entry, seed: int) -> Path:
        return self.folder / "records" / f"{entry.slug}__s{seed}.json"

    def records(self) -> dict[Entry, list[dict[str, Any]]]:
        """The finished records of this request's runs, per entry."""
        found: dict[Entry, list[dict[str, Any]]] = {}
        for entry in self.entries:
            records = [read_record(self.record_path(entry, seed)) for seed in self.seeds]
            found[entry] = [r for r in records if r and r.get("state") == FINISHED]
        return found

    def pending(self) -> list[tuple[Entry, int]]:
        """Runs not finished yet, seed-major so every entry advances together."""
        todo = []
        for seed in self.seeds:
            for entry in self.entries:
                record = read_record(self.record_path(entry, seed))
                if not record or record.get("state") != FINISHED:
                    todo.append((entry, seed))
        return todo

    def jobs(self) -> list[Job]:
        """A job per pending run; the pending seeds of an entry whose agent trains populations make one
        job (one process for all of them)."""
        jobs: list[Job] = []
        grouped: dict[Entry, list[int]] = {}
        together = {entry: self.trains_populations(entry) for entry in self.entries}
        for entry, seed in self.pending():
            if together[entry]:
                grouped.setdefault(entry, []).append(seed)
            else:
                jobs.append(self.job(entry, [seed], population=False))
        return [self.job(entry, seeds, population=True) for entry, seeds in grouped.items()] + jobs

    def trains_populations(self, entry: Entry) -> bool:
        """Whether ``entry``'s seeds train as one population: where its agent batches them (CartPole
        on the fast simulator); elsewhere a seed per process, so that they run in parallel."""
        from cartpole.envs import env_info
        from cartpole.training.config import resolve_config

        spec = get_agent(entry.agent)
        config, settings = resolve_config(entry.agent, spec.config_cls, entry.preset, self.overrides)
        return spec.batches(config, env_info(self.env_id, settings.env_kwargs, settings.wrappers))

    @property
    def overrides(self) -> dict[str, Any]:
        """The settings every entry's runs take over their presets': ``--env-kwargs``'."""
        return {"env_kwargs": self.env_kwargs} if self.env_kwargs else {}

    def job(self, entry: Entry, seeds: list[int], population: bool) -> Job:
        """Train ``seeds`` of ``entry``: one seed, or (``population``) all of them as one population."""
        seed = seeds[0]
        records = {s: str(self.record_path(entry, s)) for s in seeds} if population else None
        task = Task(
            agent=entry.agent,
            preset=str(Path(entry.preset).resolve()) if entry.preset.endswith(".toml") else entry.preset,
            seed=seed,
            env_id=self.env_id,
            budget=self.budget,
            overrides=self.overrides,
            runs_dir=str(self.folder / "runs"),
            record=str(self.record_path(entry, seed)),
            command=self.command,
            population=records,
            tensorboard=self.tensorboard,
        )
        name = f"{entry.slug}__s{seed}" if len(seeds) == 1 else f"{entry.slug}__s{seed}-{seeds[-1]}"
        path = self.folder / "tasks" / f"{name}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, task.__dict__)
        return Job(python_module(WORKER, str(path)), self.folder / "logs" / f"{name}.log", (entry, seeds))

    def run(
        self, jobs: int | Sequence[Slot], progress: Callable[[str, int, int, int], None] | None = None
    ) -> list[str]:
        """Run every pending seed, ``jobs`` at a time (a count of CPU slots, or the slots,
        :mod:`~cartpole.experiments.slots`); return problems (failed workers) as lines.

        ``progress(kind, done, solved, total)`` hears of every run that ends.
        """
        check_jobs(jobs)
        self.folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.folder / "experiment.json", {**self.setup, "command": self.command})
        total = len(self.entries) * len(self.seeds)
        records = self.records()
        done = sum(len(r) for r in records.values())
        solved = sum(bool(r.get("solved_in_training")) for rs in records.values() for r in rs)
        problems: list[str] = []
        if progress:
            progress("start", done, solved, total)

        def on_done(job: Job, code: int) -> None:
            nonlocal done, solved
            entry, seeds = job.key
            for seed in seeds:
                record = read_record(self.record_path(entry, seed))
                if record and record.get("state") == FINISHED:
                    done += 1
                    solved += bool(record.get("solved_in_training"))
                elif code not in (0, 130, -2):
                    problems.append(f"{entry.label} seed {seed} failed (exit {code}); see {job.log}")
            if progress:
                progress("run", done, solved, total)

        run_jobs(self.jobs(), jobs, on_done)
        return problems

    def run_shared(
        self,
        shared: SharedComparison,
        jobs: int | Sequence[Slot],
        chunk: int,
        progress: Callable[[str, int, int, int], None] | None = None,
    ) -> list[str]:
        """Run this machine's share of a comparison shared through a database: claim pending runs of
        this request (a chunk of one entry's seeds at a time, trained as one population where the
        entry batches its seeds), ``jobs`` claims at a time (one per slot), and store each run's record
        and curve in the database as it ends. Waits while other workers hold claims, taking over those whose
        heartbeat stops. Returns problems (failed runs) as lines."""
        check_jobs(jobs)
        if chunk < 1:
            raise ExperimentError(f"--chunk must be >= 1, got {chunk}")
        self.folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(
            self.folder / "experiment.json", {**self.setup, "command": self.command, "storage": shared.url}
        )
        runner = SharedRunner(self, shared, chunk, progress)
        runner.report("start")
        run_job_source(
            runner.next_job, jobs, runner.on_done, runner.tick, runner.more, on_stop=runner.hand_back
        )
        return runner.problems


class SharedRunner:
    """One machine's claims on a shared comparison: jobs from claims, heartbeats, results stored."""

    def __init__(
        self,
        experiment: Experiment,
        shared: SharedComparison,
        chunk: int,
        progress: Callable[[str, int, int, int], None] | None,
    ):
        self.experiment, self.shared, self.chunk, self.progress = experiment, shared, chunk, progress
        self.owner = new_owner()
        self.labels = [e.label for e in experiment.entries]
        self.batches = {e.label: experiment.trains_populations(e) for e in experiment.entries}
        shared.claim_statement(chunk, self.batches, set(), self.labels, experiment.seeds)  # built ahead
        self.failed: set[tuple[str, int]] = set()
        self.problems: list[str] = []
        self.period = min(30.0, shared.claim_timeout / 4)
        """Seconds between heartbeats."""
        self.look_period = min(2.0, self.period)
        """Seconds between looks for work when there was none."""
        self.last_beat = time.monotonic()
        self.next_look = 0.0
        self.unstored: list[tuple[Entry, int, dict[str, Any], dict[str, Any]]] = []
        """Finished runs whose results the database did not take yet (it failed): retried each beat."""
        self.warned: set[str] = set()
        self.kills: dict[tuple[str, int], int] = {}
        """Times the worker of each (entry, seed) was killed by a signal."""
        self.running: list[Job] = []
        """The jobs this machine's workers train: their rows are never claimed again by it, even once its
        heartbeat is stale (the database out of reach for longer than the claim timeout)."""
        self.lost: list[Job] = []
        """Running jobs with a claim another worker took over: killed, their results not stored."""
        self.stopping = False
        """Set on Ctrl-C or SIGTERM (:meth:`hand_back`): every claim was given back at once."""

    def database(self, what: str, action: Callable[[], Any], default: Any) -> Any:
        """``action()``, tried again while the database connection is lost (a line each time, for a
        few minutes: :func:`~cartpole.experiments.storage.retry_lost_connection`), then StorageLost.
        Another failure gives ``default`` (it is retried later): a line is printed once per kind of
        failure, and training goes on. Once stopping (:meth:`hand_back`), one try, and ``default``
        where the connection is lost: a stop does not wait for the database (a finished run's record
        stays on disk, and the machine that claims it again stores it)."""
        import sys

        from sqlalchemy.exc import SQLAlchemyError

        try:
            return retry_lost_connection(what, action, () if self.stopping else None)
        except SQLAlchemyError as err:
            if lost_connection(err) and self.stopping:
                print(f"warning: could not {what} while stopping ({reason_of(err)})", file=sys.stderr)
                return default
            if lost_connection(err):
                raise StorageLost.of(err, what) from None
            reason = str(getattr(err, "orig", None) or err).strip().splitlines()
            if what not in self.warned:
                self.warned.add(what)
                print(f"warning: the shared storage failed to {what} ({reason[0] if reason else err}); "
                      "retrying", file=sys.stderr)  # fmt: skip
            return default

    def next_job(self) -> Job | None:
        if time.monotonic() < self.next_look:
            return None
        tries = 0

        def claim() -> Claim | None:
            """A claim, or on a new try after a lost connection first the claim that try may have
            made (the database committed it, and the reply was lost): rows this worker holds but runs
            no job for."""
            nonlocal tries
            tries += 1
            skip = self.failed | self.running_rows()
            if tries > 1:
                found = self.claim_cut_off(skip)
                if found is not None:
                    return found
            return self.shared.claim(
                self.owner, self.chunk, self.batches, skip, self.labels, self.experiment.seeds
            )

        found = self.database("give work", claim, None)
        if found is None:
            self.next_look = time.monotonic() + self.look_period
            return None
        job = self.experiment.job(found.entry, found.seeds, population=self.batches[found.entry.label])
        self.running.append(job)
        return job

    def claim_cut_off(self, skip: set[tuple[str, int]]) -> Claim | None:
        """The claim whose reply a lost connection cut off, where the database had stored it: rows
        held by this worker that none of its jobs runs (one entry's, up to a chunk), or None."""
        import sys

        rows = [row for row in self.shared.held(self.owner) if (row.entry, row.seed) not in skip]
        if not rows:
            return None
        first = rows[0]
        size = self.chunk if self.batches.get(first.entry, False) else 1
        seeds = [row.seed for row in rows if row.entry == first.entry][:size]
        print(f"the claim of {first.entry} {seeds_text(seeds)} was stored before the connection was lost: "
              "training it", file=sys.stderr, flush=True)  # fmt: skip
        return Claim(Entry(first.agent, first.preset), seeds)

    def running_rows(self) -> set[tuple[str, int]]:
        """The (entry, seed) rows of :attr:`running`."""
        return {(job.key[0].label, seed) for job in self.running for seed in job.key[1]}

    def more(self) -> bool:
        """Whether to wait: runs of this request are not finished, and some are claimed by other
        workers (who may finish them, or die and leave them to this one) or are claimable again."""
        time.sleep(max(0.0, self.next_look - time.monotonic()))
        progress = self.database(
            "count runs", lambda: self.shared.progress(self.labels, self.experiment.seeds), None
        )
        if progress is None or self.unstored:
            return True
        return bool(progress.finished + len(self.failed) < progress.total)

    def tick(self) -> list[Job]:
        """Every heartbeat period: renew this worker's claims, give back those it holds without a job
        (a claim whose reply was lost, a release that failed), and return the running jobs to kill:
        those with a claim the database says is no longer this worker's (another worker took it over
        while the heartbeats were late, a long pause or a network cut, or finished the run first)."""
        if time.monotonic() - self.last_beat < self.period:
            return []
        self.last_beat = time.monotonic()
        held = self.database("renew claims", lambda: self.shared.heartbeat(self.owner), None)
        self.store(self.unstored)
        if held is None:
            return []
        self.give_back_unrun(held - self.running_rows())
        lost = [job for job in self.running if job not in self.lost and not self.holds(job, held)]
        if lost:
            rows = {(job.key[0].label, seed) for job in lost for seed in job.key[1]} - held
            now = self.database("look up runs", lambda: self.shared.where_now(rows), {})
            for job in lost:
                self.say_lost(job, held, now)
        self.lost += lost
        return lost

    def give_back_unrun(self, rows: set[tuple[str, int]]) -> None:
        """Give back claims this worker holds but runs no job for, with a line: pending again."""
        import sys

        if not rows:
            return
        given = self.database(
            "give back claims no job runs", lambda: self.shared.release_rows(self.owner, rows), set()
        )
        by_entry: dict[str, list[int]] = {}
        for label, seed in sorted(given):
            by_entry.setdefault(label, []).append(seed)
        for label, seeds in by_entry.items():
            line = f"warning: {label} {seeds_text(seeds)}: this worker held the claim but ran nothing for it "
            print(line + "(its reply lost with the connection); gave it back, pending again", file=sys.stderr)
        self.next_look = 0.0

    def hand_back(self) -> None:
        """On a stop (Ctrl-C, SIGTERM): every claim this worker holds back to pending at once, in one
        statement, while its workers save their runs, so that other machines take them without waiting
        out the claim timeout (one try: a stop does not wait for a database out of reach). A run that
        ends meanwhile is still stored (only the first finish of a run is kept)."""
        import sys

        from sqlalchemy.exc import SQLAlchemyError

        self.stopping = True
        try:
            given = retry_lost_connection(
                "give its claims back", lambda: self.shared.release_rows(self.owner), waits=()
            )
        except SQLAlchemyError as err:
            line = (
                f"warning: could not give the claims back ({reason_of(err)}): other workers take them over "
            )
            print(line + f"after the claim timeout ({self.shared.claim_timeout:g} s)", file=sys.stderr)
            return
        if given:
            print(f"stopping: gave back the claims of {len(given)} run(s) for other workers to take now; "
                  "each run in training saves its latest.pt", file=sys.stderr, flush=True)  # fmt: skip

    @staticmethod
    def holds(job: Job, held: set[tuple[str, int]]) -> bool:
        entry, seeds = job.key
        return all((entry.label, seed) in held for seed in seeds)

    def say_lost(
        self, job: Job, held: set[tuple[str, int]], now: dict[tuple[str, int], tuple[str, str | None]]
    ) -> None:
        """One line per way the job's claims were lost: finished by another worker, taken over by
        another worker, or pending again."""
        import sys

        entry, seeds = job.key
        reasons: dict[str, list[int]] = {}
        for seed in seeds:
            if (entry.label, seed) in held:
                continue
            state, owner = now.get((entry.label, seed), (None, None))
            if state == RowState.FINISHED and owner != self.owner:
                reason = "another worker finished this run first (its result is the one kept)"
            elif state == RowState.CLAIMED and owner != self.owner:
                reason = "another worker took this claim over (this worker's heartbeats were late)"
            else:
                reason = (
                    "this worker no longer holds this claim (it is pending again: its heartbeats were late)"
                )
            reasons.setdefault(reason, []).append(seed)
        for reason, lost in reasons.items():
            line = f"warning: {entry.label} {seeds_text(lost)}: {reason}"
            print(line + "; stopped its run here, saving nothing", file=sys.stderr)

    def store(self, finished: list[tuple[Entry, int, dict[str, Any], dict[str, Any]]]) -> None:
        """Put finished runs' results in the database; those it does not take wait in ``unstored``."""

        def stored(run: tuple[Entry, int, dict[str, Any], dict[str, Any]]) -> bool:
            finish = partial(self.shared.finish, self.owner, *run)
            return self.database("store results", lambda: finish() or True, False) is True

        self.unstored = [run for run in finished if not stored(run)]

    def on_done(self, job: Job, code: int) -> None:
        from cartpole.experiments.figures import EvalCurve
        from cartpole.runs import RunError

        self.running.remove(job)
        if job in self.lost:
            self.lost.remove(job)
            self.give_back(job)
            return
        entry, seeds = job.key
        finished, again = [], self.killed_again(job, code)
        for seed in seeds:
            record = read_record(self.experiment.record_path(entry, seed))
            if record and record.get("state") == FINISHED:
                try:
                    curve = EvalCurve.of_run(record["run"]).to_json()
                except (RunError, OSError, KeyError):
                    curve = {}
                finished.append((entry, seed, record, curve))
                continue
            if not self.stopping:  # when stopping, every claim was given back at once
                self.database(
                    "give a claim back", partial(self.shared.release, self.owner, entry, seed), None
                )
            if code not in (0, 130, -2) and not again:
                self.failed.add((entry.label, seed))
                self.problems.append(f"{entry.label} seed {seed} failed (exit {code}); see {job.log}")
        if finished:
            pause_at("finish")  # a test hook: nothing unless CARTPOLE_PAUSE_AT says so
        self.store(self.unstored + finished)
        self.next_look = 0.0  # a slot is free: look for work at once
        self.report("run")

    def killed_again(self, job: Job, code: int) -> bool:
        """Whether a worker killed by a signal (SIGKILL: the kernel out of memory, a person) has its
        unfinished runs claimed again, here or by another machine, up to :data:`KILLED_RETRIES` times
        per job (a line each time); its runs start again where it left their records."""
        import sys

        if code >= 0 or code == -signal.SIGINT:
            return False
        entry, seeds = job.key
        for seed in seeds:
            self.kills[(entry.label, seed)] = self.kills.get((entry.label, seed), 0) + 1
        kills = max(self.kills[(entry.label, seed)] for seed in seeds)
        if kills > KILLED_RETRIES:
            return False
        line = f"the worker of {entry.label} seeds {seeds} was killed (signal {-code}): claiming its "
        print(line + f"unfinished runs again ({kills}/{KILLED_RETRIES}); see {job.log}", file=sys.stderr)
        return True

    def give_back(self, job: Job) -> None:
        """A killed job's seeds that this worker still holds are pending again (release touches only its
        own claims); its record files and run folders, perhaps the new owner's too, are not read."""
        entry, seeds = job.key
        for seed in seeds:
            self.database("give a claim back", partial(self.shared.release, self.owner, entry, seed), None)
        self.next_look = 0.0

    def report(self, kind: str) -> None:
        if self.progress:
            progress = self.database(
                "count runs", lambda: self.shared.progress(self.labels, self.experiment.seeds), None
            )
            if progress is not None:
                self.progress(kind, progress.finished, progress.solved, progress.total)


def seeds_text(seeds: list[int]) -> str:
    """``seed 3`` or ``seeds 3, 4, 5``, as the messages name them."""
    return f"seed {seeds[0]}" if len(seeds) == 1 else "seeds " + ", ".join(map(str, seeds))
