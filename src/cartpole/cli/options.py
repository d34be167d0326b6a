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


def add_slots(parser: argparse.ArgumentParser, cpu_flag: str) -> None:
    """``--device cpu|cuda|auto`` and ``--gpus N|all``: the worker slots beside ``cpu_flag``'s CPU
    slots (:func:`slots_of` reads all three)."""
    parser.add_argument(
        "--device",
        choices=("cpu", "cuda", "auto"),
        help=f"where workers train: cpu ({cpu_flag} slots), cuda (--gpus slots, a GPU each) or auto (both, "
        "GPUs where torch sees any) (default: cuda with --gpus, else cpu); each run's record says its device",
    )
    parser.add_argument(
        "--gpus",
        metavar="N|all",
        help="GPU slots: each trains one population at a time on a GPU of its own (CUDA_VISIBLE_DEVICES); "
        "all: every GPU torch sees (default with --device cuda or auto)",
    )


def slots_of(args: Any, cpu_slots: int | None, cpu_flag: str) -> list[Any]:
    """The worker slots ``--device``, ``--gpus`` and ``cpu_flag`` (``cpu_slots``) ask for; one line,
    exit 2, where this machine cannot give them."""
    from cartpole.experiments.slots import allocate_slots, visible_gpus

    return allocate_slots(args.device, cpu_slots, args.gpus, visible_gpus(), cpu_flag)
