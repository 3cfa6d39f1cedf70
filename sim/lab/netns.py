"""A private network namespace for one emulated cell: ur_rtde's ports are fixed, so each cell gets its own loopback.

`unshare_command()` finds how this machine can make one (`unshare -n` as root, `unshare -rn` through a user
namespace otherwise, or not at all); `loopback_up()` brings `lo` up inside it (a fresh namespace has it down);
`taken_port()` and `wait_for_port()` serve the fallback on the host's loopback and the start-up wait.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import socket
import struct
import subprocess
import time
from collections.abc import Callable

#: Set in the environment of a process re-executed inside its private namespace.
NETNS_ENV = "SIM_LAB_NETNS"
_SIOCGIFFLAGS, _SIOCSIFFLAGS, _IFF_UP = 0x8913, 0x8914, 0x1
_IFREQ = struct.Struct("16sH22x")


def unshare_command() -> list[str] | None:
    """The command prefix that runs a program in a new network namespace here, or None if none can be made."""
    if shutil.which("unshare") is None:
        return None
    for prefix in (["unshare", "-n"], ["unshare", "-rn"]):
        try:
            probe = subprocess.run([*prefix, "true"], capture_output=True, timeout=10, check=False)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if probe.returncode == 0:
            return prefix
    return None


def in_private_namespace() -> bool:
    """Whether this process was re-executed in its own namespace by `python -m sim.lab run`."""
    return os.environ.get(NETNS_ENV) == "1"


def loopback_up() -> None:
    """Bring the loopback interface up (as `ip link set lo up`)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        _, flags = _IFREQ.unpack(fcntl.ioctl(sock, _SIOCGIFFLAGS, _IFREQ.pack(b"lo", 0)))
        fcntl.ioctl(sock, _SIOCSIFFLAGS, _IFREQ.pack(b"lo", flags | _IFF_UP))


def taken_port(host: str, ports: list[int]) -> int | None:
    """The first of `ports` on `host` that something already listens on or holds, or None."""
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind((host, port))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return port
                raise
    return None


def wait_for_port(host: str, port: int, deadline: float, alive: Callable[[], bool]) -> bool:
    """Wait until `host:port` accepts a connection (True), the deadline (time.monotonic) passes or `alive()` turns
    False (False)."""
    while time.monotonic() < deadline and alive():
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.05)
    return False
