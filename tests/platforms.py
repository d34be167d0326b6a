"""Skip markers for tests that need what only some operating systems have, each with its reason.

cartpole runs on Linux, macOS and Windows; some tests drive what POSIX alone has (signals sent to a
process, kill -9, sessions and process groups) or what Linux alone has (/proc). There they run as
written; elsewhere they are skipped, saying what they need, instead of failing on a missing name.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest


def posix_only(needs: str) -> pytest.MarkDecorator:
    """Skip the test on Windows, which lacks ``needs``."""
    return pytest.mark.skipif(sys.platform == "win32", reason=f"{needs}: POSIX only")


kill_9 = posix_only("kills a process with SIGKILL (kill -9; Windows has no SIGKILL)")
sigstop = posix_only("freezes a process with SIGSTOP")
stop_signal_to_a_process = posix_only(
    "stops a process with SIGINT or SIGTERM (Windows sends neither to another process: os.kill and "
    "Popen.send_signal end it with TerminateProcess, or refuse SIGINT)"
)
sessions = posix_only(
    "uses sessions and process groups (os.getsid, os.getpgid, os.killpg, start_new_session)"
)
proc = pytest.mark.skipif(
    not Path("/proc/self/stat").exists(), reason="reads processes from /proc: Linux only"
)
