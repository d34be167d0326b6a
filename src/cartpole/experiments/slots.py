"""Worker slots: where each worker process of a comparison or a sweep trains.

A slot runs one worker process at a time: a CPU slot trains on the CPU, a GPU slot on one GPU of its
own, the process seeing only that GPU (``CUDA_VISIBLE_DEVICES``: slot i gets the i-th GPU this process
sees). ``cartpole compare --jobs J`` and ``cartpole sweep --workers J`` count CPU slots, ``--gpus N|all``
GPU slots, and ``--device cpu|cuda|auto`` says which kinds there are (:func:`allocate_slots`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field

from cartpole.experiments.entries import ExperimentError

CUDA_VISIBLE = "CUDA_VISIBLE_DEVICES"
DEVICES = ("cpu", "cuda", "auto")
ALL = "all"


@dataclass(frozen=True)
class Slot:
    """A place for one worker process: its torch device and the environment it starts with."""

    device: str = "cpu"
    """``cpu`` or ``cuda``."""
    environment: dict[str, str] = field(default_factory=dict)
    """Variables set for the worker (a GPU slot's ``CUDA_VISIBLE_DEVICES``)."""

    @property
    def arguments(self) -> list[str]:
        """What a worker's command line ends with: ``--device DEVICE``."""
        return ["--device", self.device]

    def __str__(self) -> str:
        gpu = self.environment.get(CUDA_VISIBLE)
        return self.device if gpu is None else f"{self.device} (GPU {gpu})"


CPU = Slot()


def gpu_slot(gpu: str) -> Slot:
    """A slot on the GPU that ``CUDA_VISIBLE_DEVICES`` names ``gpu``."""
    return Slot("cuda", {CUDA_VISIBLE: gpu})


def visible_gpus(environ: Mapping[str, str] = os.environ) -> list[str]:
    """The GPUs torch sees here, as ``CUDA_VISIBLE_DEVICES`` values (that variable's own entries where
    it is set, so a slot's GPU is one this process was given)."""
    import torch

    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    given = environ.get(CUDA_VISIBLE)
    if given is None:
        return [str(i) for i in range(count)]
    return [gpu.strip() for gpu in given.split(",") if gpu.strip()][:count]


def parse_gpus(text: str | None) -> int | str | None:
    """``--gpus``: a count >= 0 or ``all``; ExperimentError otherwise."""
    if text is None or text == ALL:
        return text
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise ExperimentError(f"--gpus takes a count or 'all', got {text!r}")
    return count


def allocate_slots(
    device: str | None, cpu_slots: int | None, gpus: str | None, visible: list[str], cpu_flag: str = "--jobs"
) -> list[Slot]:
    """The slots of ``--device``, ``cpu_flag`` (``--jobs``/``--workers``: CPU slots) and ``--gpus``,
    given the GPUs torch sees (``visible``, from :func:`visible_gpus`); ExperimentError, one line, when
    they cannot be had. ``--device`` defaults to ``cuda`` with ``--gpus``, else ``cpu``; ``cuda`` and
    ``auto`` take every visible GPU where ``--gpus`` is not given; ``auto`` adds ``cpu_flag``'s CPU slots
    (one where there is no GPU slot and it is not given), ``cuda`` has none."""
    asked = parse_gpus(gpus)
    device = device or ("cpu" if asked is None else "cuda")
    if device not in DEVICES:
        raise ExperimentError(f"unknown --device {device!r}; use {', '.join(DEVICES)}")
    if cpu_slots is not None and cpu_slots < 1:
        raise ExperimentError(f"{cpu_flag} must be >= 1, got {cpu_slots}")
    if device == "cpu":
        if asked not in (None, 0):
            raise ExperimentError(
                f"--gpus {gpus} trains on GPUs, not with --device cpu; use --device cuda or auto"
            )
        return [CPU] * (cpu_slots or 1)
    count = len(visible) if asked in (None, ALL) else int(asked)
    if count > len(visible):
        raise ExperimentError(
            f"--gpus {count}: torch sees {len(visible)} GPU(s) on this machine; ask for at most "
            f"{len(visible)} (or --gpus all)"
        )
    if device == "cuda" and not visible:
        raise ExperimentError(
            "--device cuda: torch sees no CUDA GPU on this machine; use --device cpu or auto"
        )
    if device == "cuda" and cpu_slots is not None:
        raise ExperimentError(
            f"{cpu_flag} counts CPU slots, and --device cuda trains on GPUs only; use --device auto for both"
        )
    slots = [gpu_slot(gpu) for gpu in visible[:count]]
    if device == "auto":
        slots += [CPU] * (cpu_slots if cpu_slots is not None else (0 if slots else 1))
    if not slots:
        raise ExperimentError("--gpus 0 with --device cuda leaves no slot to train in; ask for a GPU or more")
    return slots


__all__ = [
    "CPU", "CUDA_VISIBLE", "DEVICES", "Slot", "allocate_slots", "gpu_slot", "parse_gpus", "visible_gpus",
]  # fmt: skip
