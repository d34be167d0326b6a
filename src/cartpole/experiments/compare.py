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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cartpole.agents.registry import get_agent
from cartpole.experiments.entries import Entry, ExperimentError
from cartpole.experiments.processes import Job, python_module, run_jobs
from cartpole.experiments.worker import FINISHED, Task, read_record
from cartpole.runs.atomic import write_json_atomic
from cartpole.runs.run_dir import read_json
from cartpole.training.budget import parse_budget

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
WORKER = "cartpole.experiments.worker"


def check_name(name: str, what: str) -> str:
    if not NAME.match(name):
        raise ExperimentError(f"{what} name {name!r}: use letters, digits, '.', '_' and '-'")
    return name


@dataclass
class Experiment:
    """An experiment folder and what it runs."""

    folder: Path
    entries: list[Entry]
    seeds: list[int]
    env_id: str
    budget: str | None
    command: list[str] = field(default_factory=list)

    @classmethod
    def open(
        cls,
        runs_dir: Path,
        name: str,
        entries: list[Entry],
        seeds: int,
        first_seed: int = 0,
        env_id: str = "CartPole-v1",
        budget: str | None = None,
        command: list[str] | None = None,
    ) -> Experiment:
        """Check the request, and that it matches what ``NAME`` was run with before."""
        if seeds < 1:
            raise ExperimentError(f"--seeds must be >= 1, got {seeds}")
        if first_seed < 0:
            raise ExperimentError(f"--first-seed must be >= 0, got {first_seed}")
        if budget is not None:
            try:
                parse_budget(budget)
            except ValueError as err:
                raise ExperimentError(str(err)) from None
        from cartpole.envs import env_info

        env_info(env_id)  # an unsupported env is bad input before anything is written
        folder = runs_dir / "experiments" / check_name(name, "experiment")
        experiment = cls(folder, entries, list(range(first_seed, first_seed + seeds)), env_id, budget)
        experiment.command = command or []
        experiment.check_same_setup()
        return experiment

    @property
    def setup(self) -> dict[str, Any]:
        """What every run of the experiment shares; a re-run with other values would mix results."""
        return {"env_id": self.env_id, "budget": self.budget}

    def check_same_setup(self) -> None:
        path = self.folder / "experiment.json"
        if not path.is_file():
            return
        try:
            before = read_json(path)
        except (OSError, ValueError) as err:
            raise ExperimentError(f"{path} is unreadable ({err}); use another --name") from None
        for key, value in self.setup.items():
            if before.get(key) != value:
                flag = {"env_id": "--env", "budget": "--budget"}[key]
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
        config, _ = resolve_config(entry.agent, spec.config_cls, entry.preset)
        return spec.batches(config, env_info(self.env_id))

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
            runs_dir=str(self.folder / "runs"),
            record=str(self.record_path(entry, seed)),
            command=self.command,
            population=records,
        )
        name = f"{entry.slug}__s{seed}" if len(seeds) == 1 else f"{entry.slug}__s{seed}-{seeds[-1]}"
        path = self.folder / "tasks" / f"{name}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, task.__dict__)
        return Job(python_module(WORKER, str(path)), self.folder / "logs" / f"{name}.log", (entry, seeds))

    def run(self, jobs: int, progress: Callable[[str, int, int, int], None] | None = None) -> list[str]:
        """Run every pending seed, ``jobs`` at a time; return problems (failed workers) as lines.

        ``progress(kind, done, solved, total)`` hears of every run that ends.
        """
        if jobs < 1:
            raise ExperimentError(f"--jobs must be >= 1, got {jobs}")
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
