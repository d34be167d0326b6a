#!/usr/bin/env bash
# Regenerate requirements.lock: every dependency of cartpole and of all its extras (test, bench, postgres,
# video, tensorboard, notebook), pinned, in ONE universal resolution: every CPython from 3.11 up on Linux,
# macOS and Windows, with environment markers where a platform needs a package of its own (colorama on
# Windows, the CUDA packages of Linux's torch) or a Python goes without one (box2d, no wheel for 3.14).
# One version of each package for every Python and system (uv's fewest-forks strategy), public versions
# only: no local labels such as +cpu, so the lock installs from the public index anywhere.
# `.ci/resolve_platforms.py` checks that it does, with wheels alone.
#
#   bash scripts/lock.sh              keep today's pins where pyproject.toml still allows them
#   bash scripts/lock.sh --upgrade    move every pin to the newest allowed release
#   bash scripts/lock.sh --upgrade-package NAME   move one pin
#
# Needs uv (in the test extra). It resolves against the public index only: pip's settings (a local wheel
# folder, say) are never read, so what it writes is what anyone can install.
set -euo pipefail
cd "$(dirname "$0")/.."

TORCH="torch==2.13.0"  # the tested release; where pip is pointed at PyTorch's CPU wheels it takes 2.13.0+cpu
tmp=requirements.lock.tmp
trap 'rm -f "$tmp"' EXIT
# uv keeps the pins of the output file it is given where it can: start from today's lock.
[ -e requirements.lock ] && cp requirements.lock "$tmp"
uv pip compile pyproject.toml --all-extras --universal --fork-strategy fewest --python-version 3.11 \
  --constraint <(echo "$TORCH") --no-config --no-header --quiet "$@" --output-file "$tmp"
{
  echo "# The tested environment: every dependency of cartpole and its extras, pinned, for CPython >= 3.11 (CI"
  echo "# resolves it for 3.11-3.14) on Linux, macOS and Windows (environment markers where a platform needs its"
  echo "# own package, or a Python goes without one: box2d, which has no wheel for 3.14)."
  echo "# Made by: bash scripts/lock.sh   (do not edit by hand). Install with: pip install -c requirements.lock -e \".[test]\""
  sed 's|^    #   -c /dev/fd/[0-9]*$|    #   -c scripts/lock.sh (the tested torch)|' "$tmp" | grep -v '^#'
} > requirements.lock
echo "wrote requirements.lock ($(grep -c '==' requirements.lock) pins)"
