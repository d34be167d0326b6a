"""The experiment's figures: learning curves per entry with a 95% CI band, solve steps per entry, and
rliable's views of the final returns: performance profiles and the probability of improvement."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cartpole.experiments.entries import Entry
from cartpole.experiments.stats import CONFIDENCE, RESAMPLES
from cartpole.plotting import load_run

GRID_POINTS = 300
COLORS = ["C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9"]


@dataclass(frozen=True)
class EvalCurve:
    """One run's evaluation returns against env steps, and whether its final verdict solved: what the
    curves figure draws, read from a run folder or (shared comparisons) from the database."""

    steps: np.ndarray
    means: np.ndarray
    solved: bool
    threshold: float | None

    @classmethod
    def of_run(cls, path: Path | str) -> EvalCurve:
        """The curve of a run folder (RunError if it is not one)."""
        run = load_run(path)
        return cls(run.eval_steps, run.eval_mean, bool(run.solved), run.threshold)

    def to_json(self) -> dict[str, Any]:
        return {
            "steps": [float(s) for s in self.steps],
            "means": [float(m) for m in self.means],
            "solved": self.solved,
            "threshold": self.threshold,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EvalCurve:
        threshold = data.get("threshold")
        return cls(
            np.asarray(data.get("steps", []), dtype=np.float64),
            np.asarray(data.get("means", []), dtype=np.float64),
            bool(data.get("solved")),
            None if threshold is None else float(threshold),
        )


def mean_band(curves: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs (rows) at each point and a percentile bootstrap 95% CI (scipy.stats.bootstrap)."""
    from scipy.stats import bootstrap

    mean = curves.mean(axis=0)
    if curves.shape[0] < 2:
        return mean, mean, mean
    result = bootstrap(
        (curves,),
        np.mean,
        axis=0,
        confidence_level=CONFIDENCE,
        n_resamples=min(RESAMPLES, 2000),
        method="percentile",
        vectorized=True,
        random_state=np.random.default_rng(0),
    )
    low = np.where(np.isnan(result.confidence_interval.low), mean, result.confidence_interval.low)
    high = np.where(np.isnan(result.confidence_interval.high), mean, result.confidence_interval.high)
    return mean, low, high


