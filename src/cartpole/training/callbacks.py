"""Callbacks of the shared training loop: budget, evaluation, checkpoints, metrics, progress."""

from __future__ import annotations

import html
import json
import math
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

from cartpole.agents.learner import LearnResult
from cartpole.agents.registry import AgentSpec
from cartpole.core.names import CheckpointName, RunState, StopReason
from cartpole.core.seeding import eval_seed
from cartpole.envs import EnvInfo, Simulator, check_simulator
from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, Policy, evaluate
from cartpole.runs import Checkpoint, LiveStatus, RunDir, save_checkpoint
from cartpole.training.budget import Budget
from cartpole.training.config import TrainSettings
from cartpole.training.loop import Callback, LoopState, TrainingLoop


class BudgetCallback(Callback):
    """Stops training when any limit of the budget is reached. ``whole_generations`` names an agent
    that learns in whole generations: where one overshoots a limit, the stop says how far it went."""

    def __init__(self, budget: Budget, whole_generations: str | None = None):
        self.budget = budget
        self.whole_generations = whole_generations

    def on_start(self, loop: TrainingLoop) -> None:
        """A resumed run whose budget was already spent (killed before its verdict) trains no more."""
        self.check(loop)

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        return self.check(loop)

    def check(self, loop: TrainingLoop) -> bool:
        for limit, value, unit in budget_limits(self.budget, loop.state):
            if value >= limit:
                loop.state.stop(StopReason.BUDGET, self.reached(limit, value, unit))
                return False
        return True

    def reached(self, limit: float, value: float, unit: str) -> str:
        """The stop detail: the limit, and how far past it a whole generation went."""
        if self.whole_generations is None or value == limit or unit == "seconds":
            return f"budget reached ({limit:g} {unit})"
        return (
            f"budget reached ({limit:g} {unit}; {value:,} {unit} in all: {self.whole_generations} "
            "learns in whole generations)"
        )


def budget_limits(budget: Budget, state: LoopState) -> list[tuple[float, float, str]]:
    """(limit, value so far, unit) for each limit the budget sets."""
    limits = (
        (budget.env_steps, state.env_steps, "env steps"),
        (budget.episodes, state.episodes, "episodes"),
        (budget.iterations, state.iterations, "iterations"),
        (budget.seconds, state.elapsed, "seconds"),
    )
    return [(limit, value, unit) for limit, value, unit in limits if limit is not None]


def budget_progress(budget: Budget, state: LoopState) -> float:
    """The share of the budget spent: 1.0 when its first limit is reached (0.0 with no limit)."""
    return max((value / limit for limit, value, _ in budget_limits(budget, state)), default=0.0)


def report_rank(report: EvalReport) -> tuple[bool, bool, float]:
    """Order of merit: a verified solve, then a full-length evaluation, then the mean."""
    return (report.solved, report.episodes >= MIN_EPISODES_FOR_SOLVED, report.mean)


class EvalCallback(Callback):
    """Periodic greedy evaluation: a quick screen, then the full evaluation when the screen passes.

    The screen runs on the fast simulator (cheap); the full evaluation, whose verdict decides
    "solved", runs on ``settings.eval_simulator`` (Gymnasium's own env by default). Seeds come from
    :func:`eval_seed`, disjoint from training seeds and different at every evaluation.
    """

    def __init__(
        self,
        env: EnvInfo,
        seed: int,
        settings: TrainSettings,
        evaluator: Callable[[TrainingLoop], EvalReport | None] | None = None,
    ):
        self.env, self.seed, self.settings = env, seed, settings
        self.evaluator = evaluator
        """Where a report may already be waiting (a population evaluates its seeds together);
        None from it, or no evaluator, and this callback evaluates the policy itself."""

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        if loop.state.env_steps - loop.state.last_eval_step < self.settings.eval_every:
            return True
        loop.state.last_eval_step = loop.state.env_steps
        return loop.record_eval(self.evaluate(loop))

    def on_end(self, loop: TrainingLoop) -> None:
        """Judge the final policy too, so every finished run has a best checkpoint and a verdict."""
        if loop.state.stop_reason in (StopReason.FAILED, StopReason.INTERRUPTED):
            return
        if loop.state.evaluations == 0 or loop.state.last_eval_step < loop.state.env_steps:
            loop.state.last_eval_step = loop.state.env_steps
            loop.record_eval(self.evaluate(loop))

    def evaluate(self, loop: TrainingLoop) -> EvalReport:
        report = self.evaluator(loop) if self.evaluator is not None else None
        if report is not None:
            return report
        return screened_evaluation(
            loop.learner.policy(), self.env, self.seed, loop.state.evaluations, self.settings
        )


