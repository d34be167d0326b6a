"""Is requirements.lock what this environment and pyproject.toml need?

    python .ci/check_lock.py          exit 1 if the lock is stale: a requirement of pyproject.toml (any
                                      extra) that no pin satisfies, or an installed package that the lock
                                      does not pin at that version (pip took it from outside the lock)
    python .ci/check_lock.py --diff   only list the installed packages whose versions differ from the lock
                                      (the newest-versions check); always exits 0

Run it with the environment's own python (it reads that environment's installed distributions).
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
PROJECT = "cartpole"
NOT_PINNED = {"pip", "setuptools", "wheel"}  # the venv's own tools


def read_lock(path: Path) -> dict[str, Version]:
    """The lock's pins for this environment: a pin whose marker is false here (colorama on Linux, the CUDA
    packages elsewhere) is left out."""
    pins = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            pin = Requirement(line)
            if pin.marker is None or pin.marker.evaluate():
                pins[canonicalize_name(pin.name)] = Version(str(pin.specifier).removeprefix("=="))
    return pins


def matches(installed: Version, pin: Version) -> bool:
    """An installed build matches its pin, a local build (torch's 2.13.0+cpu) a public pin (2.13.0)."""
    return installed == pin or (not pin.local and Version(installed.public) == pin)


def project_requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project.get("optional-dependencies", {})
    texts = project["dependencies"] + [text for group in extras.values() for text in group]
    return [Requirement(text) for text in texts if canonicalize_name(Requirement(text).name) != PROJECT]


def unmet_requirements(pins: dict[str, Version]) -> list[str]:
    """Requirements of pyproject.toml that no pin satisfies; one whose marker is false here (box2d on a
    Python it has no wheel for) asks for nothing."""
    problems = []
    for req in project_requirements():
        if req.marker is not None and not req.marker.evaluate():
            continue
        pin = pins.get(canonicalize_name(req.name))
        if pin is None:
            problems.append(f"{req} is not in the lock")
        elif not req.specifier.contains(pin, prereleases=True):
            problems.append(f"{req} but the lock pins {pin}")
    return problems


def installed() -> dict[str, Version]:
    found = {}
    for dist in metadata.distributions():
        name = canonicalize_name(dist.metadata["Name"])
        if name not in NOT_PINNED and name != PROJECT:
            found[name] = Version(dist.version)
    return found


def differences(pins: dict[str, Version]) -> list[str]:
    return [
        f"{name} {version} (lock: {pins[name]})" if name in pins else f"{name} {version} (not in the lock)"
        for name, version in sorted(installed().items())
        if name not in pins or not matches(version, pins[name])
    ]


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lock", type=Path, default=ROOT / "requirements.lock")
    parser.add_argument("--diff", action="store_true", help="list the differences from the lock, exit 0")
    args = parser.parse_args()
    pins = read_lock(args.lock)
    diff = differences(pins)
    if args.diff:
        print(f"{len(diff)} installed package(s) differ from {args.lock.name}:")
        print("\n".join(f"  {line}" for line in diff) or "  none")
        return 0
    problems = unmet_requirements(pins) + [f"installed {line}" for line in diff]
    if problems:
        print(f"{args.lock.name} is stale against pyproject.toml; refresh it with: bash scripts/lock.sh")
        print("\n".join(f"  {line}" for line in problems))
        return 1
    print(f"{args.lock.name}: {len(pins)} pins; every requirement met, every installed package pinned")
    return 0


if __name__ == "__main__":
    sys.exit(main())
