"""What CPU a benchmark ran on: its model name, and whether it has AVX-512 (NumPy's and torch's float
kernels, and so their speed and last bits, differ by it); and pinning a process to one CPU. Imported by
the scripts beside it."""

from __future__ import annotations

import os
import platform


def describe_cpu() -> str:
    """``model name, N CPUs, AVX-512: yes|no``, from /proc/cpuinfo where there is one."""
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
    return f"{model}, {os.cpu_count()} CPUs, AVX-512: {'yes' if avx512 else 'no'}"


def pin_to_one_cpu(cpu: int | None) -> int | None:
    """Pin this process to ``cpu`` (default: the first it may use); None where unsupported."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    allowed = sorted(os.sched_getaffinity(0))
    chosen = allowed[0] if cpu is None else cpu
    os.sched_setaffinity(0, {chosen})
    return chosen
