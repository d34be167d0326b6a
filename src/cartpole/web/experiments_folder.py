"""Experiments and sweeps as the web app sees them: read-only, inside the runs folder, by validated names.

``cartpole compare`` writes ``RUNS_DIR/experiments/NAME/`` (report.json, report.md, curves.png,
solve_steps.png) and ``cartpole sweep`` writes ``RUNS_DIR/sweeps/NAME/`` (sweep.json, the Optuna
journal ``journal.log``, best.toml). A name from a URL must name a folder directly inside one of these
(no separators, no ``..``, no hidden names, no link out of the runs folder), and only the files named
here are ever opened, each a regular file (a symlink is not followed). Answers name no path of this
machine: run folders by their name, preset files outside the runs folder by their file name
(:func:`~cartpole.web.answers.shown_paths`).

A file that cannot be read or does not have the expected form is a listed problem, never an error
answer: the page shows what it could read and says what it could not.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, ValidationError

from cartpole.runs.run_dir import read_json
from cartpole.web.answers import shown_paths, shown_root
from cartpole.web.runs_folder import SAFE_NAME, NotFound, inside
from cartpole.web.shared_reports import SharedReport, SharedReports, SharedStatus

EXPERIMENTS = "experiments"
SWEEPS = "sweeps"
FIGURES = ("curves", "solve_steps", "performance_profile", "improvement")
"""The figures ``cartpole compare`` draws, as ``NAME.png``."""


# ---------------------------------------------------------------------------------------------------
# The report of `cartpole compare`, as the API gives it
# ---------------------------------------------------------------------------------------------------


class TimeToSolve(BaseModel):
    """Median, IQR and 95% bootstrap CI of a time to the first verified solve (unsolved runs censored)."""

    median: float | None
    iqr: list[float] | None
    ci95: list[float] | None
    censored: int = Field(ge=0, description="runs that never solved, counted at what they used")
    median_is_lower_bound: bool = Field(description="at least half the runs are censored")


class FinalReturn(BaseModel):
    """The final verdicts' mean returns over runs: interquartile mean with a 95% bootstrap CI."""

    iqm: float | None
    ci95: list[float] | None
    mean: float | None
    min: float | None
    max: float | None


class ReportEntry(BaseModel):
    """One entry (an agent with a preset) over its seeds."""

    entry: str
    agent: str
    preset: str
    runs: int = Field(ge=0)
    solved: int = Field(ge=0, description="runs with a verified solve during training")
    final_solved: int = Field(ge=0, description="runs whose final verdict is solved")
    env_steps_to_solve: TimeToSolve
    cpu_seconds_to_solve: TimeToSolve
    wall_seconds_to_solve: TimeToSolve
    final_mean_return: FinalReturn
    seeds: list[int]
    run_folders: list[str] = Field(description="run folder names, in the experiment's runs/ folder")


class ScoreMatrix(BaseModel):
    """Every run's score as rliable reads it: runs (a row per seed) by entries (a column each)."""

    score: str = Field(description="what a run's score is")
    entries: list[str] = Field(description="the columns' entries")
    seeds: list[int] = Field(description="the rows' seeds")
    matrix: list[list[float | None]] = Field(
        description="None where that seed of that entry has not finished"
    )


class Improvement(BaseModel):
    """rliable's probability of improvement: the chance that a run of ``x`` scores above a run of ``y``."""

    x: str
    y: str
    probability: float | None
    ci95: list[float] | None


class Report(BaseModel):
    env_id: str
    budget: str
    seeds: list[int]
    confidence: float
    method: str
    entries: list[ReportEntry]
    scores: ScoreMatrix | None = Field(None, description="absent from reports made before it")
    probability_of_improvement: list[Improvement] = Field(
        default_factory=list, description="for each entry over each later one"
    )


class ExperimentRow(BaseModel):
    """One experiment folder in the list."""

    name: str
    env_id: str | None
    entries: list[str]
    seeds: int | None = Field(description="seeds per entry")
    runs: int = Field(description="finished runs in the report")
    updated: str | None = Field(description="when report.json was written (UTC)")
    problem: str | None = Field(description="why the report cannot be shown, if it cannot")


