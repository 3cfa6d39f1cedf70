"""Host process for ONE ur_rtde interface; `hardware.ur.RTDEClient` starts it and calls it over a socket.

Run by path (`python hardware/rtde_host.py control|receive HOST FD TIMEOUT`), so it imports only the standard
library and ur_rtde, never the `hardware` package. It builds the interface, answers `(method, args)` requests with
`("ok", value)` or `("error", exception type, message)`, and exits when its socket closes or its parent dies.
Before building a receive interface it checks, with a deadline and a short RTDE session of its own, that the
controller answers the handshake and streams (`probe`); the controller version read there is served as
`getControllerVersion()`, which ur_rtde knows but its Python binding does not offer.

Why a process of its own: ur_rtde's constructors hold the GIL and can wait for ever (a controller that accepts
RTDE and never streams), and the library can kill its process with SIGSEGV (reconnect races, bridge-audit F1/F2).
Here a hang can be abandoned and a crash is only this process's exit code.
"""

from __future__ import annotations

import os
import signal
import socket
import struct
import sys
import threading
import time
from multiprocessing.connection import Connection
from typing import Any, Callable

#: How often (s) the host checks that its parent is still alive.
_PARENT_CHECK_PERIOD = 0.5


def _exit_when_orphaned(parent: int) -> None:
    """End this process once its parent is gone (a hung ur_rtde call would otherwise keep it alive)."""
    while os.getppid() == parent:
        time.sleep(_PARENT_CHECK_PERIOD)
    os._exit(3)


#: RTDE's port and the package types the probe uses (UR's RTDE guide: protocol version 2).
RTDE_PORT = 30004
_PROTOCOL, _VERSION, _OUTPUTS, _START, _DATA, _MESSAGE = b"V", b"v", b"O", b"S", b"U", b"M"
#: Deadline (s) of the whole probe; a controller answers it in milliseconds.
PROBE_TIMEOUT = 3.0


class ProbeError(ConnectionError):
    """The controller's RTDE server did not answer the probe as RTDE does."""


class _Wire:
    """One RTDE connection of the probe, with one deadline for everything read on it."""

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock, self.deadline = sock, deadline
        self.pending = 0  # bytes read of a package not yet complete

    def send(self, kind: bytes, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), kind[0]) + payload)

    def read(self, size: int, missing: str) -> bytes:
        data = b""
        while len(data) < size:
            remaining = self.deadline - time.monotonic()
            if remaining <= 0:
                got = self.pending + len(data)
                noise = f" (it sent {got} bytes of an incomplete package)" if got else ""
                raise ProbeError(f"{missing} within {PROBE_TIMEOUT:g} s{noise}")
            self.sock.settimeout(remaining)
            try:
                chunk = self.sock.recv(size - len(data))
            except socket.timeout:
                continue
            if not chunk:
                raise ProbeError(f"the controller closed the connection: {missing}")
            data += chunk
        return data

    def expect(self, kind: bytes, missing: str) -> bytes:
        """The payload of the next package of type `kind` (text messages skipped)."""
        while True:
            header = self.read(3, missing)
            size, received = struct.unpack(">HB", header)
            if size < 3:
                raise ProbeError(f"what it sent is not RTDE (a package of {size} bytes): {missing}")
            self.pending = 3
            payload = self.read(size - 3, missing)
            self.pending = 0
            if bytes([received]) == kind:
                return payload
            if bytes([received]) != _MESSAGE:
                raise ProbeError(f"what it sent is not RTDE (package type {received}, expected {kind[0]}): {missing}")


def probe(host: str) -> tuple[int, int, int, int]:
    """The controller version (major, minor, bugfix, build) after checking that RTDE negotiates protocol 2,
    sets up an output recipe, starts and delivers a data package, all within `PROBE_TIMEOUT`."""
    try:
        with socket.create_connection((host, RTDE_PORT), timeout=PROBE_TIMEOUT) as sock:
            wire = _Wire(sock, time.monotonic() + PROBE_TIMEOUT)
            wire.send(_PROTOCOL, struct.pack(">H", 2))
            if wire.expect(_PROTOCOL, "no answer to the protocol request")[:1] != b"\x01":
                raise ProbeError("the controller refused RTDE protocol version 2")
            wire.send(_VERSION)
            payload = wire.expect(_VERSION, "no controller version")
            if len(payload) < 16:
                raise ProbeError(f"the controller version reply has {len(payload)} bytes, not 16")
            version = struct.unpack(">IIII", payload[:16])
            wire.send(_OUTPUTS, struct.pack(">d", 10.0) + b"timestamp")
            if wire.expect(_OUTPUTS, "no answer to the output recipe")[1:] != b"DOUBLE":
                raise ProbeError("the controller did not set up an output recipe with its timestamp")
            wire.send(_START)
            if wire.expect(_START, "no answer to the start request")[:1] != b"\x01":
                raise ProbeError("the controller refused to start the RTDE data stream")
            wire.expect(_DATA, "it answers the RTDE handshake but sent no data package")
    except (ProbeError, OSError) as exc:
        raise ProbeError(f"RTDE at {host}:{RTDE_PORT}: {exc}") from None
    return version


def _build(kind: str, host: str) -> Any:
    if kind == "control":
        import rtde_control

        return rtde_control.RTDEControlInterface(host)
    if kind == "receive":
        import rtde_receive

        return rtde_receive.RTDEReceiveInterface(host)
    raise ValueError(f"unknown ur_rtde interface {kind!r} (expected control or receive)")


def main(argv: list[str]) -> int:
    """Serve one interface: argv is [kind, host, socket fd, connect timeout in s]."""
    kind, host, fd, timeout = argv[0], argv[1], int(argv[2]), float(argv[3])
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it then closes us cleanly
    threading.Thread(target=_exit_when_orphaned, args=(os.getppid(),), daemon=True).start()
    connection = Connection(fd)
    # The constructor holds the GIL, so no Python thread can end a hung one: SIGALRM's default action ends the
    # process instead (the parent gives up at its own deadline, which comes first).
    signal.alarm(int(timeout) + 5)
    try:
        extras: dict[str, Callable[[], Any]] = {}
        if kind == "receive":
            version = probe(host)
            extras["getControllerVersion"] = lambda: version
        interface = _build(kind, host)
    except Exception as exc:  # every failure goes back to the parent as text
        connection.send(("error", type(exc).__name__, str(exc)))
        return 1
    finally:
        signal.alarm(0)
    connection.send(("ok", None))
    while True:
        try:
            name, args = connection.recv()
        except (EOFError, OSError):
            return 0
        try:
            reply = ("ok", (extras.get(name) or getattr(interface, name))(*args))
        except Exception as exc:
            reply = ("error", type(exc).__name__, str(exc))
        try:
            connection.send(reply)
        except OSError:
            return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
