"""Options that several commands take alike."""

from __future__ import annotations

import argparse
from typing import Any


def add_env_kwargs(parser: argparse.ArgumentParser) -> None:
    """``--env-kwargs KEY=VALUE ...``: the env's constructor arguments (``args.env_kwargs``, a list of
    pairs; :func:`cartpole.training.request.parse_env_kwargs` reads them)."""
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="keyword arguments of the env's constructor, as gymnasium.make(ID, **kwargs) passes them, "
        "e.g. --env-kwargs sutton_barto_reward=true (values as --set reads them); for training, "
        "evaluations and the verdict, and recorded in the run folder",
    )


def env_overrides(args: Any) -> dict[str, Any]:
    """The settings ``--env-kwargs`` stands for: ``{"env_kwargs": {...}}``, or none."""
    from cartpole.training.request import parse_env_kwargs

    kwargs = parse_env_kwargs(args.env_kwargs)
    return {"env_kwargs": kwargs} if kwargs else {}
