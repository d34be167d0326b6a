"""Learning curves from run folders: one run in detail, or several runs of an agent aggregated.

``plot_runs`` reads only what training wrote (``config.json``, ``status.json``, ``eval.json``,
``metrics.jsonl``) and draws, on one axes:

- training returns: per episode (``train/episode_return``, DQN) or per generation
  (``train/mean_return``, the linear searches), raw in a light line, with a trailing moving average;
- evaluations (``eval/mean_return`` ± ``eval/std_return``) as points with error bars, a star where the
  evaluation verified a solve;
- the env's solved threshold (``reward_threshold`` from Gymnasium's registry) as a dashed line.

Runs of the same agent on the same env are aggregated: the mean of their moving averages with a 95%
bootstrap confidence band over runs, and "k/n solved" in the legend. A run that stopped early (for
instance when solved) keeps its last value up to the longest run, so early finishers are not dropped
from the mean. Figures are drawn with matplotlib's object API (no pyplot, no display needed).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cartpole.core.errors import InputError
from cartpole.runs import RunDir, RunError, summarize_run
from cartpole.runs.atomic import replace_atomically

if TYPE_CHECKING:
    from matplotlib.figure import Figure

XAxis = Literal["steps", "episodes"]
IMAGE_SUFFIXES = (".png", ".svg", ".pdf")
EPISODE_WINDOW = 100
"""Moving-average window for per-episode returns: Gymnasium's rule averages 100 episodes."""
GENERATION_WINDOW = 10
"""Moving-average window for per-generation mean returns (each already averages many episodes)."""
BOOTSTRAP_SAMPLES = 2000
GRID_POINTS = 400


class PlotError(InputError, ValueError):
    """Nothing to plot, or an output file type we cannot write."""


@dataclass
class RunCurves:
    """The series of one run that a plot needs."""

    name: str
    agent: str
    env_id: str
    threshold: float | None
    solved: bool
    unit: str
    """"episode" (one training row per episode) or "generation" (one row per generation)."""
    steps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    episodes: np.ndarray = field(default_factory=lambda: np.zeros(0))
    returns: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_steps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_episodes: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_mean: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eval_solved: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def x(self, axis: XAxis) -> np.ndarray:
        return self.steps if axis == "steps" else self.episodes

    def eval_x(self, axis: XAxis) -> np.ndarray:
        return self.eval_steps if axis == "steps" else self.eval_episodes