PlayEpisodes = Callable[[list[int], list[int], int, Simulator], list[EvalReport]]
"""Plays greedy episodes of several runs' policies: (run seeds, each run's first episode seed,
episodes, simulator) -> a report per run, each from episode seeds ``first, first + 1, ...``."""


def screened_reports(
    due: list[tuple[int, int]], play: PlayEpisodes, env: EnvInfo, settings: TrainSettings
) -> dict[int, EvalReport]:
    """Reports of the ``(run seed, evaluation index)`` pairs in ``due``: for evaluation ``index`` of
    run ``seed``, a screen of ``eval_screen_episodes`` on the fast simulator; when its mean reaches
    the threshold, the full ``eval_episodes`` on ``eval_simulator``; and when that passes too and
    ``confirm_solves`` is set, the next ``eval_episodes`` episode seeds of the same stream, the run's
    report being the lower of the two full ones (a solve counts when both pass)."""
    full_simulator = check_simulator(settings.eval_simulator)

    def played(
        pairs: list[tuple[int, int]], first: Callable[[int, int], int], episodes: int, simulator: Simulator
    ) -> dict[int, EvalReport]:
        reports = play([seed for seed, _ in pairs], [first(*pair) for pair in pairs], episodes, simulator)
        return dict(zip([seed for seed, _ in pairs], reports, strict=True))

    def passing() -> list[tuple[int, int]]:
        threshold = env.reward_threshold
        return [
            (seed, index) for seed, index in due if threshold is not None and reports[seed].mean >= threshold
        ]

    reports = played(due, screen_seed, settings.eval_screen_episodes, "fast")
    if passed := passing():
        reports.update(played(passed, full_seed, settings.eval_episodes, full_simulator))
    if settings.confirm_solves and (passed := passing()):
        confirmations = played(passed, confirmation_seed(settings), settings.eval_episodes, full_simulator)
        reports.update(
            {seed: min(reports[seed], again, key=lambda r: r.mean) for seed, again in confirmations.items()}
        )
    return reports


def screen_seed(seed: int, index: int) -> int:
    """First episode seed of the screen of evaluation ``index`` of run ``seed``."""
    return eval_seed(seed, 2 * index)


def full_seed(seed: int, index: int) -> int:
    """First episode seed of the full evaluation of evaluation ``index`` of run ``seed``."""
    return eval_seed(seed, 2 * index + 1)


def confirmation_seed(settings: TrainSettings) -> Callable[[int, int], int]:
    """First episode seed of a full evaluation's confirmation: the episode after its last."""
    return lambda seed, index: full_seed(seed, index) + settings.eval_episodes


def screened_evaluation(
    policy: Policy, env: EnvInfo, seed: int, index: int, settings: TrainSettings
) -> EvalReport:
    """The ``index``-th evaluation of run ``seed`` (:func:`screened_reports`). (Also how the
    benchmarks judge other libraries' agents.)"""

    def play(seeds: list[int], first: list[int], episodes: int, simulator: Simulator) -> list[EvalReport]:
        return [evaluate(policy, env, episodes, seed=first[0], simulator=simulator)]

    return screened_reports([(seed, index)], play, env, settings)[seed]


class StopWhenSolved(Callback):
    """Ends training at the first verified solve."""

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        if report.solved:
            loop.state.stop(StopReason.SOLVED, "solved")
            return False
        return True


@dataclass(frozen=True)
class CheckpointSchedule:
    """When ``latest`` is due: after ``fraction`` of the budget, after ``seconds`` of wall time, or
    (when > 0) after ``env_steps`` env steps since the last save, whichever comes first. So a kill -9
    loses at most one interval of work."""

    budget: Budget
    fraction: float = 0.05
    seconds: float = 30.0
    env_steps: int = 0

    @classmethod
    def from_settings(cls, budget: Budget, settings: TrainSettings) -> CheckpointSchedule:
        fraction, seconds = settings.checkpoint_fraction, settings.checkpoint_seconds
        return cls(budget, fraction, seconds, settings.checkpoint_every)


