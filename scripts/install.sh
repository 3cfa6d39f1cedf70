#!/usr/bin/env bash
# Install SegGrasp into the current Python 3.11 environment: the system libraries it needs (Debian/Ubuntu, when
# missing), then the package with its Python dependencies at the versions CI passed with (constraints.txt).
#   libosmesa6    OSMesa, the software OpenGL that renders the views headless (seggrasp/gl.py)
#   libusb-1.0-0  USB access for pyrealsense2 (the real cell's cameras)
# SEGGRASP_UNPINNED=1 skips constraints.txt (scripts/lock.sh uses it to try the newest releases).
set -euo pipefail
cd "$(dirname "$0")/.."

SYSTEM_PACKAGES=(libosmesa6 libusb-1.0-0)

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "ok installed"; }

install_system_packages() {
  if ! command -v dpkg-query >/dev/null; then
    echo "install.sh: not a Debian-based system; make sure these libraries are installed: ${SYSTEM_PACKAGES[*]}" >&2
    return 0
  fi
  local missing=() package
  for package in "${SYSTEM_PACKAGES[@]}"; do installed "$package" || missing+=("$package"); done
  [ ${#missing[@]} -eq 0 ] && return 0
  local as_root=()
  if [ "$(id -u)" -ne 0 ]; then
    if ! command -v sudo >/dev/null; then
      echo "error: SegGrasp needs the system packages ${missing[*]}; install them as root" \
           "(apt-get install ${missing[*]}) and run this script again" >&2
      return 1
    fi
    as_root=(sudo)
  fi
  echo "install.sh: installing system packages ${missing[*]}"
  if ! { "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq \
         && "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
              "${missing[@]}" >/dev/null; }; then
    echo "error: could not install the system packages ${missing[*]}; install them as root" \
         "(apt-get install ${missing[*]}) and run this script again" >&2
    return 1
  fi
}

install_system_packages

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
