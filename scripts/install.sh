#!/usr/bin/env bash
# Install SegGrasp into the current Python 3.11 environment: the system libraries it needs (Debian/Ubuntu, when
# missing: scripts/system_packages.sh), then the package with its Python dependencies at the versions CI passed
# with (constraints.txt).
# SEGGRASP_UNPINNED=1 skips constraints.txt (scripts/lock.sh uses it to try the newest releases).
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/system_packages.sh

pip_install() { python -m pip install -q --disable-pip-version-check "$@"; }
# torch==2.13.0 (CPU) is taken from a local wheel folder when the machine has one.
extra=()
[ -d /opt/wheels ] && extra=(--find-links /opt/wheels)
# Two pip steps on purpose: pyrender pins PyOpenGL 3.1.0, which breaks headless OSMesa rendering; asking for both
# in one resolve makes pip backtrack to ancient releases. So the first step's constraints leave PyOpenGL out.
if [ "${SEGGRASP_UNPINNED:-0}" = 1 ]; then
  pip_install "${extra[@]}" -e ".[dev]"
  pip_install "PyOpenGL>=3.1.7"
else
  without_pyopengl=$(mktemp)
  trap 'rm -f "$without_pyopengl"' EXIT
  grep -iv '^pyopengl==' constraints.txt >"$without_pyopengl"
  pip_install "${extra[@]}" -c "$without_pyopengl" -e ".[dev]"
  pip_install -c constraints.txt "PyOpenGL>=3.1.7"
fi
echo "install.sh: done. pip's 'ERROR ... pyrender 0.1.45 requires PyOpenGL==3.1.0' above is expected: PyOpenGL" \
     ">= 3.1.7 is installed on purpose (3.1.0 cannot render through OSMesa)."
