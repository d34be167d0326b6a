"""glibc's allocator, told to keep the memory a command frees for its next allocations.

By default glibc hands a large freed block straight back to the kernel (blocks above its mmap
threshold, and free memory at the top of the heap above its trim threshold). Torch frees and
allocates the same large activation and gradient buffers at every step of a convolutional network,
so each step got fresh pages from the kernel and faulted every one of them in again: a pixel run
spent a fifth of its CPU time in the kernel, and next to none with both thresholds raised
(benchmarks/README.md#pixels). The memory is kept, not leaked: a later allocation reuses it.

The thresholds are process-wide, so only the command's entry point sets them (never a library
object): :func:`keep_freed_memory` sets them in this process through ``mallopt`` and, as glibc's
``MALLOC_*_`` variables, for the processes it starts (experiment workers, picture workers), which
read them as they start. Values the user set in the environment win. Elsewhere than glibc (macOS,
musl) it does nothing. Written by hand: PyTorch's own advice for CPU training is to preload
jemalloc or tcmalloc, which a ``pip install`` cannot do.
"""

from __future__ import annotations

import ctypes
import os
import platform

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""``mallopt`` parameters (glibc's malloc.h)."""

THRESHOLDS = {M_MMAP_THRESHOLD: 256 * 2**20, M_TRIM_THRESHOLD: 2**30}
"""Blocks up to 256 MiB come from the heap (reused once freed), and up to 1 GiB of free memory at the
heap's top stays with the process."""
VARIABLES = {M_MMAP_THRESHOLD: "MALLOC_MMAP_THRESHOLD_", M_TRIM_THRESHOLD: "MALLOC_TRIM_THRESHOLD_"}


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds here and for child processes (see the module's
    docstring); whether this process's allocator took them (False: not glibc)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    mallopt = ctypes.CDLL(None).mallopt
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    taken = True
    for parameter, value in THRESHOLDS.items():
        if VARIABLES[parameter] in os.environ:  # the user's: glibc read it as this process started
            continue
        os.environ[VARIABLES[parameter]] = str(value)  # read by the processes this one starts
        taken = bool(mallopt(parameter, value)) and taken
    return taken


__all__ = ["keep_freed_memory"]
