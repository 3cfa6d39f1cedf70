"""The Robotiq 2F-85 over the URCap's ASCII socket (TCP port 63352 on the UR controller).

Protocol (Robotiq Gripper URCap): the client sends one line per request, ``SET <VAR> <value> [<VAR> <value> ...]``
answered by ``ack``, or ``GET <VAR>`` answered by ``<VAR> <value>``. Variables used here: ACT (activation request),
ATR (automatic release), GTO (go to the requested position), POS (requested/actual position register, 0 = open,
255 = closed), SPE and FOR (speed and force registers, 0-255), PRE (echo of the position request), STA (0 reset,
1 activating, 3 active), OBJ (0 moving, 1 stopped on an object while opening, 2 stopped on an object while
closing, 3 reached the request without an object) and FLT (fault code, 0 = none).

Registers map to SI units linearly: the finger opening is `stroke` at `open_register` and 0 at `closed_register`
(read the two after activation with `calibrate_range()`); speed 0-255 spans `FINGER_SPEED_RANGE` and force 0-255
`GRIP_FORCE_RANGE` (2F-85 datasheet, `seggrasp.cell`; both approximate).

Deadlines: every reply within `gripper.timeout`; a finger motion within its travel at the commanded speed plus
`gripper.timeout` (`motion_timeout`). Under the robot's emergency stop the URCap answers ``<VAR> ?`` to every GET:
the client raises a `GripperError` that names the e-stop.
"""

from __future__ import annotations

import logging
import re
import socket
import time
from dataclasses import dataclass

import numpy as np

from hardware.config import GripperConfig
from hardware.errors import ConnectionLostError, GripperError, SafetyError
from hardware.safety import SafetyGuard
from seggrasp.cell import FINGER_SPEED_RANGE, GRIP_FORCE_RANGE

log = logging.getLogger(__name__)

SPEED_RANGE = FINGER_SPEED_RANGE  # m/s at registers 0 and 255
FORCE_RANGE = GRIP_FORCE_RANGE  # N at registers 0 and 255

STA_RESET, STA_ACTIVATING, STA_ACTIVE = 0, 1, 3
OBJ_MOVING, OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING, OBJ_AT_POSITION = 0, 1, 2, 3

FAULTS = {
    5: "action delayed: the activation must complete first",
    7: "the activation bit must be set before moving",
    8: "maximum operating temperature exceeded",
    9: "no communication with the gripper for at least 1 s",
    10: "under minimum operating voltage",
    11: "automatic release in progress",
    12: "internal fault",
    13: "activation fault: check that nothing blocks the fingers",
    14: "overcurrent triggered",
    15: "automatic release completed",
}

#: The largest value each variable can read (the others are registers, 0-255); a reply beyond it is a protocol error.
MAX_VALUE = {"ACT": 1, "GTO": 1, "ATR": 1, "ADR": 1, "STA": 3, "OBJ": 3, "FLT": 15}

_SETTLE = 0.02  # s of silence that ends a complete reply sent without a newline
MAX_REPLY_BYTES = 256  # the longest reply the client accepts (the URCap's are under 10 bytes)


@dataclass(frozen=True)
class _Reply:
    """The reply a request expects: `head` followed by text matching `tail` (a regex), e.g. "POS " + digits."""

    head: str
    tail: str = ""

    @property
    def describe(self) -> str:
        """How the expected reply is named in errors."""
        return f"{self.head!r}" + (" and a number" if self.tail else "")

    def complete(self, text: str) -> bool:
        """Whether `text` is the whole expected reply."""
        return text.startswith(self.head) and re.fullmatch(self.tail, text[len(self.head):]) is not None

    def partial(self, text: str) -> bool:
        """Whether `text` is the expected reply's beginning, still missing its end."""
        return (self.head.startswith(text) and text != self.head) or (
            text.startswith(self.head) and bool(self.tail) and not text[len(self.head):].strip())


_ACK = _Reply("ack")


@dataclass(frozen=True)
class GripperState:
    """A snapshot of the gripper's status variables."""

    activated: bool
    status: int  # STA
    object_status: int  # OBJ
    fault: int  # FLT
    position: int  # POS (actual)
    request_echo: int  # PRE

    @property
    def object_detected(self) -> bool:
        """True when the fingers stopped on an object (OBJ 1 or 2)."""
        return self.object_status in (OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING)


@dataclass(frozen=True)
class GripResult:
    """How a finger motion ended."""

    object_detected: bool
    width: float  # m between the fingers when they stopped
    position: int  # POS register when they stopped