def plot_curves(groups: dict[str, list[EvalCurve]], out: Path, env_id: str) -> Path | None:
    """Evaluation return (the greedy policy's mean over its evaluation episodes) against env steps:
    per entry the mean over its runs and a 95% CI band. A run that stopped early (solved) keeps its
    last value, so early finishers stay in the mean."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(9, 5.5), layout="constrained")
    ax = figure.add_subplot()
    drawn = False
    threshold = None
    for index, (label, all_runs) in enumerate(groups.items()):
        runs = [r for r in all_runs if r.means.size]
        if not runs:
            continue
        threshold = threshold or runs[0].threshold
        grid = np.linspace(0, max(r.steps[-1] for r in runs), GRID_POINTS)
        curves = np.stack([np.interp(grid, r.steps, r.means) for r in runs])
        mean, low, high = mean_band(curves)
        color = COLORS[index % len(COLORS)]
        ax.fill_between(grid, low, high, color=color, alpha=0.2, linewidth=0)
        solved = sum(r.solved for r in runs)
        ax.plot(
            grid,
            mean,
            color=color,
            linewidth=2,
            label=f"{label}: {len(runs)} runs, final verdict solved {solved}",
        )
        drawn = True
    if not drawn:
        return None
    if threshold is not None:
        ax.axhline(
            threshold, color="0.3", linestyle="--", linewidth=1, label=f"solved threshold {threshold:g}"
        )
    ax.set_xlabel("env steps")
    ax.set_ylabel("evaluation return (greedy policy)")
    ax.set_title(f"{env_id}: mean over runs, {CONFIDENCE:.0%} bootstrap CI")
    ax.grid(True, alpha=0.3)
    ax.set_xlim(left=0)
    if all(r.means.min() >= 0 for runs in groups.values() for r in runs if r.means.size):
        ax.set_ylim(bottom=0)  # CartPole's returns; Acrobot's and MountainCar's are negative
    ax.legend(loc="lower right", fontsize=9)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    return out


def plot_solve_steps(
    summaries: list[dict[str, Any]], records: dict[Entry, list[dict[str, Any]]], out: Path
) -> Path | None:
    """Each run's env steps to its first verified solve, per entry; unsolved runs as hollow markers at
    what they used (censored), and the median as a bar."""
    from matplotlib.figure import Figure

    if not any(records.values()):
        return None
    figure = Figure(figsize=(9, 4.8), layout="constrained")
    ax = figure.add_subplot()
    rng = np.random.default_rng(0)
    for index, runs in enumerate(records.values()):
        color = COLORS[index % len(COLORS)]
        solved = [r for r in runs if r.get("solved_in_training")]
        unsolved = [r for r in runs if not r.get("solved_in_training")]
        for group, filled in ((solved, True), (unsolved, False)):
            if not group:
                continue
            y = [r["solve_steps"] if filled else r["env_steps"] for r in group]
            x = index + rng.uniform(-0.15, 0.15, len(group))
            ax.scatter(
                x,
                y,
                s=30,
                color=color if filled else "none",
                edgecolors=color,
                label=None if filled else ("not solved (at its budget)" if index == 0 else None),
            )
        median = summaries[index]["env_steps_to_solve"]["median"]
        if median is not None:
            ax.hlines(median, index - 0.3, index + 0.3, color="black", linewidth=2)
    ax.set_xticks(range(len(records)), [e.label for e in records], rotation=0)
    ax.set_ylabel("env steps to the first verified solve")
    ax.set_yscale("log")
    ax.set_title("Solve steps per run (black bar: median; hollow: unsolved, censored at its budget)")
    ax.grid(True, axis="y", alpha=0.3)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    return out


def plot_performance_profile(view: dict[str, Any], out: Path) -> Path | None:
    """rliable's performance profile: per entry, the fraction of runs whose final verdict mean return
    is above each tau, with a pointwise 95% bootstrap CI band; the solved threshold as a line."""
    from matplotlib.figure import Figure

    profiles = view["entries"]
    if not profiles or not view["taus"]:
        return None
    figure = Figure(figsize=(9, 5), layout="constrained")
    ax = figure.add_subplot()
    taus = np.asarray(view["taus"])
    for index, (label, profile) in enumerate(profiles.items()):
        color = COLORS[index % len(COLORS)]
        low, high = profile["ci95_low"], profile["ci95_high"]  # a step at each run's score
        ax.fill_between(taus, low, high, step="post", color=color, alpha=0.2, linewidth=0)
        ax.plot(taus, profile["fraction"], drawstyle="steps-post", color=color, linewidth=2, label=label)
    if view.get("threshold") is not None:
        ax.axvline(view["threshold"], color="0.3", linestyle="--", linewidth=1,
                   label=f"solved threshold {view['threshold']:g}")  # fmt: skip
    ax.set_xlabel("final verdict mean return (tau)")
    ax.set_ylabel("fraction of runs with score > tau")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"Performance profile: {CONFIDENCE:.0%} bootstrap CI")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower left", fontsize=9)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    return out


def plot_improvement(pairs: list[dict[str, Any]], out: Path) -> Path | None:
    """rliable's probability of improvement: for each pair of entries, P(X > Y) (a run of X scores above
    a run of Y, ties half) with its 95% bootstrap CI; 0.5 is no difference."""
    from matplotlib.figure import Figure

    shown = [p for p in pairs if p["probability"] is not None]
    if not shown:
        return None
    figure = Figure(figsize=(9, 1.4 + 0.5 * len(shown)), layout="constrained")
    ax = figure.add_subplot()
    rows = np.arange(len(shown))[::-1]
    for row, pair in zip(rows, shown, strict=True):
        low, high = pair["ci95"] or (pair["probability"], pair["probability"])
        ax.barh(row, high - low, left=low, height=0.6, color="C0", alpha=0.35)
        ax.plot([pair["probability"]] * 2, [row - 0.3, row + 0.3], color="C0", linewidth=2)
    ax.set_yticks(rows, [f"P({p['x']} > {p['y']})" for p in shown])
    ax.axvline(0.5, color="0.3", linestyle="--", linewidth=1)
    ax.set_xlim(0, 1)
    ax.set_xlabel("probability of improvement (final verdict mean return)")
    ax.set_title(f"Probability of improvement: {CONFIDENCE:.0%} bootstrap CI")
    ax.grid(True, axis="x", alpha=0.3)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    return out
