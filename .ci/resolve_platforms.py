"""Does requirements.lock install from the public index on every Python and system the README names?

    python .ci/resolve_platforms.py                 the twelve (Python, system) pairs; exit 1 naming each
                                                    pair that fails and the package that stops it
    python .ci/resolve_platforms.py --lock FILE     check another lock (a candidate, or a broken one)

For each pair, uv resolves cartpole with every extra (the core, `test` and all it pulls in, `bench`)
under the lock's pins as constraints, for that interpreter and platform, with binary wheels only
(`--only-binary :all:`: a user's machine needs no compiler) and against the public index alone: uv
reads no configuration (`--no-config`, and no UV_* index or find-links variables), so no local wheel
folder of this machine can stand in for a wheel the index lacks. The lock is universal
(`scripts/lock.sh`), so one file serves all twelve: a pin with no wheel for one pair fails that pair.
A requirement that pyproject.toml marks for some Pythons only is left out by its marker elsewhere: Box2D
(the `box2d` extra) has no wheel for 3.14, so there `python_version < '3.14'` skips it and every extra
still resolves without it.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYTHONS = ("3.11", "3.12", "3.13", "3.14")


@dataclass(frozen=True)
class System:
    name: str
    platform: str  # uv's --python-platform
    env: tuple[tuple[str, str], ...] = ()


SYSTEMS = (
    System("Linux x86-64 (glibc 2.28+)", "x86_64-manylinux_2_28"),
    System("macOS 14 arm64", "aarch64-apple-darwin", (("MACOSX_DEPLOYMENT_TARGET", "14.0"),)),
    System("Windows x86-64", "x86_64-pc-windows-msvc"),
)

# Settings that could point uv at another index or a wheel folder: never inherited.
UV_SOURCES = ("UV_INDEX", "UV_INDEX_URL", "UV_DEFAULT_INDEX", "UV_EXTRA_INDEX_URL", "UV_FIND_LINKS")


@dataclass(frozen=True)
class Outcome:
    python: str
    system: System
    ok: bool
    seconds: float
    message: str

    @property
    def pair(self) -> str:
        return f"CPython {self.python} on {self.system.name}"


def resolve(lock: Path, python: str, system: System) -> Outcome:
    env = {k: v for k, v in os.environ.items() if k not in UV_SOURCES} | dict(system.env)
    command = [
        *uv(),
        "pip",
        "compile",
        str(ROOT / "pyproject.toml"),
        "--all-extras",
        "--constraint",
        str(lock),
        "--python-version",
        python,
        "--python-platform",
        system.platform,
        "--only-binary",
        ":all:",
        "--no-config",
        "--quiet",
        "--output-file",
        os.devnull,
    ]
    start = time.monotonic()
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    return Outcome(python, system, done.returncode == 0, time.monotonic() - start, done.stderr.strip())


def uv() -> list[str]:
    """uv as the test extra installs it (its Python module finds the binary)."""
    return [sys.executable, "-m", "uv"]


def culprit(message: str) -> str:
    """The package uv's message blames: the first `name==version` that has no usable wheel."""
    found = re.search(r"Because (\S+?)(?:\{[^}]*\})?==(\S+) has no", message)
    if found:
        return f"{found.group(1)}=={found.group(2)}"
    found = re.search(r"(\S+==\S+)", message)
    return found.group(1) if found else "see uv's message"


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lock", type=Path, default=ROOT / "requirements.lock")
    args = parser.parse_args()
    pairs = [(python, system) for python in PYTHONS for system in SYSTEMS]
    with ThreadPoolExecutor(max_workers=len(pairs)) as pool:
        outcomes = list(pool.map(lambda pair: resolve(args.lock, *pair), pairs))
    for outcome in outcomes:
        verdict = "resolves" if outcome.ok else f"FAILS on {culprit(outcome.message)}"
        print(f"  {outcome.pair:<44} {verdict} ({outcome.seconds:.1f} s)")
    failed = [outcome for outcome in outcomes if not outcome.ok]
    for outcome in failed:
        print(f"\n{args.lock.name} does not install on {outcome.pair} ({culprit(outcome.message)}):")
        print("\n".join(f"    {line}" for line in outcome.message.splitlines()))
    if failed:
        print(f"\n{len(failed)} of {len(pairs)} pairs fail: re-lock (bash scripts/lock.sh) or change the pin")
        return 1
    print(f"{args.lock.name}: every pin has a wheel on all {len(pairs)} pairs (binary wheels, public index)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