def load_run(path: Path | str) -> RunCurves:
    """Read a run folder's training and evaluation series (RunError if it is not a run folder)."""
    from cartpole.envs import env_info

    run = RunDir.open(Path(path))
    config = run.config()
    env_id = str(config.get("env_id", "?"))
    try:
        threshold = env_info(env_id).reward_threshold
    except Exception:  # an env we cannot look up still has curves worth drawing
        threshold = None
    rows = run.metrics()
    per_episode = [r for r in rows if "train/episode_return" in r]
    if per_episode:
        train, key, unit = per_episode, "train/episode_return", "episode"
    else:
        train = [r for r in rows if "train/mean_return" in r]
        key, unit = "train/mean_return", "generation"
    evals = [r for r in rows if "eval/mean_return" in r]

    def column(items: list[dict[str, Any]], name: str, default: float = 0.0) -> np.ndarray:
        try:
            return np.array([float(r.get(name, default)) for r in items], dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise RunError(f"{run.metrics_path} has a malformed {name!r} value: {err}") from err

    return RunCurves(
        name=run.name,
        agent=str(config.get("agent", "?")),
        env_id=env_id,
        threshold=threshold,
        solved=summarize_run(run.path).solved,
        unit=unit,
        steps=column(train, "step"),
        episodes=column(train, "episode"),
        returns=column(train, key),
        eval_steps=column(evals, "step"),
        eval_episodes=column(evals, "episode"),
        eval_mean=column(evals, "eval/mean_return"),
        eval_std=column(evals, "eval/std_return"),
        eval_solved=np.array([bool(r.get("eval/solved", False)) for r in evals], dtype=bool),
    )


def load_readable_runs(paths: list[Path], on_skip: Callable[[str], None] | None) -> list[RunCurves]:
    """The curves of each run; an unreadable run raises, or goes to ``on_skip`` when one is given."""
    runs = []
    for path in paths:
        try:
            runs.append(load_run(path))
        except RunError as err:
            if on_skip is None:
                raise
            on_skip(f"skipped {path}: {err}")
    if not runs and paths and on_skip is not None:
        raise PlotError(f"no readable run among the {len(paths)} given")
    return runs


def expand_run_paths(paths: Sequence[Path | str]) -> list[Path]:
    """Run folders as given; a folder of run folders (like ``runs/``) stands for all of them."""
    found: list[Path] = []
    for item in map(Path, paths):
        if (item / "config.json").is_file():
            found.append(item)
        elif item.is_dir() and (children := sorted(p.parent for p in item.glob("*/config.json"))):
            found += children
        else:
            raise RunError(f"{item} is not a run folder (no config.json); see `cartpole runs`")
    return found


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start)."""
    if values.size == 0:
        return values
    sums = np.cumsum(np.insert(values.astype(np.float64), 0, 0.0))
    ends = np.arange(1, values.size + 1)
    starts = np.maximum(ends - window, 0)
    return (sums[ends] - sums[starts]) / (ends - starts)


def bootstrap_band(
    curves: np.ndarray, level: float = 0.95, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs (rows of ``curves`` [runs, points]) and a percentile bootstrap band."""
    rng = np.random.default_rng(seed)
    n = curves.shape[0]
    picks = rng.integers(0, n, size=(samples, n))
    # How often each resample picked each run, then one product: the resampled means without the
    # [samples, runs, points] array that indexing ``curves[picks]`` would build (320 MB for 50 runs).
    counts = np.zeros((samples, n))
    np.add.at(counts, (np.arange(samples)[:, None], picks), 1.0)
    means = counts @ curves / n  # [samples, points]
    tail = (1.0 - level) / 2 * 100
    low, high = np.percentile(means, [tail, 100 - tail], axis=0)
    return curves.mean(axis=0), low, high


def _what(unit: str) -> str:
    return "episode return" if unit == "episode" else "mean return of each generation"


def default_window(unit: str) -> int:
    return EPISODE_WINDOW if unit == "episode" else GENERATION_WINDOW