def _to_register(value: float, value_range: tuple[float, float], name: str, unit: str) -> int:
    low, high = value_range
    if not low - 1e-9 <= value <= high + 1e-9:  # also refuses NaN
        raise SafetyError(f"{name} {value!r} {unit} is outside the 2F-85's range [{low:g}, {high:g}] {unit}")
    return int(round(np.clip((value - low) / (high - low), 0.0, 1.0) * 255))


class RobotiqGripper:
    """Client for the URCap gripper socket; every reply is bounded by `config.timeout`, every finger motion by
    `motion_timeout`."""

    def __init__(self, config: GripperConfig, guard: SafetyGuard, *, dry_run: bool = False) -> None:
        self.config = config
        self.guard = guard
        self.dry_run = dry_run
        self.commands: list[str] = []  # every SET line sent (or, in dry run, planned)
        self._socket: socket.socket | None = None
        self._open_register = config.open_register
        self._closed_register = config.closed_register
        self._dry_position = config.open_register

    # ---------------------------------------------------------------------------------------------- unit mapping
    def width_to_register(self, width: float) -> int:
        """Finger opening (m) -> POS register, clipped to the calibrated range."""
        fraction = np.clip(width / self.config.stroke, 0.0, 1.0)
        return int(round(self._closed_register - fraction * (self._closed_register - self._open_register)))

    def register_to_width(self, register: int) -> float:
        """POS register -> finger opening (m), clipped to [0, stroke]."""
        span = self._closed_register - self._open_register
        return float(np.clip((self._closed_register - register) / span, 0.0, 1.0) * self.config.stroke)

    @staticmethod
    def speed_to_register(speed: float) -> int:
        """Finger speed (m/s) -> SPE register; a speed the 2F-85 cannot do is refused, not clipped."""
        return _to_register(speed, SPEED_RANGE, "finger speed", "m/s")

    @staticmethod
    def force_to_register(force: float) -> int:
        """Grip force (N) -> FOR register; a force the 2F-85 cannot apply is refused, not clipped."""
        return _to_register(force, FORCE_RANGE, "grip force", "N")

    # ------------------------------------------------------------------------------------------------- transport
    def connect(self) -> None:
        """Open the socket to the URCap (not in dry run)."""
        if self.dry_run:
            log.info("[dry run] not connecting to the gripper at %s:%d", self.config.host, self.config.port)
            return
        self.disconnect()  # a fresh connection: nothing from an earlier one can be read as a reply
        try:
            self._socket = socket.create_connection((self.config.host, self.config.port), timeout=self.config.timeout)
        except OSError as exc:
            raise ConnectionLostError(f"cannot reach the Robotiq URCap socket at {self.config.host}:"
                                      f"{self.config.port}: {exc}") from exc
        log.info("connected to the gripper at %s:%d", self.config.host, self.config.port)

    def disconnect(self) -> None:
        """Close the socket. Safe to call more than once."""
        if self._socket is not None:
            try:
                self._socket.close()
            finally:
                self._socket = None

    def _request(self, line: str, expected: _Reply) -> str:
        """Send `line` and return its reply; one deadline (`config.timeout`) bounds the whole exchange.

        Any timeout or protocol error (an unexpected, over-long or late reply) drops the connection, so a reply
        that arrives late can never be taken for the answer to a later request; `connect()` starts afresh.
        """
        if self._socket is None:
            raise ConnectionLostError("the gripper is not connected (call connect() first)")
        deadline = time.monotonic() + self.config.timeout
        try:
            self._check_in_step(line)
            self._socket.settimeout(self.config.timeout)
            self._socket.sendall((line + "\n").encode("ascii"))
            reply = self._read_reply(line, expected, deadline)
        except socket.timeout:
            raise self._drop(f"no reply from the gripper to {line!r} within {self.config.timeout} s")
        except OSError as exc:
            self.disconnect()
            raise ConnectionLostError(f"lost the gripper connection during {line!r}: {exc}") from exc
        if not expected.complete(reply):
            raise self._drop(f"the gripper answered {reply!r} to {line!r} (expected {expected.describe})")
        return reply

    def _check_in_step(self, line: str) -> None:
        """Refuse to send while unread bytes wait on the socket: they would be read as this request's reply."""
        assert self._socket is not None
        self._socket.settimeout(0.0)
        try:
            stale = self._socket.recv(MAX_REPLY_BYTES, socket.MSG_PEEK)
        except (BlockingIOError, InterruptedError):
            return
        if not stale:
            self.disconnect()
            raise ConnectionLostError("the gripper closed the connection")
        raise self._drop(f"unexpected data {stale[:32]!r} from the gripper before {line!r} (a late reply to an "
                         "earlier request)")

    def _read_reply(self, line: str, expected: _Reply, deadline: float) -> str:
        """One reply: up to a newline or, for a bare reply (the URCap sends `ack` without one), the expected text
        followed by a moment of silence. A partial reply waits for the rest until the deadline."""
        assert self._socket is not None
        buffer = bytearray()
        while True:
            end = buffer.find(b"\n")
            if end >= 0:
                if buffer[end + 1:].strip():
                    raise self._drop(f"more data than one reply to {line!r}: {bytes(buffer[:64])!r}")
                return buffer[:end].decode("ascii", errors="replace").strip()
            text = buffer.decode("ascii", errors="replace").strip()
            settling = bool(text) and not expected.partial(text)  # complete, or not what we asked for
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise socket.timeout()
            self._socket.settimeout(min(remaining, _SETTLE) if settling else remaining)
            try:
                chunk = self._socket.recv(4096)
            except socket.timeout:
                if settling:
                    return text
                raise
            if not chunk:
                self.disconnect()
                raise ConnectionLostError("the gripper closed the connection")
            buffer += chunk
            if len(buffer) > MAX_REPLY_BYTES:
                raise self._drop(f"the reply to {line!r} is longer than {MAX_REPLY_BYTES} bytes "
                                 f"(starts {bytes(buffer[:32])!r}): not a URCap gripper socket?")

    def _drop(self, problem: str) -> GripperError:
        """Disconnect (resynchronising the stream) and return the error to raise."""
        self.disconnect()
        return GripperError(f"{problem}; disconnected (call connect() to retry)")

    def set(self, **variables: int) -> None:
        """Send one SET line with the given variables (in order); raises unless the gripper answers `ack`."""
        line = "SET " + " ".join(f"{name} {int(value)}" for name, value in variables.items())
        self.commands.append(line)
        if self.dry_run:
            log.info("[dry run] gripper %s", line)
            return
        self._request(line, _ACK)

    def get(self, name: str) -> int:
        """Read one variable with GET; raises (and disconnects) on a malformed reply or a value out of the
        variable's range, and names an emergency stop (the URCap's ``<VAR> ?``; the link stays in step, so it stays
        connected)."""
        reply = self._request(f"GET {name}", _Reply(f"{name} ", r"\d+|\?"))
        value = reply.split()[1]
        if value == "?":
            raise GripperError(f"the gripper answered {reply!r} to 'GET {name}': the robot is in emergency stop, "
                               "so the URCap reads nothing from the gripper; release the e-stop, then activate the "
                               "gripper again")
        high = MAX_VALUE.get(name, 255)
        if int(value) > high:
            raise self._drop(f"the gripper answered {reply!r} to 'GET {name}' ({name} is 0-{high})")
        return int(value)

    # ------------------------------------------------------------------------------------------------ operations
    def state(self) -> GripperState:
        """Read STA, OBJ, FLT, POS, PRE and ACT."""
        if self.dry_run:
            return GripperState(True, STA_ACTIVE, OBJ_AT_POSITION, 0, self._dry_position, self._dry_position)
        return GripperState(activated=self.get("ACT") == 1, status=self.get("STA"), object_status=self.get("OBJ"),
                            fault=self.get("FLT"), position=self.get("POS"), request_echo=self.get("PRE"))

    def is_active(self) -> bool:
        """True when activation has completed (STA 3)."""
        return self.dry_run or self.get("STA") == STA_ACTIVE

    def activate(self, reset: bool = True) -> None:
        """Reset (clearing faults) and activate; the fingers open and close once during activation."""
        if reset:
            self.reset()
        self.set(ACT=1)
        if self.dry_run:
            return
        self._wait(lambda: self.get("STA") == STA_ACTIVE, "activation", self.config.timeout + 5.0)
        log.info("gripper activated")

    def reset(self) -> None:
        """ACT 0 / ATR 0 until the gripper reports reset (ACT 0, STA 0); this clears the fault status."""
        self.set(ACT=0, ATR=0)
        if self.dry_run:
            return
        self._wait(lambda: self.get("ACT") == 0 and self.get("STA") == STA_RESET, "reset", self.config.timeout)

    def clear_fault(self) -> None:
        """Clear a fault by resetting and re-activating (the documented recovery)."""
        fault = 0 if self.dry_run else self.get("FLT")
        log.warning("clearing gripper fault %d (%s)", fault, FAULTS.get(fault, "unknown"))
        self.activate(reset=True)

    def calibrate_range(self) -> tuple[int, int]:
        """Open fully and close fully on nothing, and use the POS values read as the width mapping's ends."""
        self.move_register(0, speed=SPEED_RANGE[1], force=FORCE_RANGE[0])
        open_register = self.get("POS")
        self.move_register(255, speed=SPEED_RANGE[1], force=FORCE_RANGE[0])
        closed_register = self.get("POS")
        if closed_register - open_register < 100:
            raise GripperError(f"calibration read open={open_register}, closed={closed_register}: is something "
                               "between the fingers?")
        self._open_register, self._closed_register = open_register, closed_register
        log.info("gripper range calibrated: open=%d closed=%d", open_register, closed_register)
        return open_register, closed_register

    def move_register(self, position: int, *, speed: float, force: float, wait: bool = True) -> GripResult:
        """Go to POS register `position` with the given speed (m/s) and force (N); wait for the fingers to stop."""
        if not 0 <= int(position) <= 255:
            raise SafetyError(f"gripper position register must be in [0, 255], got {position}")
        self.guard.check_grip_force(force)
        line = {"POS": int(position), "SPE": self.speed_to_register(speed), "FOR": self.force_to_register(force)}
        target_width = self.register_to_width(position)
        self.guard.check_opening(target_width)
        # while the fingers move they may be anywhere between the old and the new opening
        self.guard.finger_opening = max(self.guard.finger_opening, target_width)
        start = self.get("POS") if wait and not self.dry_run else int(position)
        self.set(**line, GTO=1)
        if self.dry_run:
            self._dry_position = int(position)
            self.guard.finger_opening = target_width
            return GripResult(False, target_width, int(position))
        if not wait:
            return GripResult(False, self.width(), self.get("POS"))
        self._wait(lambda: self.get("PRE") == int(position), "position request echo", self.config.timeout)
        self._wait(lambda: self.get("OBJ") != OBJ_MOVING, "finger motion", self.motion_timeout(start, position, speed))
        state = self.state()
        if state.fault:
            raise GripperError(f"gripper fault {state.fault} in the finger motion to POS {position}: "
                               f"{FAULTS.get(state.fault, 'unknown fault')}")
        self.guard.finger_opening = self.register_to_width(state.position)
        return GripResult(state.object_detected, self.guard.finger_opening, state.position)

    def motion_timeout(self, start: int, goal: int, speed: float) -> float:
        """Deadline (s) of a finger motion from POS `start` towards `goal` at `speed` (m/s): the travel time (the
        calibrated ends bound the travel) plus `config.timeout` as the margin for settling and speed error (a fixed
        deadline failed full strokes at slow speeds: issue 33, F10)."""
        travel = abs(self.register_to_width(goal) - self.register_to_width(start))
        return travel / speed + self.config.timeout

    def move_to_width(self, width: float, *, speed: float | None = None, force: float | None = None) -> GripResult:
        """Open or close to a finger opening in metres."""
        if not 0.0 <= width <= self.config.stroke + 1e-9:
            raise SafetyError(f"gripper width {width:.4f} m is outside [0, {self.config.stroke}] m")
        return self.move_register(self.width_to_register(width), speed=speed or self.config.speed,
                                  force=force or self.config.force)

    def open(self, *, speed: float | None = None, force: float | None = None) -> GripResult:
        """Open fully."""
        return self.move_register(0, speed=speed or self.config.speed, force=force or self.config.force)

    def close(self, *, speed: float | None = None, force: float | None = None) -> GripResult:
        """Close fully (stopping on an object) with the given force (N) and speed (m/s)."""
        return self.move_register(255, speed=speed or self.config.speed, force=force or self.config.force)

    def width(self) -> float:
        """Current finger opening (m)."""
        if self.dry_run:
            return self.register_to_width(self._dry_position)
        return self.register_to_width(self.get("POS"))

    def object_detected(self) -> bool:
        """True when the fingers are stopped on an object (OBJ 1 or 2); False in dry run (nothing is held)."""
        if self.dry_run:
            return False
        return self.get("OBJ") in (OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING)

    def _wait(self, condition, what: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            fault = self.get("FLT")
            if fault and fault not in (5,):  # 5 (action delayed) clears itself once activation completes
                raise GripperError(f"gripper fault {fault} while waiting for {what}: "
                                   f"{FAULTS.get(fault, 'unknown fault')}")
            if time.monotonic() > deadline:
                raise GripperError(f"gripper {what} did not complete within {timeout:.1f} s")
            time.sleep(0.01)