class ExperimentOut(BaseModel):
    """One experiment: its report (None with a problem when there is none to show) and its figures."""

    name: str
    report: Report | None
    problem: str | None
    shared: SharedStatus | None = Field(
        description="a comparison shared through a database (`cartpole compare --storage`): its report is "
        "built live from every machine's finished runs, and this says where it stands"
    )
    figures: list[str] = Field(description="figure names; each is served at .../figures/{figure}.png")
    command: list[str] | None = Field(description="the `cartpole compare` command that made it")
    runs_folder: str = Field(description="its run folders, relative to the runs folder")
    updated: str | None


class Trial(BaseModel):
    """One trial of a sweep."""

    number: int
    state: str = Field(description="Optuna's state: COMPLETE, PRUNED, FAIL, RUNNING or WAITING")
    value: float | None = Field(description="median env steps to a verified solve over the trial's seeds")
    params: dict[str, Any]
    seed_costs: list[float | None] = Field(description="each seed's cost, where it finished")
    runs: list[str] = Field(description="its run folders' names, in the sweep's runs/ folder")
    started: str | None
    completed: str | None
    seconds: float | None


class SweepRow(BaseModel):
    """One sweep folder in the list."""

    name: str
    agent: str | None
    env_id: str | None
    trials_asked: int | None = Field(description="finished trials the sweep was asked for")
    storage: str = Field(description='"journal" (journal.log in its folder) or "database"')
    has_best: bool
    updated: str | None
    problem: str | None


class SweepOut(BaseModel):
    """One sweep: what it tunes, its trials (from the journal file) and its best preset."""

    name: str
    agent: str | None
    preset: str | None
    env_id: str | None
    budget: str | None
    seeds_per_trial: int | None
    trials_asked: int | None
    space: dict[str, Any] | None
    storage: str = Field(description='"journal" or "database"')
    dashboard: str = Field(description="the command that opens the study in optuna-dashboard")
    trials: list[Trial]
    counts: dict[str, int] = Field(description="trials per state")
    best: int | None = Field(description="the best complete trial's number")
    best_toml: str | None = Field(description="best.toml, the best trial as a preset file")
    problem: str | None


# ---------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------


def _modified(path: Path) -> str | None:
    try:
        stamp = path.stat().st_mtime
    except OSError:
        return None
    return datetime.fromtimestamp(stamp, UTC).isoformat(timespec="seconds")


def _regular_file(path: Path, folder: Path) -> bool:
    """A regular file (not a link) directly inside ``folder``."""
    return not path.is_symlink() and path.is_file() and inside(path, folder)


def _problem(what: str, err: Exception) -> str:
    reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    return f"{what} is unreadable ({reason[:200]})"


def _read_json_file(path: Path, folder: Path) -> Any:
    """The JSON in ``path``; OSError or ValueError if it is not a regular file that parses."""
    if not _regular_file(path, folder):
        raise FileNotFoundError(f"no {path.name}")
    return read_json(path)


