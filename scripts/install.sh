#!/usr/bin/env bash
# Install SegGrasp and its Python dependencies into the current Python 3.11 environment.
# Two pip steps on purpose: pyrender pins PyOpenGL 3.1.0, which breaks headless OSMesa rendering;
# asking for both in one resolve makes pip backtrack to ancient releases.
set -euo pipefail
cd "$(dirname "$0")/.."
# torch==2.13.0 (CPU) is taken from a local wheel folder when the machine has one.
extra=()
[ -d /opt/wheels ] && extra=(--find-links /opt/wheels)
python -m pip install -q --disable-pip-version-check "${extra[@]}" -e ".[dev]"
python -m pip install -q --disable-pip-version-check "PyOpenGL>=3.1.7"
