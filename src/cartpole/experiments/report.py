"""The experiment report: ``report.json`` (every number), ``report.md`` (a table for GitHub) and plots."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cartpole.experiments.compare import Experiment
from cartpole.experiments.entries import Entry
from cartpole.experiments.figures import EvalCurve
from cartpole.experiments.shared import SharedComparison
from cartpole.experiments.stats import (
    CONFIDENCE,
    censored_summary,
    improvement_summary,
    iqm_summary,
    performance_profile,
    profile_taus,
)
from cartpole.runs.atomic import write_json_atomic, write_text_atomic

TIMES = (
    ("env_steps_to_solve", "solve_steps", "env_steps"),
    ("cpu_seconds_to_solve", "solve_cpu_seconds", "cpu_seconds"),
    ("wall_seconds_to_solve", "solve_wall_seconds", "wall_seconds"),
)
"""(report key, the record's value at the first solve, what an unsolved run used: its censoring)."""


def entry_summary(entry: Entry, records: list[dict[str, Any]]) -> dict[str, Any]:
    """One entry's line of the report; unsolved runs enter the times censored at what they used."""
    solved = [bool(r.get("solved_in_training")) for r in records]
    summary: dict[str, Any] = {
        "entry": entry.label,
        "agent": entry.agent,
        "preset": entry.preset,
        "runs": len(records),
        "solved": sum(solved),
        "final_solved": sum(bool(r.get("final_solved")) for r in records),
    }
    censored = [not ok for ok in solved]
    for key, at_solve, used in TIMES:
        values = [float(r[at_solve] if ok else r[used]) for r, ok in zip(records, solved, strict=True)]
        # with the per-seed values it summarizes (in the order of "seeds"), for rliable and other tools
        summary[key] = censored_summary(values, censored) | {"values": values, "censored_runs": censored}
    finals = [float(r["final_mean"]) for r in records]
    summary["final_mean_return"] = iqm_summary(finals) | {"values": finals}
    summary["seeds"] = [r["seed"] for r in records]
    summary["run_folders"] = [r["run"] for r in records]
    summary["devices"] = sorted({str(r.get("device", "cpu")) for r in records})
    return summary


@dataclass
class Results:
    """What a report is built from: the finished runs' records and evaluation curves, per entry, read
    from a local experiment's folder or from a shared comparison's database rows."""

    env_id: str
    budget: str | None
    seeds: list[int]
    records: dict[Entry, list[dict[str, Any]]]
    curves: dict[Entry, list[EvalCurve]]

    @classmethod
    def of_experiment(cls, experiment: Experiment) -> Results:
        """A local experiment's results: its records, and the curves of their run folders."""
        from cartpole.runs import RunError

        records = experiment.records()
        curves: dict[Entry, list[EvalCurve]] = {}
        for entry, found in records.items():
            curves[entry] = []
            for record in found:
                try:
                    curves[entry].append(EvalCurve.of_run(record["run"]))
                except (RunError, OSError, KeyError):  # a run folder deleted or damaged since
                    continue
        return cls(experiment.env_id, experiment.budget, experiment.seeds, records, curves)

    @classmethod
    def of_shared(cls, shared: SharedComparison) -> Results:
        """A shared comparison's results: every finished row in its database, whichever machine ran it."""
        records, curves = shared.finished()
        return cls(
            str(shared.setup.get("env_id")),
            shared.setup.get("budget"),
            shared.seeds(),
            records,
            {entry: [EvalCurve.from_json(c) for c in found if c] for entry, found in curves.items()},
        )


SCORE = "final_mean"
"""The score of a run in the rliable views: its final verdict's mean return (the kept best policy on
100 fresh episodes), as it is: one task needs no normalizing across tasks, and a threshold's ratio
would turn over on envs whose returns are negative."""


def score_matrix(results: Results) -> dict[str, Any]:
    """Every run's score as rliable reads it: a matrix of runs (rows, one per seed in ``seeds``) by
    entries (columns, in ``entries``' order), None where a seed of an entry has not finished."""
    scores = {e.label: {int(r["seed"]): float(r[SCORE]) for r in rs} for e, rs in results.records.items()}
    found = {seed for by_seed in scores.values() for seed in by_seed}
    seeds = [s for s in results.seeds if s in found] + sorted(found - set(results.seeds))
    return {
        "score": "each run's final verdict mean return (100 fresh episodes of the kept best policy)",
        "entries": list(scores),
        "seeds": seeds,
        "matrix": [[by_seed.get(seed) for by_seed in scores.values()] for seed in seeds],
    }


def threshold_of(results: Results) -> float | None:
    """The env's solved threshold, as the runs' curves record it (None if none does)."""
    return next((c.threshold for cs in results.curves.values() for c in cs if c.threshold is not None), None)


def rliable_views(results: Results) -> dict[str, Any]:
    """The score matrix, each entry's performance profile (fraction of runs above each score tau) and
    the probability of improvement of each entry over each later one, all with 95% bootstrap CIs."""
    scores = {e.label: [float(r[SCORE]) for r in rs] for e, rs in results.records.items()}
    threshold = threshold_of(results)
    taus = profile_taus([v for vs in scores.values() for v in vs], [] if threshold is None else [threshold])
    labels = list(scores)
    return {
        "scores": score_matrix(results),
        "performance_profile": {
            "taus": [float(t) for t in taus],
            "threshold": threshold,
            "entries": {label: performance_profile(values, taus) for label, values in scores.items()},
        },
        "probability_of_improvement": [
            {"x": x, "y": y} | improvement_summary(scores[x], scores[y])
            for i, x in enumerate(labels)
            for y in labels[i + 1 :]
        ],
    }


def build_report(results: Results) -> dict[str, Any]:
    records = results.records
    return {
        "env_id": results.env_id,
        "budget": results.budget or "each preset's own",
        "seeds": results.seeds,
        "confidence": CONFIDENCE,
        "method": (
            "medians and IQRs of times to the first verified solve (a full 100-episode evaluation at the "
            "threshold), unsolved runs counted censored at what they used (their budget); final return: "
            "interquartile mean of each run's final verdict (the kept best policy on 100 fresh episodes); "
            "95% CIs: percentile bootstrap (scipy.stats.bootstrap, 4000 resamples) over runs; performance "
            "profiles (the fraction of runs whose final verdict mean return is above each tau) and the "
            "probability of improvement P(X > Y) (Mann-Whitney U / (n m), the runs of X and Y resampled "
            "independently) as rliable defines them (Agarwal et al., 2021), from the score matrix"
        ),
        "entries": [entry_summary(entry, rs) for entry, rs in records.items()],
    } | rliable_views(results)


def _number(value: float, digits: int) -> str:
    return f"{value:,.{digits}f}"


def _time_cell(stats: dict[str, Any], digits: int) -> str:
    if stats["median"] is None:
        return "-"
    bound = "≥ " if stats["median_is_lower_bound"] else ""
    text = f"{bound}{_number(stats['median'], digits)}"
    if stats["ci95"]:
        low, high = stats["ci95"]
        text += f" [{_number(low, digits)}, {_number(high, digits)}]"
    low, high = stats["iqr"]
    return text + f" (IQR {_number(low, digits)}-{_number(high, digits)})"


def _return_cell(stats: dict[str, Any]) -> str:
    if stats["iqm"] is None:
        return "-"
    text = f"{stats['iqm']:.1f}"
    if stats["ci95"]:
        text += f" [{stats['ci95'][0]:.1f}, {stats['ci95'][1]:.1f}]"
    return text


def seed_range(seeds: list[int]) -> str:
    if not seeds:
        return "No runs yet."
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"Seeds {seeds[0]}-{seeds[-1]}."
    return f"{len(seeds)} seeds: {', '.join(map(str, seeds))}."


def markdown(report: dict[str, Any], figures: list[str]) -> str:
    """``report.md``: the table, how to read it, and the figures."""
    lines = [
        f"# {report['env_id']}: {len(report['entries'])} entries x {len(report['seeds'])} seeds",
        "",
        "| entry | runs | solved | final verdict solved | env steps to solve | CPU s to solve "
        "| wall s to solve | final return, IQM |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for e in report["entries"]:
        lines.append(
            f"| {e['entry']} | {e['runs']} | {e['solved']}/{e['runs']} | {e['final_solved']}/{e['runs']} "
            f"| {_time_cell(e['env_steps_to_solve'], 0)} | {_time_cell(e['cpu_seconds_to_solve'], 2)} "
            f"| {_time_cell(e['wall_seconds_to_solve'], 2)} | {_return_cell(e['final_mean_return'])} |"
        )
    lines += [
        "",
        f"Times: median [95% bootstrap CI] (IQR) over runs, to the first verified solve (a full "
        f"100-episode evaluation at the threshold during training). A run that never solved counts at "
        f"what it used (its budget: {report['budget']}), censored, not dropped; ≥ marks a median that "
        f"such runs hold up (at least half unsolved). Final return: interquartile mean [95% CI] of each "
        f"run's final verdict (its kept best policy on 100 fresh episodes). {seed_range(report['seeds'])}",
        "",
    ]
    devices = {e["entry"]: e.get("devices", ["cpu"]) for e in report["entries"]}
    if any(found != ["cpu"] for found in devices.values()):  # a CPU-only report reads as before
        lines += ["Devices: " + "; ".join(f"{k}: {', '.join(v)}" for k, v in devices.items()) + ".", ""]
    lines += improvement_lines(report["probability_of_improvement"])
    lines += [f"![{Path(f).stem}]({Path(f).name})" for f in figures]
    return "\n".join(lines) + "\n"


def improvement_lines(pairs: list[dict[str, Any]]) -> list[str]:
    """The probability of improvement of each pair, in words, for ``report.md``."""
    shown = [p for p in pairs if p["probability"] is not None]
    if not shown:
        return []
    lines = [
        "Probability of improvement: the chance that a run of X ends with a higher final verdict mean "
        "return than a run of Y (ties count half; 0.5: no difference) [95% bootstrap CI]. Every run's "
        "score is in report.json's `scores` (runs x entries, as rliable reads it).",
        "",
    ]
    for p in shown:
        ci = f" [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}]" if p["ci95"] else ""
        lines.append(f"- P({p['x']} > {p['y']}) = {p['probability']:.2f}{ci}")
    return [*lines, ""]


def write_report(results: Results, folder: Path) -> tuple[dict[str, Any], list[Path]]:
    """Write report.json, report.md and the PNGs into ``folder``; return the report and the files."""
    from cartpole.experiments.figures import (
        plot_curves,
        plot_improvement,
        plot_performance_profile,
        plot_solve_steps,
    )

    report = build_report(results)
    groups = {entry.label: curves for entry, curves in results.curves.items()}
    figures = [
        plot_curves(groups, folder / "curves.png", report["env_id"]),
        plot_solve_steps(report["entries"], results.records, folder / "solve_steps.png"),
        plot_performance_profile(report["performance_profile"], folder / "performance_profile.png"),
        plot_improvement(report["probability_of_improvement"], folder / "improvement.png"),
    ]
    written = [p for p in figures if p is not None]
    write_json_atomic(folder / "report.json", report)
    text = markdown(report, [str(p) for p in written])
    write_text_atomic(folder / "report.md", text)
    return report, [folder / "report.json", folder / "report.md", *written]
