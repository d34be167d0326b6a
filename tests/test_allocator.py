"""The command keeps the memory it frees (glibc's thresholds, cartpole.cli.allocator): large blocks
freed and allocated again come back without the kernel faulting their pages in again."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from cartpole.cli.main import main

pytestmark = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc's allocator"
)

VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")

ALLOCATE_AND_FREE = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from cartpole.cli.allocator import keep_freed_memory
    assert keep_freed_memory()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):  # as a network's step: the same few buffers, allocated, used and freed
    blocks = [np.ones(2**19) for _ in range(4)]  # 4 MiB each
    del blocks
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def page_faults(mode: str) -> int:
    environment = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    result = subprocess.run(
        [sys.executable, "-c", ALLOCATE_AND_FREE, mode],
        capture_output=True,
        text=True,
        check=True,
        env=environment,
    )
    return int(result.stdout.split()[-1])


def test_freed_blocks_are_reused_without_faulting_their_pages_in_again():
    pages = 16 * 2**20 // os.sysconf("SC_PAGE_SIZE")  # of one step's blocks
    assert page_faults("default") > 5 * pages  # the blocks' pages faulted in afresh, step after step
    assert page_faults("keep") < 3 * pages  # the first step's, then the same memory again


def test_the_command_sets_the_thresholds_for_the_processes_it_starts(monkeypatch, capsys):
    for variable in VARIABLES:
        monkeypatch.setenv(variable, "1")  # so that the test's end removes what main sets
        monkeypatch.delenv(variable)
    assert main(["presets"]) == 0
    assert os.environ["MALLOC_MMAP_THRESHOLD_"] == str(256 * 2**20)
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == str(2**30)


def test_thresholds_the_user_set_win(monkeypatch, capsys):
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "12345")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "1")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_")
    assert main(["presets"]) == 0
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "12345"