class ExperimentsFolder:
    """Read access to ``root/experiments`` and ``root/sweeps``."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._studies = StudyCache()
        self._shared = SharedReports()

    # -- folders -------------------------------------------------------------------------------------

    def _folder(self, kind: str, name: str) -> Path:
        what = "experiment" if kind == EXPERIMENTS else "sweep"
        if not SAFE_NAME.match(name) or ".." in name:
            raise NotFound(f"no {what} named {name!r}")
        path = self.root / kind / name
        if path.is_symlink() or not path.is_dir() or not inside(path, self.root):
            raise NotFound(f"no {what} named {name!r} in {kind}/ of the runs folder")
        return path

    def _names(self, kind: str) -> Iterator[str]:
        base = self.root / kind
        if base.is_symlink() or not base.is_dir():
            return
        try:
            children = sorted(base.iterdir(), key=lambda p: p.name)
        except OSError:
            return
        for child in children:
            if SAFE_NAME.match(child.name) and not child.is_symlink() and child.is_dir():
                yield child.name

    # -- experiments ---------------------------------------------------------------------------------

    def experiments(self) -> list[dict[str, Any]]:
        """Every experiment folder, most recently reported first."""
        rows = [self._experiment_row(name) for name in self._names(EXPERIMENTS)]
        return sorted(rows, key=lambda r: r["updated"] or "", reverse=True)

    def _experiment_row(self, name: str) -> dict[str, Any]:
        folder = self.root / EXPERIMENTS / name
        shared, _ = self._shared_report(folder)
        report, problem = self._report(folder, shared)
        return {
            "name": name,
            "env_id": report.env_id if report else None,
            "entries": [e.entry for e in report.entries] if report else [],
            "seeds": len(report.seeds) if report else None,
            "runs": sum(e.runs for e in report.entries) if report else 0,
            "updated": _modified(folder / "report.json"),
            "problem": problem,
        }

    def experiment(self, name: str) -> dict[str, Any]:
        """One experiment's report and figures; NotFound for an unknown name."""
        folder = self._folder(EXPERIMENTS, name)
        shared, shared_problem = self._shared_report(folder)
        report, problem = self._report(folder, shared)
        command = self._setup(folder).get("command")
        if not (isinstance(command, list) and all(isinstance(c, str) for c in command)):
            command = None
        figures_folder = shared.figures if shared else folder
        return {
            "name": name,
            "report": report,
            "problem": shared_problem or problem,
            "shared": shared.status if shared else None,
            "figures": [f for f in FIGURES if _regular_file(figures_folder / f"{f}.png", figures_folder)],
            "command": [shown_paths(c, self.root) for c in command] if command else None,
            "runs_folder": f"{EXPERIMENTS}/{name}/runs",
            "updated": _modified(folder / "report.json"),
        }

    def _setup(self, folder: Path) -> dict[str, Any]:
        """experiment.json (what was asked, the command, a shared comparison's storage), or {}."""
        try:
            setup = _read_json_file(folder / "experiment.json", folder)
        except (OSError, ValueError):
            return {}
        return setup if isinstance(setup, dict) else {}

    def _shared_report(self, folder: Path) -> tuple[SharedReport | None, str | None]:
        """The live report of a comparison shared through a database, or None (and why, if it failed)."""
        url = self._setup(folder).get("storage")
        if not isinstance(url, str) or not url:
            return None, None
        try:
            return self._shared.report(url, folder.name), None
        except Exception as err:  # any failure of a database we do not control is a problem to show
            reason = str(getattr(err, "orig", None) or err).strip().splitlines()
            return (
                None,
                f"cannot read the shared comparison from its database: {reason[0] if reason else err}",
            )

    def _report(self, folder: Path, shared: SharedReport | None = None) -> tuple[Report | None, str | None]:
        """The report (of a shared comparison, live; else the folder's report.json), checked, with paths
        shown; or None and why."""
        if shared is not None:
            data: Any = shared.report
        else:
            path = folder / "report.json"
            if not path.exists() and not path.is_symlink():
                started = (folder / "experiment.json").exists()
                why = "still running or interrupted: " if started else ""
                return None, f"no report.json yet ({why}`cartpole compare` writes it when its runs end)"
            try:
                data = _read_json_file(path, folder)
            except (OSError, ValueError) as err:
                return None, _problem("report.json", err)
        try:
            report = Report.model_validate(data)
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "the top level"
            why = f"{where}: {first['msg']}"
            return None, f"report.json does not have the form `cartpole compare` writes ({why})"
        for entry in report.entries:
            entry.entry = shown_paths(entry.entry, self.root)
            entry.preset = shown_paths(entry.preset, self.root)
            entry.run_folders = [Path(p).name for p in entry.run_folders]
        return report, None

    def figure(self, name: str, figure: str) -> Path:
        """The PNG file of one figure; NotFound if it is not one, or not there."""
        folder = self._folder(EXPERIMENTS, name)
        shared, _ = self._shared_report(folder)
        if shared is not None:
            folder = shared.figures
        path = folder / f"{figure}.png"
        if figure not in FIGURES or not _regular_file(path, folder):
            raise NotFound(f"experiment {name} has no figure {figure!r}")
        return path

    # -- sweeps --------------------------------------------------------------------------------------

    def sweeps(self) -> list[dict[str, Any]]:
        """Every sweep folder, most recently changed first."""
        rows = [self._sweep_row(name) for name in self._names(SWEEPS)]
        return sorted(rows, key=lambda r: r["updated"] or "", reverse=True)

    def _spec(self, folder: Path) -> tuple[dict[str, Any], str | None]:
        try:
            spec = _read_json_file(folder / "sweep.json", folder)
        except FileNotFoundError:
            return {}, "no sweep.json (not written by `cartpole sweep`, or it has not started)"
        except (OSError, ValueError) as err:
            return {}, _problem("sweep.json", err)
        if not isinstance(spec, dict):
            return {}, "sweep.json does not have the form `cartpole sweep` writes"
        return spec, None

    def _sweep_row(self, name: str) -> dict[str, Any]:
        folder = self.root / SWEEPS / name
        spec, problem = self._spec(folder)
        journal = folder / "journal.log"
        return {
            "name": name,
            "agent": _text(spec.get("agent")),
            "env_id": _text(spec.get("env_id")),
            "trials_asked": _int(spec.get("trials")),
            "storage": "database" if spec.get("storage") else "journal",
            "has_best": _regular_file(folder / "best.toml", folder),
            "updated": _modified(journal) or _modified(folder / "sweep.json"),
            "problem": problem,
        }

    def sweep(self, name: str) -> dict[str, Any]:
        """One sweep: its settings, its trials read from the journal file, best.toml; NotFound if unknown.

        Reads Optuna's journal: call it off the event loop."""
        folder = self._folder(SWEEPS, name)
        spec, problem = self._spec(folder)
        study_name = _text(spec.get("name")) or name
        journal = folder / "journal.log"
        database = bool(spec.get("storage"))
        trials: list[dict[str, Any]] = []
        if database:
            problem = problem or (
                "this study lives in a database, which this page does not read: open it with "
                "optuna-dashboard and the --storage URL the sweep was run with"
            )
            dashboard = "optuna-dashboard <the --storage URL of the sweep>"
        else:
            dashboard = f"optuna-dashboard {self._shown_root()}/{SWEEPS}/{name}/journal.log"
            if _regular_file(journal, folder):
                try:
                    trials = [self._trial(t) for t in self._studies.trials(journal, study_name)]
                except NoStudy as err:
                    problem = f"journal.log {err}"
                except Exception as err:  # anything Optuna raises on a damaged journal
                    problem = _problem("journal.log", err)
            else:
                problem = problem or "no journal.log yet: the sweep has not started a trial"
        best_path = folder / "best.toml"
        best_toml = None
        if _regular_file(best_path, folder):
            try:
                best_toml = shown_paths(best_path.read_text(encoding="utf-8"), self.root)
            except (OSError, UnicodeDecodeError) as err:
                problem = problem or _problem("best.toml", err)
        complete = [t for t in trials if t["state"] == "COMPLETE" and t["value"] is not None]
        counts: dict[str, int] = {}
        for trial in trials:
            counts[trial["state"]] = counts.get(trial["state"], 0) + 1
        space = spec.get("space")
        return {
            "name": name,
            "agent": _text(spec.get("agent")),
            "preset": shown_paths(p, self.root) if (p := _text(spec.get("preset"))) else None,
            "env_id": _text(spec.get("env_id")),
            "budget": _text(spec.get("budget")),
            "seeds_per_trial": _int(spec.get("seeds_per_trial")),
            "trials_asked": _int(spec.get("trials")),
            "space": space if isinstance(space, dict) else None,
            "storage": "database" if database else "journal",
            "dashboard": dashboard,
            "trials": trials,
            "counts": counts,
            "best": min(complete, key=lambda t: t["value"])["number"] if complete else None,
            "best_toml": best_toml,
            "problem": problem,
        }

    def best_toml(self, name: str) -> str:
        """The text of a sweep's best.toml; NotFound if there is none."""
        folder = self._folder(SWEEPS, name)
        path = folder / "best.toml"
        if not _regular_file(path, folder):
            raise NotFound(f"sweep {name} has no best.toml yet (written once a trial completes)")
        try:
            return shown_paths(path.read_text(encoding="utf-8"), self.root)
        except (OSError, UnicodeDecodeError) as err:
            raise NotFound(_problem(f"sweep {name}'s best.toml", err)) from err

    def _trial(self, trial: Any) -> dict[str, Any]:
        attrs = trial.user_attrs
        seeds = sorted(
            int(k.removeprefix("run_seed")) for k in attrs if re.fullmatch(r"run_seed\d+", k)
        ) or sorted(int(k.removeprefix("cost_seed")) for k in attrs if re.fullmatch(r"cost_seed\d+", k))
        start, end = trial.datetime_start, trial.datetime_complete
        return {
            "number": trial.number,
            "state": trial.state.name,
            "value": trial.value,
            "params": trial.params,
            "seed_costs": [_float(attrs.get(f"cost_seed{i}")) for i in seeds],
            "runs": [Path(str(attrs[f"run_seed{i}"])).name for i in seeds if f"run_seed{i}" in attrs],
            "started": start.isoformat(timespec="seconds") if start else None,
            "completed": end.isoformat(timespec="seconds") if end else None,
            "seconds": (end - start).total_seconds() if start and end else None,
        }

    def _shown_root(self) -> str:
        return shown_root(self.root)


