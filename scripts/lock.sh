#!/usr/bin/env bash
# Regenerate requirements.lock: every dependency of cartpole and of all its extras (test, bench, postgres,
# video, tensorboard), pinned, for CPython 3.11 on x86-64 Linux, with PyTorch's CPU build.
#
#   bash scripts/lock.sh              keep today's pins where pyproject.toml still allows them
#   bash scripts/lock.sh --upgrade    move every pin to the newest allowed release
#   bash scripts/lock.sh --upgrade-package NAME   move one pin
#
# Needs uv (pip install uv). PyTorch's CPU wheels are not on PyPI: the script looks for them where pip is
# told to look (PIP_FIND_LINKS, or pip's find-links setting); set TORCH_FIND_LINKS to a folder or index page
# that holds torch-2.13.0+cpu otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."

TORCH="torch==2.13.0+cpu"
links="${TORCH_FIND_LINKS:-${PIP_FIND_LINKS:-$(python -m pip config get global.find-links 2>/dev/null || true)}}"
find_links=()
for link in $links; do find_links+=(--find-links "$link"); done

uv pip compile pyproject.toml --all-extras \
  --python-version 3.11 --python-platform x86_64-manylinux_2_28 \
  --constraint <(echo "$TORCH") "${find_links[@]}" \
  --no-header --quiet "$@" \
  --output-file requirements.lock.tmp
{
  echo "# The tested environment: every dependency of cartpole and its extras, pinned (CPython 3.11, x86-64 Linux)."
  echo "# Made by: bash scripts/lock.sh   (do not edit by hand). Install with: pip install -c requirements.lock -e \".[test]\""
  cat requirements.lock.tmp
} > requirements.lock
rm requirements.lock.tmp
echo "wrote requirements.lock ($(grep -c '==' requirements.lock) pins)"