class CheckpointCallback(Callback):
    """Keeps ``latest`` (on :class:`CheckpointSchedule` and at exit), ``best`` (best
    evaluation, with its report in ``best_eval.json``) and ``solved`` (first verified solve)."""

    def __init__(
        self,
        run: RunDir,
        agent: AgentSpec,
        meta: dict[str, Any],
        schedule: CheckpointSchedule,
        metrics: MetricsCallback | None = None,
        status: StatusCallback | None = None,
    ):
        self.run, self.agent, self.meta, self.schedule = run, agent, meta, schedule
        self.metrics = metrics
        """Flushed before each ``latest``, so a resume from it finds every metric row up to its step."""
        self.status = status
        """Written before each ``latest``, so that after a kill -9 ``status.json`` never lags behind
        it (a population writes its status only every few seconds)."""
        self.last_save = (0, 0.0, 0.0)
        """(env steps, perf_counter time, budget progress) at the last save of ``latest``."""
        self.best: EvalReport | None = None
        self.latest_loop: dict[str, Any] | None = None
        """The loop counters in the last ``latest`` written."""

    def on_start(self, loop: TrainingLoop) -> None:
        if not self.run.checkpoint_path(CheckpointName.LATEST).exists():
            self.save(loop, CheckpointName.LATEST, resume=True)  # a kill -9 from here on loses little
        self.mark_saved(loop)
        previous = self.run.best_eval_report() if loop.state.evaluations else None
        if previous and "returns" in previous:
            self.best = EvalReport.from_dict(previous)

    def mark_saved(self, loop: TrainingLoop) -> None:
        progress = budget_progress(self.schedule.budget, loop.state)
        self.last_save = (loop.state.env_steps, time.perf_counter(), progress)

    def due(self, loop: TrainingLoop) -> bool:
        steps, when, progress = self.last_save
        schedule = self.schedule
        return (
            (schedule.env_steps > 0 and loop.state.env_steps - steps >= schedule.env_steps)
            or time.perf_counter() - when >= schedule.seconds
            or budget_progress(schedule.budget, loop.state) - progress >= schedule.fraction
        )

    def save(self, loop: TrainingLoop, name: CheckpointName, resume: bool) -> None:
        if resume and self.metrics is not None:
            # Rows still pending would be lost by a kill -9 after this save, and a resume from this
            # checkpoint would not log them again: a gap. Write them first.
            self.metrics.write_pending()
        if resume and self.status is not None:
            self.status.write(loop)
        tensors, data = loop.learner.state_dict(resume=resume)
        meta = {
            **self.meta,
            "step": loop.state.env_steps,
            "learner": data,
            "loop": loop.state.to_dict(),
            "resumable": resume,
        }
        save_checkpoint(self.run.checkpoint_path(name), Checkpoint(meta=meta, tensors=tensors))
        if name == CheckpointName.LATEST:
            self.latest_loop = meta["loop"]

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        if self.due(loop):
            self.save(loop, CheckpointName.LATEST, resume=True)
            self.mark_saved(loop)
        return True

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        if self.best is None or report_rank(report) > report_rank(self.best):
            self.best = report
            self.save(loop, CheckpointName.BEST, resume=False)
            self.run.write_best_eval(report.to_dict())
        if report.solved and not self.run.checkpoint_path(CheckpointName.SOLVED).exists():
            self.save(loop, CheckpointName.SOLVED, resume=False)
        return True

    def on_end(self, loop: TrainingLoop) -> None:
        if without_time(loop.state.to_dict()) != without_time(self.latest_loop or {}):
            self.save(loop, CheckpointName.LATEST, resume=True)  # not already saved by the last step


def without_time(loop: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in loop.items() if k != "elapsed"}


def finite(scalars: dict[str, float]) -> dict[str, float]:
    """The scalars that JSON can hold: a NaN loss (no update yet) is left out, not written."""
    return {k: float(v) for k, v in scalars.items() if math.isfinite(v)}


