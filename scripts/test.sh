#!/usr/bin/env bash
# The test command: headless rendering through OSMesa, one torch thread (2-core machines), Hugging Face offline.
#   bash scripts/test.sh             the whole suite (what CI runs)
#   bash scripts/test.sh --fast      the quick loop for a change: leaves out the tests marked slow
#   bash scripts/test.sh ARGS...     any pytest arguments (a file, -k, -x; -n 1 for one process)
# Two processes (pytest-xdist), each test file in one of them: most tests run one thread, and the emulated cell's
# tests wait on its wall clock, so a second process roughly halves the suite's time on a 2-core machine.
set -euo pipefail
cd "$(dirname "$0")/.."
export PYOPENGL_PLATFORM="${PYOPENGL_PLATFORM:-osmesa}"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 HF_HUB_OFFLINE=1 TRANSFORMERS_OFFLINE=1
if [ "${1:-}" = "--fast" ]; then
  shift
  exec python -m pytest -q -n 2 --dist loadfile -m "not slow" "$@"
fi
exec python -m pytest -q -n 2 --dist loadfile "$@"