def _hold_last(grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y(x)`` on ``grid``, linear between points and held at its last value after the run ended."""
    return np.interp(grid, x, y, left=y[0], right=y[-1])


def plot_runs(
    paths: Sequence[Path | str],
    out: Path | str,
    *,
    x_axis: XAxis = "steps",
    window: int | None = None,
    title: str | None = None,
    dpi: int = 150,
    on_skip: Callable[[str], None] | None = None,
) -> Path:
    """Draw the runs' learning curves to ``out`` (.png, .svg or .pdf) and return its path.

    A run that cannot be read raises RunError, or with ``on_skip`` is left out and its problem
    passed to ``on_skip`` (PlotError if no run is left)."""
    out = Path(out)
    if out.suffix.lower() not in IMAGE_SUFFIXES:
        raise PlotError(f"cannot write {out}: use a .png, .svg or .pdf file name")
    figure = runs_figure(paths, x_axis=x_axis, window=window, title=title, on_skip=on_skip)
    # Atomically, as every file we write: a full disk leaves no half figure, and its error names the file.
    replace_atomically(out, lambda tmp: figure.savefig(tmp, dpi=dpi), suffix=out.suffix)
    return out


def runs_figure(
    paths: Sequence[Path | str],
    *,
    x_axis: XAxis = "steps",
    window: int | None = None,
    title: str | None = None,
    on_skip: Callable[[str], None] | None = None,
) -> Figure:
    """The runs' learning curves as a matplotlib Figure (one panel per env), as :func:`plot_runs`
    draws them; PlotError when there is nothing to draw."""
    from matplotlib.figure import Figure

    if x_axis not in ("steps", "episodes"):
        raise PlotError(f"x axis must be steps or episodes, got {x_axis!r}")
    runs = load_readable_runs(expand_run_paths(paths), on_skip)
    if not runs:
        raise PlotError("no runs to plot")
    empty = [r.name for r in runs if r.returns.size == 0 and r.eval_mean.size == 0]
    if len(empty) == len(runs):
        raise PlotError(f"no metrics yet in {', '.join(empty)}: train first (or wait for the first rows)")
    runs = [r for r in runs if r.name not in empty]

    panels = panels_by_env(runs)
    legend_rows = [-(-(len(groups) * 3 + 2) // LEGEND_COLUMNS) for groups in panels.values()]
    height = sum(PANEL_HEIGHT + LEGEND_ROW_HEIGHT * rows for rows in legend_rows)
    figure = Figure(figsize=(10, height), layout="constrained")
    axes = figure.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, groups in zip(axes, panels.values(), strict=True):
        env_runs = [run for members in groups.values() for run in members]
        own_title = title if len(panels) == 1 and title else _default_title(env_runs, groups)
        _draw_panel(ax, env_runs, groups, x_axis, window, own_title)
    if title and len(panels) > 1:
        figure.suptitle(title)
    return figure


PANEL_HEIGHT = 5.2
"""Inches of one env's panel, before its legend."""
LEGEND_COLUMNS = 2
LEGEND_ROW_HEIGHT = 0.2
COLORS = ["C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9"]
"""One color per agent (or agent and preset) in a panel: more than these cannot be told apart."""


def panels_by_env(runs: list[RunCurves]) -> dict[str, dict[str, list[RunCurves]]]:
    """The runs by env (one panel each), then by agent (one curve or band each); PlotError when a
    panel would hold more agents than it has colors."""
    panels: dict[str, dict[str, list[RunCurves]]] = {}
    for run in runs:
        panels.setdefault(run.env_id, {}).setdefault(run.agent, []).append(run)
    for env_id, groups in panels.items():
        if len(groups) > len(COLORS):
            raise PlotError(
                f"{len(groups)} agents on {env_id} are more than one figure can tell apart ({len(COLORS)} "
                "colors): pass the run folders of fewer agents"
            )
    return panels


def _draw_panel(
    ax: Any,
    runs: list[RunCurves],
    groups: dict[str, list[RunCurves]],
    x_axis: XAxis,
    window: int | None,
    title: str,
) -> None:
    """One env's runs on ``ax``: a curve or band per agent, its threshold, and its own legend below."""
    for color, (agent, members) in zip(COLORS, groups.items(), strict=False):
        if len(members) == 1:
            _draw_single(ax, members[0], x_axis, window, color, agent)
        else:
            _draw_group(ax, members, x_axis, window, color, agent)
    for threshold in sorted({r.threshold for r in runs if r.threshold is not None}):
        ax.axhline(
            threshold, color="0.25", linestyle="--", linewidth=1.0, label=f"solved threshold {threshold:g}"
        )
    ax.set_xlabel("env steps" if x_axis == "steps" else "episodes")
    ax.set_ylabel("return")
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3)
    ax.set_xlim(left=0)
    ax.set_ylim(*_y_limits(runs))
    ax.ticklabel_format(axis="x", style="plain")
    ax.xaxis.set_major_formatter(_thousands())
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # one "verified solve" entry, not one per group
    # Below the axes, so it never hides a curve, a point or the threshold line.
    ax.legend(
        unique.values(),
        unique.keys(),
        loc="upper center",
        bbox_to_anchor=(0.5, -0.12),
        ncols=LEGEND_COLUMNS,
        fontsize=8,
        frameon=False,
    )


def _thousands() -> Any:
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda value, _: f"{value:,.0f}")


def _y_limits(runs: list[RunCurves]) -> tuple[float, float]:
    """From 0 (or the lowest return, for envs whose returns are negative, such as Acrobot's) to a
    little above the highest return, threshold and error bar."""
    values = [r.returns for r in runs if r.returns.size]
    values += [r.eval_mean + r.eval_std for r in runs if r.eval_mean.size]
    values += [r.eval_mean - r.eval_std for r in runs if r.eval_mean.size]
    values += [np.array([r.threshold]) for r in runs if r.threshold is not None]
    low = min(0.0, *(float(v.min()) for v in values)) if values else 0.0
    high = max(0.0, *(float(v.max()) for v in values)) if values else 1.0
    margin = 0.08 * ((high - low) or 1.0)
    return (low - margin if low < 0 else 0.0), high + margin