class MetricsCallback(Callback):
    """Appends metric rows to ``metrics.jsonl`` every ``flush_seconds`` (and before each ``latest``)."""

    FLUSH_SECONDS = 1.0

    def __init__(self, run: RunDir, flush_seconds: float = FLUSH_SECONDS):
        self.run, self.flush_seconds = run, flush_seconds
        self.pending: list[dict[str, Any]] = []
        self.listeners: list[Callable[[list[dict[str, Any]]], None]] = []
        """Also given every batch of rows written (e.g. :class:`TensorBoardCallback`)."""
        self.last_flush = 0.0
        self.last_sps_time = 0.0
        self.last_sps_steps = 0

    def base_row(self, loop: TrainingLoop) -> dict[str, Any]:
        s = loop.state
        return {"step": s.env_steps, "episode": s.episodes, "time": round(s.elapsed, 4)}

    def on_start(self, loop: TrainingLoop) -> None:
        self.last_sps_time, self.last_sps_steps = time.perf_counter(), loop.state.env_steps

    def on_episode(self, loop: TrainingLoop, episode_return: float, length: int) -> bool:
        row = self.base_row(loop)
        row["train/episode_return"] = float(episode_return)
        row["train/episode_length"] = int(length)
        row.update(finite(loop.state.scalars))
        self.pending.append(row)
        return True

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        if result.log_scalars:
            row = self.base_row(loop) | {"train/iteration": loop.state.iterations}
            self.pending.append(row | finite(result.scalars))
        now = time.perf_counter()
        if now - self.last_flush >= self.flush_seconds:
            self.flush(loop, now)
        return True

    def flush(self, loop: TrainingLoop, now: float) -> None:
        if self.pending:
            seconds = max(now - self.last_sps_time, 1e-9)
            self.pending[-1]["time/sps"] = (loop.state.env_steps - self.last_sps_steps) / seconds
        self.last_sps_time, self.last_sps_steps = now, loop.state.env_steps
        self.write_pending()
        self.last_flush = now

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        row = self.base_row(loop)
        row.update(
            {
                "eval/mean_return": report.mean,
                "eval/std_return": report.std,
                "eval/min_return": report.min,
                "eval/max_return": report.max,
                "eval/episodes": report.episodes,
                "eval/solved": report.solved,
                "eval/simulator": report.simulator,
            }
        )
        self.pending.append(row)
        return True

    def write_pending(self) -> None:
        """Append the pending rows to ``metrics.jsonl`` and pass them to the listeners."""
        rows, self.pending = self.pending, []
        self.run.append_metrics(rows)
        for listener in self.listeners:
            listener(rows)

    def on_end(self, loop: TrainingLoop) -> None:
        self.write_pending()


def status_fields(state: LoopState) -> dict[str, Any]:
    """The loop's counters as ``status.json`` records them."""
    return {
        "env_steps": state.env_steps,
        "episodes": state.episodes,
        "iterations": state.iterations,
        "elapsed": round(state.elapsed, 3),
        "best_eval_mean": state.best_eval_mean,
        "solved_in_training": state.solved,
        "solved_at_step": state.solved_at_step,
        "stop_reason": state.stop_reason.value if state.stop_reason else None,
        "stop_detail": state.stop_detail,
    }


class StatusCallback(Callback):
    """Keeps ``status.json`` "running" with fresh counters every ``flush_seconds``.

    It never writes an end state: the session does, once ``latest`` and the verdict are on disk.
    (The heartbeat between writes comes from :class:`~cartpole.runs.LiveStatus`'s thread.)
    """

    FLUSH_SECONDS = 1.0

    def __init__(self, status: LiveStatus, flush_seconds: float = FLUSH_SECONDS):
        self.status, self.flush_seconds = status, flush_seconds
        self.last_write = 0.0

    def write(self, loop: TrainingLoop) -> None:
        self.status.write(RunState.RUNNING, status_fields(loop.state))
        self.last_write = time.perf_counter()

    def on_start(self, loop: TrainingLoop) -> None:
        self.write(loop)

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        if time.perf_counter() - self.last_write >= self.flush_seconds:
            self.write(loop)
        return True

    def on_end(self, loop: TrainingLoop) -> None:
        self.write(loop)


class TensorBoardCallback(Callback):
    """Mirrors the metric rows as TensorBoard scalars in ``<run>/tensorboard/``.

    It writes exactly what :class:`MetricsCallback` writes (same keys, x = env steps), so the two
    never disagree. Given the run's ``record`` (its ``config.json``), a new run also gets its settings
    as hyperparameters (:func:`hparams_of`, for TensorBoard's HParams tab, whose metrics are the final
    verdict's: :func:`write_verdict` logs them) and its command as text. Needs the ``tensorboard``
    package (the ``tensorboard`` extra).
    """

    DIR = "tensorboard"
    SKIP = ("step", "episode", "time")

    def __init__(self, run: RunDir, metrics: MetricsCallback, record: dict[str, Any] | None = None):
        require_tensorboard()
        self.log_dir = run.path / self.DIR
        self.record = record
        self.writer: Any = None
        metrics.listeners.append(self.write_rows)

    def on_start(self, loop: TrainingLoop) -> None:
        from torch.utils.tensorboard import SummaryWriter

        # On a resume, drop events logged after the checkpoint, as metrics.jsonl drops its rows.
        purge = loop.state.env_steps + 1 if loop.state.env_steps else None
        self.writer = SummaryWriter(log_dir=str(self.log_dir), purge_step=purge)
        if self.record is not None and purge is None:  # a resume keeps those of its start
            write_settings(self.writer, self.record)

    def write_rows(self, rows: list[dict[str, Any]]) -> None:
        if self.writer is None:
            return
        for row in rows:
            step = int(row.get("step", 0))
            for key, value in row.items():
                if key in self.SKIP or isinstance(value, str) or value is None:
                    continue
                self.writer.add_scalar(key, float(value), global_step=step)
        self.writer.flush()

    def on_end(self, loop: TrainingLoop) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


