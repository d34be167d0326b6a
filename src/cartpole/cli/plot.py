"""``cartpole plot``: learning curves of one or more runs, as PNG, SVG or PDF."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "plot",
        help="plot learning curves of runs",
        description=(
            "Draw training returns (raw, light, with a moving average), evaluations with error bars "
            "and the solved threshold. Several runs of the same agent and env are aggregated: mean "
            "curve, 95% bootstrap confidence band, and how many runs solved. A folder of runs "
            "(e.g. runs/) stands for every run in it."
        ),
    )
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run folders (or a folder of runs)")
    parser.add_argument(
        "--out",
        metavar="FILE",
        help="FILE.png, .svg or .pdf (default: <run name>.png, or plot.png for several runs)",
    )
    parser.add_argument(
        "--x",
        dest="x_axis",
        choices=["steps", "episodes"],
        default="steps",
        help="x axis: env steps or episodes (default: steps)",
    )
    parser.add_argument(
        "--window",
        type=int,
        metavar="N",
        help="moving-average window (default: 100 episodes, or 10 generations)",
    )
    parser.add_argument("--title", metavar="TEXT", help="figure title (default: the run or agents)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from cartpole.cli.errors import UsageError
    from cartpole.plotting import PlotError, expand_run_paths, plot_runs

    if args.window is not None and args.window < 1:
        raise UsageError(f"--window must be >= 1, got {args.window}")
    paths = expand_run_paths(args.runs)
    out = Path(args.out) if args.out else Path(f"{paths[0].name}.png" if len(paths) == 1 else "plot.png")
    skipped: list[str] = []
    try:
        written = plot_runs(
            paths, out, x_axis=args.x_axis, window=args.window, title=args.title, on_skip=skipped.append
        )
    except PlotError as err:
        raise UsageError(": ".join([str(err), *skipped])) from None
    for problem in skipped:
        print(f"warning: {problem}", file=sys.stderr)
    shown = len(paths) - len(skipped)
    left_out = f", {len(skipped)} unreadable left out" if skipped else ""
    print(f"wrote {written} ({shown} run{'s' * (shown > 1)}{left_out})")
    return 0