def _default_title(runs: list[RunCurves], groups: dict[str, list[RunCurves]]) -> str:
    if len(runs) == 1:
        return runs[0].name
    envs = sorted({r.env_id for r in runs})
    what = ", ".join(f"{agent} ({len(m)} run{'s' * (len(m) > 1)})" for agent, m in groups.items())
    return f"{' / '.join(envs)}: {what}"


def _draw_evals(
    ax: Any, run: RunCurves, x_axis: XAxis, color: str, label: str | None, faint: bool = False
) -> None:
    """Evaluation means with ± std bars, and a star at the run's first verified solve."""
    if run.eval_mean.size == 0:
        return
    x = run.eval_x(x_axis)
    ax.errorbar(
        x,
        run.eval_mean,
        yerr=run.eval_std,
        fmt="o",
        markersize=3 if faint else 4,
        color=color,
        ecolor=color,
        elinewidth=0.8 if faint else 1,
        capsize=2 if faint else 3,
        alpha=0.45 if faint else 0.9,
        label=label,
        zorder=4,
    )
    if run.eval_solved.any():
        first = int(np.argmax(run.eval_solved))
        ax.scatter(
            x[first],
            run.eval_mean[first],
            marker="*",
            s=180,
            color="gold",
            edgecolors="black",
            linewidths=0.7,
            label="first verified solve",
            zorder=5,
        )


def _draw_single(ax: Any, run: RunCurves, x_axis: XAxis, window: int | None, color: str, prefix: str) -> None:
    x = run.x(x_axis)
    if run.returns.size:
        size = window or default_window(run.unit)
        ax.plot(x, run.returns, color=color, alpha=0.25, linewidth=0.8, label=f"{prefix}: {_what(run.unit)}")
        ax.plot(
            x,
            moving_average(run.returns, size),
            color=color,
            linewidth=2,
            marker="o" if x.size < 30 else None,  # a short run's few points still show
            markersize=4,
            label=f"{prefix}: mean of last {size} {run.unit}s",
        )
    verdict = "solved" if run.solved else "not solved"
    _draw_evals(ax, run, x_axis, color, f"{prefix}: evaluation mean ± std ({verdict})")


def _draw_group(
    ax: Any, runs: list[RunCurves], x_axis: XAxis, window: int | None, color: str, prefix: str
) -> None:
    with_data = [r for r in runs if r.returns.size]
    solved = sum(r.solved for r in runs)
    if with_data:
        size = window or default_window(with_data[0].unit)
        xs = [r.x(x_axis) for r in with_data]
        grid = np.linspace(max(x[0] for x in xs), max(x[-1] for x in xs), GRID_POINTS)
        curves = np.stack([_hold_last(grid, r.x(x_axis), moving_average(r.returns, size)) for r in with_data])
        mean, low, high = bootstrap_band(curves)
        for r in with_data:
            ax.plot(r.x(x_axis), r.returns, color=color, alpha=0.06, linewidth=0.6)
        ax.fill_between(grid, low, high, color=color, alpha=0.22, linewidth=0, label=None)
        ax.plot(
            grid,
            mean,
            color=color,
            linewidth=2,
            label=(
                f"{prefix}: mean of {len(with_data)} runs (last {size} {with_data[0].unit}s), "
                f"95% bootstrap CI; {solved}/{len(runs)} solved"
            ),
        )
    first = True
    for r in runs:
        label = f"{prefix}: evaluation mean ± std of each run" if first else None
        _draw_evals(ax, r, x_axis, color, label, faint=True)
        first = first and r.eval_mean.size == 0


__all__ = [
    "PlotError",
    "RunCurves",
    "bootstrap_band",
    "expand_run_paths",
    "load_run",
    "moving_average",
    "plot_runs",
    "runs_figure",
]