HPARAM_SECTIONS = ("agent", "env_id", "seed", "preset", "device", "config", "settings", "budget")
"""What of a run's ``config.json`` TensorBoard gets as hyperparameters (``config/lr``, ...)."""
VERDICT_METRICS = ("verdict/mean_return", "verdict/solved")
"""The hyperparameters' metrics: the final verdict's mean return, and 1 if it solved."""
HParam = bool | int | float | str


def hparams_of(record: dict[str, Any]) -> dict[str, HParam]:
    """A run's settings as TensorBoard takes hyperparameters: nested tables flattened into
    ``section/key`` names, lists written as JSON text, and None (a setting left unset) left out."""
    flat: dict[str, HParam] = {}

    def add(name: str, value: Any) -> None:
        if isinstance(value, dict):
            for key, inner in value.items():
                add(f"{name}/{key}", inner)
        elif isinstance(value, bool | int | float | str):
            flat[name] = value
        elif value is not None:
            flat[name] = json.dumps(value, default=str)

    for section in HPARAM_SECTIONS:
        if section in record:
            add(section, record[section])
    return flat


def write_settings(writer: Any, record: dict[str, Any]) -> None:
    """The run's settings as hyperparameters, whose metrics are :data:`VERDICT_METRICS`, and its
    command as text (the same three summaries as torch's ``add_hparams``, in the run's own folder)."""
    from torch.utils.tensorboard.summary import hparams

    for summary in hparams(hparams_of(record), dict.fromkeys(VERDICT_METRICS, 0.0)):
        writer.file_writer.add_summary(summary)
    command = record.get("command") or []
    writer.add_text("command", "    " + shlex.join(str(part) for part in command))  # a code block
    writer.flush()


def write_verdict(run: RunDir, report: EvalReport, step: int) -> None:
    """Log the final verdict's :data:`VERDICT_METRICS` at ``step`` in ``<run>/tensorboard/``: the
    metrics of the run's hyperparameters."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(log_dir=str(run.path / TensorBoardCallback.DIR))
    try:
        for tag, value in zip(VERDICT_METRICS, (report.mean, float(report.solved)), strict=True):
            writer.add_scalar(tag, value, global_step=step)
    finally:
        writer.close()


TENSORBOARD_EXTRA = "pip install 'cartpole[tensorboard]'"


def require_tensorboard() -> None:
    """Raise ConfigError with the install line when the ``tensorboard`` package is missing."""
    from cartpole.core.errors import ConfigError

    try:
        import tensorboard  # noqa: F401
    except ImportError:
        raise ConfigError(f"--tensorboard needs the tensorboard package: {TENSORBOARD_EXTRA}") from None


def in_notebook() -> bool:
    """Whether this process is a Jupyter kernel (Jupyter, JupyterLab, VS Code, Colab): its cells
    show HTML, and its stderr is no terminal."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    return shell is not None and getattr(shell, "kernel", None) is not None


class NotebookBar:
    """A progress bar in a notebook cell's output: an HTML ``<progress>`` replaced in place through
    IPython's display handles (no widgets needed, so it shows wherever the notebook is opened)."""

    def __init__(self) -> None:
        from IPython.display import HTML, display

        self.html = HTML
        self.handle = display(HTML(""), display_id=True)

    def show(self, fraction: float | None, text: str) -> None:
        value = "" if fraction is None else f' value="{min(max(fraction, 0.0), 1.0):.4f}"'
        bar = f'<progress max="1"{value} style="width:320px;vertical-align:middle"></progress>'
        self.handle.update(self.html(f"<div>{bar} <small>{html.escape(text)}</small></div>"))


