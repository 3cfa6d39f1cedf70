#!/usr/bin/env bash
# Install the Debian/Ubuntu packages SegGrasp needs when they are missing: apt-get as root, through sudo otherwise;
# when neither works, one message naming the packages and exit code 1.
#   libosmesa6    OSMesa, the software OpenGL that renders the views headless (seggrasp/gl.py)
#   libusb-1.0-0  USB access for pyrealsense2 (the real cell's cameras)
#   iproute2      `ip`, to bring up loopback in the emulated lab cell's private network namespace (sim/lab)
#   util-linux    `unshare`, which makes that namespace
set -euo pipefail

packages=(libosmesa6 libusb-1.0-0 iproute2 util-linux)

if ! command -v dpkg-query >/dev/null; then
  echo "system_packages.sh: not a Debian-based system; make sure these libraries are installed: ${packages[*]}" >&2
  exit 0
fi
missing=()
for package in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "ok installed" || missing+=("$package")
done
[ ${#missing[@]} -eq 0 ] && exit 0

fail() {
  echo "error: SegGrasp needs the system packages ${missing[*]}: $1; install them as root" \
       "(apt-get install ${missing[*]}) and run this script again" >&2
  exit 1
}
as_root=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || fail "not root and no sudo"
  as_root=(sudo)
fi
echo "system_packages.sh: installing ${missing[*]}"
apt_get=("${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get)
"${apt_get[@]}" update -qq || fail "apt-get update failed"
"${apt_get[@]}" install -y -qq --no-install-recommends "${missing[@]}" >/dev/null || fail "apt-get install failed"
