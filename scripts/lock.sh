#!/usr/bin/env bash
# Upgrade constraints.txt: install SegGrasp with the newest allowed releases into a fresh virtual environment, run
# the whole test suite there, and only if it passes rewrite constraints.txt with that environment's exact versions.
# Usage: bash scripts/lock.sh [PYTHON]   (PYTHON: a Python 3.11 interpreter, default python3.11 or python)
set -euo pipefail
cd "$(dirname "$0")/.."

python=${1:-$(command -v python3.11 || command -v python)}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$python" -m venv "$work/venv"
# shellcheck disable=SC1091
source "$work/venv/bin/activate"
SEGGRASP_UNPINNED=1 bash scripts/install.sh
bash scripts/test.sh
{
  sed -n '/^#/p' constraints.txt  # keep the header
  # exact versions, without local labels (torch 2.13.0+cpu -> 2.13.0, which also matches the CUDA wheel elsewhere)
  python -m pip freeze --exclude-editable | grep -v '^#' | sed 's/+[^ ]*$//' | LC_ALL=C sort -f
} >"$work/constraints.txt"
mv "$work/constraints.txt" constraints.txt
echo "constraints.txt: $(grep -vc '^#' constraints.txt) packages pinned; review with git diff and commit"
