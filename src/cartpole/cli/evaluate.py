"""``cartpole eval``: judge a saved agent with Gymnasium's rule."""

from __future__ import annotations

import argparse
import json
from typing import Any

from cartpole.cli.options import add_env_kwargs


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "eval",
        help="evaluate a checkpoint or run folder",
        description=(
            "Play greedy episodes of a saved agent (a checkpoint .pt file, or a run folder: its best "
            "checkpoint) and judge them: solved means mean return >= the env's reward_threshold over "
            ">= 100 episodes. By default on Gymnasium's own env, from fresh seeds never used in training."
        ),
    )
    parser.add_argument("path", metavar="PATH", help="checkpoint file or run folder")
    parser.add_argument("--episodes", type=int, default=100, metavar="N", help="episodes (default: 100)")
    parser.add_argument(
        "--seed",
        type=int,
        metavar="N",
        help="episode i starts from reset(seed=N+i); default: a fresh random seed",
    )
    parser.add_argument(
        "--env",
        metavar="ID",
        help="evaluate on another env id (default: the checkpoint's, with the kwargs and wrappers its run "
        "recorded)",
    )
    add_env_kwargs(parser)
    parser.add_argument(
        "--simulator",
        choices=["gymnasium", "fast"],
        default="gymnasium",
        help="gymnasium (the reference, default) or fast (our simulator)",
    )
    parser.add_argument("--json", action="store_true", help="print the full report as JSON")
    # --render (issue 5): a video of the evaluation's first episodes, made by cartpole.cli.record.
    parser.add_argument(
        "--render",
        nargs="?",
        const="",
        metavar="FILE",
        help="also write a video (.gif, or .mp4 with the video extra) of the first 3 episodes of "
        "this evaluation, from the same seeds (default FILE: ./<run>-<checkpoint>-seed<S>.gif)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cartpole.agents.registry import open_policy
    from cartpole.cli.errors import UsageError
    from cartpole.cli.record import eval_video_path, tell_skipped, write_eval_video
    from cartpole.core.seeding import fresh_eval_seed
    from cartpole.envs import env_info
    from cartpole.evaluation import MAX_EPISODES, evaluate
    from cartpole.training.engine import picture_workers
    from cartpole.training.request import parse_env_kwargs

    if not 1 <= args.episodes <= MAX_EPISODES:
        raise UsageError(
            f"--episodes must be between 1 and {MAX_EPISODES:,} (the report keeps every episode), "
            f"got {args.episodes:,}"
        )
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    opened = open_policy(args.path, env_id=args.env)
    path, checkpoint, policy = opened.path, opened.checkpoint, opened.policy
    tell_skipped(opened.skipped, path)
    env = opened.env
    if args.env or args.env_kwargs:  # another env, or this one changed: as asked, without the run's own
        env = env_info(args.env or checkpoint.env_id, parse_env_kwargs(args.env_kwargs))
    env_id = env.label
    seed = fresh_eval_seed() if args.seed is None else args.seed
    out = None if args.render is None else eval_video_path(path, seed, args.render)  # checked before playing
    report = evaluate(
        policy, env, args.episodes, seed=seed, simulator=args.simulator, workers=picture_workers()
    )
    video: dict[str, str] = {}
    if out is not None:  # --render (issue 5)
        video = {"video": str(write_eval_video(policy, env, seed, report.episodes, out))}
    if args.json:
        print(json.dumps(report.to_dict() | {"checkpoint": str(path)} | video, indent=2))
        return 0
    console = Console(soft_wrap=True)
    summary = Table(title=f"{checkpoint.agent} on {env_id}: {path}", show_header=False)
    rows = [
        ("episodes", f"{report.episodes} (seeds {report.seeds[0]}..{report.seeds[-1]})"),
        ("simulator", report.simulator),
        ("mean ± std", f"{report.mean:.1f} ± {report.std:.1f}"),
        ("min / max", f"{report.min:.0f} / {report.max:.0f}"),
        ("threshold", "none registered" if report.threshold is None else f"{report.threshold:g}"),
    ]
    for key, value in rows:
        summary.add_row(key, value)
    console.print(summary)
    color = "green" if report.solved else "red"
    console.print(f"[bold {color}]{report.verdict}[/]", highlight=False)
    if video:
        console.print(f"video of the first episodes: {video['video']}", highlight=False)
    return 0
