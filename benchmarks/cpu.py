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


AVX2_SETTINGS = {
    "NUMBA_CPU_NAME": "haswell",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "AVX2",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
}
"""The settings under which an AVX-512 CPU runs the float code of an AVX2 one: numba compiles for
Haswell, torch takes its AVX2 kernels, MKL its AVX2 path and NumPy's own loops dispatch to AVX2
(X86_V3) at most (docs/DEVELOPMENT.md). What none of them reaches stays the host's: the CPU's
caches, its clock, and any library outside these four."""


def numpy_simd() -> str:
    """The widest SIMD target that NumPy's own loops dispatch to in this process (``X86_V4``: AVX-512,
    ``X86_V3``: AVX2, ...), from ``numpy.lib.introspect.opt_func_info``."""
    from numpy.lib.introspect import opt_func_info

    targets = {
        signature["current"].split("(")[-1].rstrip(")")
        for signatures in opt_func_info().values()
        for signature in signatures.values()
    }
    for target in ("X86_V4", "X86_V3", "X86_V2"):
        if any(t == target or (target == "X86_V4" and t.startswith("AVX512")) for t in targets):
            return target
    return ", ".join(sorted(targets)) or "baseline"


def float_path_settings() -> dict[str, str]:
    """Those of :data:`AVX2_SETTINGS`' variables that this process has set, with their values."""
    return {name: os.environ[name] for name in AVX2_SETTINGS if os.environ.get(name)}


def emulated_isa(avx512: bool) -> str | None:
    """``AVX2`` where an AVX-512 CPU runs with all of :data:`AVX2_SETTINGS` and NumPy's loops took
    them (a table made so is an emulated AVX2 one, and says so); None on a CPU measured as it is."""
    settings = float_path_settings()
    if avx512 and all(
        settings.get(name, "").lower() == value.lower() for name, value in AVX2_SETTINGS.items()
    ):
        return "AVX2" if numpy_simd() != "X86_V4" else None
    return None


def describe_cpu() -> str:
    """``model name, N CPUs, AVX-512: yes|no``, or ``..., emulated AVX2 on an AVX-512 CPU``."""
    model, avx512 = cpu_model_and_avx512()
    emulated = emulated_isa(avx512)
    isa = f"AVX-512: {'yes' if avx512 else 'no'}"
    if emulated:
        isa = f"emulated {emulated} on an AVX-512 CPU (numba, torch, MKL and NumPy kernels)"
    return f"{model}, {os.cpu_count()} CPUs, {isa}"


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
        "emulated": emulated_isa(avx512),
        "float_paths": float_path_settings(),
        "numpy_simd": numpy_simd(),
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
