"""``cartpole export``: a saved agent's greedy policy as ONNX, or a folder to publish on a model hub."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "export",
        help="export a saved agent as ONNX, or as a model hub folder",
        description=(
            "Write the greedy policy of a saved agent (a run folder: its best checkpoint; or a checkpoint "
            ".pt file) as an ONNX graph, observation standardization included, then check with "
            "onnxruntime that it acts as ours on 10,000 observations played on the env. With --hub, "
            "write a folder to publish on the Hugging Face hub instead: a model card with the verdict, "
            "the checkpoint, config.json, eval.json, model.onnx and a replay video (with the video "
            "extra); `cartpole eval DIR` and cartpole.load_policy(DIR) read it back. Needs the export "
            'extra: pip install -e ".[export]".'
        ),
    )
    parser.add_argument("path", metavar="RUN", help="run folder (or checkpoint file, without --hub)")
    parser.add_argument("--format", choices=["onnx"], default="onnx", help="onnx (the only one, default)")
    parser.add_argument("--out", metavar="FILE", help="the ONNX file to write (default: ./<run name>.onnx)")
    parser.add_argument(
        "--hub",
        metavar="DIR",
        help="write a model hub folder at DIR (new, or empty) instead: model card, weights, ONNX, video",
    )
    parser.set_defaults(run=run)


def default_onnx_path(checkpoint: Path, given: Path) -> Path:
    """``<run name>.onnx`` in the current folder for a run folder (``<run name>-<checkpoint>.onnx``
    for one of its checkpoint files; ``<file name>.onnx`` for another file): run folders are only
    read."""
    if given.is_dir():
        return Path(f"{given.resolve().name}.onnx")
    if checkpoint.parent.name == "checkpoints" and (checkpoint.parent.parent / "config.json").is_file():
        return Path(f"{checkpoint.parent.parent.resolve().name}-{checkpoint.stem}.onnx")
    return Path(f"{checkpoint.stem}.onnx")


def run(args: argparse.Namespace) -> int:
    from cartpole.agents.registry import open_policy
    from cartpole.cli.errors import UsageError
    from cartpole.cli.record import tell_skipped
    from cartpole.export import check_parity, play_observations, require_export_extra, write_onnx
    from cartpole.export.hub import UPLOAD_COMMAND, write_hub_folder

    if args.hub is not None and args.out is not None:
        raise UsageError(
            "--out is the file of a plain export; with --hub the graph is DIR/model.onnx: drop --out"
        )
    if args.out is not None and Path(args.out).suffix.lower() != ".onnx":
        raise UsageError(f"--out {args.out}: name an .onnx file")
    require_export_extra()
    if args.hub is not None:
        hub = write_hub_folder(args.path, args.hub)
        opened, onnx_file = open_policy(hub.path), hub.onnx
        files = [hub.checkpoint.name, "config.json", "eval.json", onnx_file.name]
        print(f"wrote {hub.path}: a model card, {', '.join(files + ([hub.video.name] if hub.video else []))}")
        if hub.video is None:
            print('no replay video: the video extra is not installed (pip install -e ".[video]")')
    else:
        opened = open_policy(args.path)
        tell_skipped(opened.skipped, opened.path)
        onnx_file = write_onnx(
            opened, Path(args.out) if args.out else default_onnx_path(opened.path, Path(args.path))
        )
        agent = f"{opened.checkpoint.agent} on {opened.env.label}"
        print(f"wrote {onnx_file}: the greedy policy of {opened.path} ({agent})")
    parity = check_parity(opened, onnx_file, play_observations(opened.policy, opened.env))
    print(parity.summary())
    if args.hub is not None:
        print(f"publish it with: {UPLOAD_COMMAND.format(folder=args.hub)}")
    return 0 if parity.equal else 1
