"""scripts/system_packages.sh installs missing system packages (apt-get as root, sudo otherwise) or names them;
constraints.txt pins what install.sh installs. System commands are replaced by fakes: nothing is installed."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "system_packages.sh"
PACKAGES = ["libosmesa6", "libusb-1.0-0", "iproute2", "util-linux"]

FAKES = {
    # installed packages are listed in $FAKE_INSTALLED
    "dpkg-query": 'for p in $FAKE_INSTALLED; do [ "$p" = "${@: -1}" ] && { echo -n "install ok installed"; exit 0; }; '
                  'done; exit 1',
    "id": 'echo "$FAKE_UID"',
    "apt-get": 'echo "apt-get $*" >>"$FAKE_LOG"; exit "${FAKE_APT_STATUS:-0}"',
    "sudo": 'echo "sudo" >>"$FAKE_LOG"; exec "$@"',
}


def _run(tmp_path: Path, installed: list[str], uid: int, sudo: bool = True, apt_status: int = 0
         ) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Run system_packages.sh with fake dpkg-query/id/apt-get/sudo; returns the result and the logged calls."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, body in FAKES.items():
        if name == "sudo" and not sudo:
            continue
        (bin_dir / name).write_text(f"#!/bin/bash\n{body}\n")
        (bin_dir / name).chmod(0o755)
    for tool in ("grep", "env"):  # the only other programs the script runs; PATH holds nothing else
        (bin_dir / tool).symlink_to(shutil.which(tool))
    log = tmp_path / "calls.log"
    log.touch()
    env = {"PATH": str(bin_dir), "FAKE_INSTALLED": " ".join(installed), "FAKE_UID": str(uid),
           "FAKE_LOG": str(log), "FAKE_APT_STATUS": str(apt_status), "HOME": str(tmp_path)}
    result = subprocess.run(["/bin/bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=60)
    return result, log.read_text().splitlines()


def test_nothing_is_installed_when_the_packages_are_present(tmp_path: Path) -> None:
    result, calls = _run(tmp_path, PACKAGES, uid=1000, sudo=False)
    assert result.returncode == 0, result.stderr
    assert calls == []


def test_root_installs_only_the_missing_packages_with_apt_get(tmp_path: Path) -> None:
    result, calls = _run(tmp_path, PACKAGES[1:], uid=0)
    assert result.returncode == 0, result.stderr
    assert calls[0] == "apt-get update -qq"
    assert calls[1] == "apt-get install -y -qq --no-install-recommends libosmesa6"
    assert len(calls) == 2


def test_a_user_installs_through_sudo(tmp_path: Path) -> None:
    result, calls = _run(tmp_path, [], uid=1000)
    assert result.returncode == 0, result.stderr
    assert calls == ["sudo", "apt-get update -qq", "sudo",
                     "apt-get install -y -qq --no-install-recommends libosmesa6 libusb-1.0-0 iproute2 util-linux"]


@pytest.mark.parametrize(("uid", "sudo", "apt_status", "reason"),
                         [(1000, False, 0, "not root and no sudo"), (0, True, 100, "apt-get update failed")])
def test_when_nothing_can_install_one_message_names_the_packages(
    tmp_path: Path, uid: int, sudo: bool, apt_status: int, reason: str
) -> None:
    result, _ = _run(tmp_path, [], uid=uid, sudo=sudo, apt_status=apt_status)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        f"error: SegGrasp needs the system packages libosmesa6 libusb-1.0-0 iproute2 util-linux: {reason}; install "
        "them as root (apt-get install libosmesa6 libusb-1.0-0 iproute2 util-linux) and run this script again"
    ]


def test_constraints_pin_every_dependency_exactly_and_pyopengl_above_pyrenders_pin() -> None:
    lines = [line for line in (REPO / "constraints.txt").read_text().splitlines() if line and not line.startswith("#")]
    pins = dict(line.split("==") for line in lines)
    assert all(re.fullmatch(r"[A-Za-z0-9_.\-]+==[0-9][0-9A-Za-z.]*", line) for line in lines), lines
    assert pins["torch"] == "2.13.0"
    major, minor, patch = (int(x) for x in pins["PyOpenGL"].split(".")[:3])
    assert (major, minor, patch) >= (3, 1, 7)  # OSMesa needs >= 3.1.7; pyrender itself asks for 3.1.0
    for name in ("pyrender", "trimesh", "gymnasium", "transformers", "numpy", "pytest"):
        assert name in pins, name
    install = (REPO / "scripts" / "install.sh").read_text()
    assert install.count("-c constraints.txt") == 1 and "-c \"$without_pyopengl\"" in install
    assert os.access(REPO / "scripts" / "lock.sh", os.X_OK)