class NoStudy(LookupError):
    """The journal file holds no study of the sweep's name."""


class StudyCache:
    """Trials of journal files. A file that did not change is not read again; one that grew is read
    from where the last read stopped (Optuna's JournalStorage reads only new lines when reused), so a
    page following a long sweep does not parse its whole journal every few seconds."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._storages: dict[Path, tuple[int, Any]] = {}
        self._trials: dict[tuple[Path, str], tuple[tuple[int, int], list[Any]]] = {}

    def trials(self, journal: Path, study_name: str) -> list[Any]:
        stat = journal.stat()
        stamp = (stat.st_size, stat.st_mtime_ns)
        with self._lock:
            cached = self._trials.get((journal, study_name))
            if cached and cached[0] == stamp:
                return cached[1]
            size, storage = self._storages.get(journal, (0, None))
            if storage is None or stat.st_size < size:  # new, or rewritten: read from the start
                storage = open_journal(journal)
            self._storages.pop(journal, None)  # kept again only if the read succeeds
            trials = read_trials(storage, study_name)
            self._storages[journal] = (stat.st_size, storage)
            self._trials[(journal, study_name)] = (stamp, trials)
            return trials


def open_journal(journal: Path) -> Any:
    """Optuna's storage over a journal file (it opens the file to append, and writes nothing)."""
    import optuna
    from optuna.storages.journal import JournalFileBackend

    return optuna.storages.JournalStorage(JournalFileBackend(str(journal)))


def read_trials(storage: Any, study_name: str) -> list[Any]:
    """Every trial of ``study_name`` in an Optuna storage (optuna's public API).

    NoStudy if the storage holds no such study (and not exactly one other)."""
    import optuna

    names = optuna.study.get_all_study_names(storage)
    if study_name not in names:
        if len(names) != 1:
            raise NoStudy(
                f"holds no study named {study_name} ({len(names)} others)" if names else "holds no study yet"
            )
        study_name = names[0]
    study = optuna.load_study(study_name=study_name, storage=storage)
    return list(study.get_trials(deepcopy=False))


def _text(value: Any) -> str | None:
    return value if isinstance(value, str) else None


def _int(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _float(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
