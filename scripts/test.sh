#!/usr/bin/env bash
# The test command: headless rendering through OSMesa, one torch thread (2-core machines), Hugging Face offline.
#   bash scripts/test.sh             the whole suite (what CI runs)
#   bash scripts/test.sh --fast      the quick loop for a change: leaves out the tests marked slow
#   bash scripts/test.sh ARGS...     any pytest arguments (a file, -k, -x)
set -euo pipefail
cd "$(dirname "$0")/.."
export PYOPENGL_PLATFORM="${PYOPENGL_PLATFORM:-osmesa}"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 HF_HUB_OFFLINE=1 TRANSFORMERS_OFFLINE=1
if [ "${1:-}" = "--fast" ]; then
  shift
  exec python -m pytest -q -m "not slow" "$@"
fi
exec python -m pytest -q "$@"