class ProgressCallback(Callback):
    """A rich progress bar on a terminal, an HTML bar in a notebook; a plain line every few seconds
    otherwise."""

    PLAIN_SECONDS = 5.0
    NOTEBOOK_SECONDS = 0.5

    def __init__(self, budget: Budget, unit: str, stream: TextIO | None = None):
        self.budget, self.unit = budget, unit
        self.stream = stream or sys.stderr
        self.progress: Any = None
        self.task: Any = None
        self.notebook: NotebookBar | None = None
        self.last_line = 0.0

    def total_and_done(self, loop: TrainingLoop) -> tuple[float | None, float, str]:
        s, b = loop.state, self.budget
        if b.env_steps:
            return b.env_steps, s.env_steps, "steps"
        if b.episodes:
            return b.episodes, s.episodes, "episodes"
        if b.iterations:
            return b.iterations, s.iterations, f"{self.unit}s"
        if b.seconds:
            return b.seconds, s.elapsed, "s"
        return None, s.env_steps, "steps"

    def describe(self, loop: TrainingLoop) -> str:
        s = loop.state
        parts = []
        if s.recent_returns:
            parts.append(f"return {s.recent_returns[-1]:.0f} (mean100 {s.mean_recent_return:.1f})")
        elif "train/mean_return" in s.scalars:  # population methods report per generation
            parts.append(f"generation mean return {s.scalars['train/mean_return']:.1f}")
        if s.last_eval is not None:
            parts.append(f"eval {s.last_eval.mean:.1f}/{s.last_eval.episodes}ep")
        for key in ("train/epsilon", "train/loss"):
            if key in s.scalars:
                parts.append(f"{key.split('/')[1]} {s.scalars[key]:.3g}")
        return "  ".join(parts)

    def on_start(self, loop: TrainingLoop) -> None:
        self.last_line = time.perf_counter()  # the first plain line comes after PLAIN_SECONDS
        if not self.stream.isatty():
            if in_notebook():
                self.notebook = NotebookBar()
                self.show_in_notebook(loop)
            return
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        from rich.text import Text

        class TwoLineProgress(Progress):
            """The bar on one line, the returns/eval/epsilon/loss below it: on an 80-column
            terminal one long line would make rich drop the bar and the ETA."""

            def get_renderables(self) -> Any:
                yield self.make_tasks_table(self.tasks)
                for task in self.tasks:
                    if task.fields.get("info"):
                        yield Text("  " + task.fields["info"], overflow="ellipsis", no_wrap=True)

        total, done, label = self.total_and_done(loop)
        self.progress = TwoLineProgress(
            TextColumn("[bold]training"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(label),
            TextColumn("{task.fields[sps]} steps/s"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(file=self.stream),
            transient=False,
        )
        self.task = self.progress.add_task("train", total=total, completed=done, sps="-", info="")
        self.progress.start()

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        now = time.perf_counter()
        if self.notebook is not None:
            if now - self.last_line >= self.NOTEBOOK_SECONDS:
                self.last_line = now
                self.show_in_notebook(loop)
        elif self.progress is not None:
            if now - self.last_line >= 0.2:
                _, done, _ = self.total_and_done(loop)
                sps = f"{loop.state.env_steps / max(loop.state.elapsed, 1e-9):,.0f}"
                self.progress.update(self.task, completed=done, sps=sps, info=self.describe(loop))
                self.last_line = now
        elif now - self.last_line >= self.PLAIN_SECONDS:
            self.last_line = now
            self.print_line(loop)
        return True

    def line(self, loop: TrainingLoop) -> str:
        """Where training is, in one line: time, budget spent, speed, returns and evaluations."""
        s = loop.state
        total, done, label = self.total_and_done(loop)
        number = "{:,.1f}" if label == "s" else "{:,.0f}"
        share = "/" + number.format(total) if total else ""
        sps = s.env_steps / max(s.elapsed, 1e-9)
        progress = f"{number.format(done)}{share} {label}"
        return f"[{s.elapsed:7.1f}s] {progress}  {sps:,.0f} steps/s  {self.describe(loop)}"

    def print_line(self, loop: TrainingLoop) -> None:
        print(self.line(loop), file=self.stream, flush=True)

    def show_in_notebook(self, loop: TrainingLoop) -> None:
        assert self.notebook is not None
        total, done, _ = self.total_and_done(loop)
        self.notebook.show(done / total if total else None, self.line(loop).strip())

    def on_end(self, loop: TrainingLoop) -> None:
        if self.notebook is not None:
            self.show_in_notebook(loop)
        if self.progress is not None:
            _, done, _ = self.total_and_done(loop)
            self.progress.update(self.task, completed=done, info=self.describe(loop))
            self.progress.stop()
