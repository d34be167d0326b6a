"""What machine a benchmark ran on: its CPU model, whether it has AVX-512 (NumPy's and torch's float
kernels, and so their speed and last bits, differ by it), its cores and load; and pinning a process to
one CPU. Imported by the scripts beside it."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from typing import Any


def cpu_model_and_avx512() -> tuple[str, bool]:
    """The CPU's model name and whether it has AVX-512, from /proc/cpuinfo where there is one."""
    model, avx512 = platform.processor() or platform.machine(), False
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as handle:
            for line in handle:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    avx512 = "avx512f" in line.split()
    except OSError:
        pass
    return model, avx512


def describe_cpu() -> str:
    """``model name, N CPUs, AVX-512: yes|no``."""
    model, avx512 = cpu_model_and_avx512()
    return f"{model}, {os.cpu_count()} CPUs, AVX-512: {'yes' if avx512 else 'no'}"


def load_average() -> float | None:
    """The 1-minute load average (processes running or waiting for a CPU); None where unknown."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def package_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def machine() -> dict[str, Any]:
    """The machine and software a table was measured on, as plain data (a table's JSON keeps it)."""
    model, avx512 = cpu_model_and_avx512()
    return {
        "cpu": model,
        "avx512": avx512,
        "cpus": os.cpu_count(),
        "load_average": load_average(),
        "python": platform.python_version(),
        "packages": {name: package_version(name) for name in ("torch", "numpy", "numba", "gymnasium")},
    }


def pin_to_one_cpu(cpu: int | None) -> int | None:
    """Pin this process to ``cpu`` (default: the first it may use); None where unsupported."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    allowed = sorted(os.sched_getaffinity(0))
    chosen = allowed[0] if cpu is None else cpu
    os.sched_setaffinity(0, {chosen})
    return chosen
