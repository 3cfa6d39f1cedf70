"""The Robotiq 2F-85 behind its URCap socket, emulated for the lab cell (issue 33), and kinematic fingers for it.

The wire, as public clients of the URCap speak it (ur_rtde's RobotiqGripper, airo-ugent/robotiq2F_tcp): TCP,
port 63352 on the controller, one ASCII request per line ending in ``\\n``, one reply each:

- ``SET <VAR> <int> [<VAR> <int> ...]`` -> ``ack`` (no newline). Writable: ACT (activate), GTO (go to the
  request), ATR (automatic release), ADR (its direction, 1 opens; ur_rtde spells it ARD, both are accepted),
  POS (position request), SPE (speed), FOR (force); 0-255, the flags 0-1. All pairs are applied together.
- ``GET <VAR>`` -> ``<VAR> <int>\\n`` for the writable ones and STA (0 reset, 1 activating, 3 active), OBJ (0
  moving, 1 stopped on an object while opening, 2 while closing, 3 at the request), FLT (fault code), PRE (the
  position request's echo). GET POS is the actual position.
- Under the robot's emergency stop every GET is answered ``<VAR> ?\\n`` (ur_rtde documents it) and a SET is
  acknowledged and ignored; releasing the e-stop leaves the gripper reset (it lost power): activate it again.
- Guesses, since the real URCap's behaviour is not documented: a request it cannot parse (unknown verb or
  variable, a value out of range, a read-only variable in a SET) is answered ``?`` and changes nothing; a line over
  `MAX_LINE` bytes closes the connection; several clients may be connected at once and share one gripper.

The gripper: SET ACT 1 from reset starts activation (STA 1, `ACTIVATION_TIME` s, then STA 3; the fingers do not
replay the real one's open-close stroke). PRE echoes a POS `ECHO_DELAY` s after the request, and a motion
starts then: with GTO 1 any new POS, SPE or FOR is a new motion, GTO 0 holds the fingers. GTO 1 before ACT 1 is
fault 7 (no motion); during activation fault 5 (the motion waits for activation, then the fault clears). Any other
fault (`inject_fault`) stops the fingers and blocks motion until a reset (ACT 0, which also clears the fault).
OBJ reads 0 while GTO is 0. ATR 1 while active drives the fingers open (ADR 1) or shut at the slowest speed,
FLT 11 while they move, 15 when they stop.

The fingers are a `FingerModel`; the server converts nothing they need not know and calls them under `lock`.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from seggrasp.cell import FINGER_SPEED_RANGE, GRIP_FORCE_RANGE
from sim.gripper import MAX_WIDTH
from sim.lab import TcpServer, control

log = logging.getLogger(__name__)

URCAP_PORT = 63352
#: s from SET ACT 1 to STA 3; the real 2F-85 takes about as long for its activation stroke.
ACTIVATION_TIME = 1.5
#: s from a SET POS to its echo in PRE (and the motion's start): the URCap's Modbus round trip, a guess.
ECHO_DELAY = 0.01
#: s between the server's own finger steps (None: someone else steps the fingers).
STEP_PERIOD = 0.005
MAX_LINE = 1024
#: POS read fully open / closed on nothing by the emulated unit (a real 2F-85 reads about 3 / 228-230).
OPEN_REGISTER, CLOSED_REGISTER = 3, 228
#: What the gripper answers while `garbage` is on: bytes no URCap sends (a stray binary frame).
GARBAGE = b"\x15\x03\xff\x00RQ\x9c"

STA_RESET, STA_ACTIVATING, STA_ACTIVE = 0, 1, 3
OBJ_MOVING, OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING, OBJ_AT_POSITION = 0, 1, 2, 3
FLT_DELAYED, FLT_NOT_ACTIVATED, FLT_RELEASING, FLT_RELEASED = 5, 7, 11, 15

WRITABLE = ("ACT", "GTO", "ATR", "ADR", "POS", "SPE", "FOR")
READABLE = (*WRITABLE, "STA", "OBJ", "FLT", "PRE")
ALIASES = {"ARD": "ADR"}
FLAGS = ("ACT", "GTO", "ATR", "ADR")


def finger_speed(register: int) -> float:
    """SPE register -> finger speed (m/s), linear over the 2F-85's range."""
    low, high = FINGER_SPEED_RANGE
    return low + (high - low) * register / 255.0


def grip_force(register: int) -> float:
    """FOR register -> grip force (N), linear over the 2F-85's range."""
    low, high = GRIP_FORCE_RANGE
    return low + (high - low) * register / 255.0


class FingerModel(Protocol):
    """The fingers behind the socket, in registers. `request` starts a motion (the server calls it with the
    current position to hold); `step` advances wall-clock time; `object_status` is OBJ for the last request; a
    model that sets `fault` itself must stop its fingers; `lose_object` lets go of what the fingers hold (the
    control channel's `lose_object`)."""

    fault: int

    def step(self, dt: float) -> None: ...
    def request(self, position_register: int, speed_register: int, force_register: int) -> None: ...
    def position_register(self) -> int: ...
    def object_status(self) -> int: ...
    def lose_object(self) -> None: ...


class KinematicFingers:
    """A 2F-85 without physics: the fingers move at the requested speed to the request, clipped to the unit's
    mechanical ends, and stop on an object placed with `set_object`."""

    def __init__(self, *, stroke: float = MAX_WIDTH, open_register: int = OPEN_REGISTER,
                 closed_register: int = CLOSED_REGISTER) -> None:
        self.stroke, self.open_register, self.closed_register = stroke, open_register, closed_register
        self.fault = 0
        self.force = GRIP_FORCE_RANGE[0]  # N of the last request
        self._position = float(open_register)
        self._goal = self._position
        self._rate = 0.0  # registers/s
        self._status = OBJ_MOVING
        self._object: tuple[float, bool] | None = None  # (register, between the fingers)

    def register_for_width(self, width: float) -> float:
        """Finger opening (m) -> POS register (float) of this unit."""
        return self.closed_register - width / self.stroke * (self.closed_register - self.open_register)

    def width(self) -> float:
        """The finger opening (m)."""
        return (self.closed_register - self._position) / (self.closed_register - self.open_register) * self.stroke

    def set_object(self, width: float, *, between_fingers: bool = True) -> None:
        """An object `width` wide: between the fingers it stops them closing (OBJ 2), around them (an inner grip)
        opening (OBJ 1), on motions that reach that opening."""
        self._object = (self.register_for_width(width), between_fingers)

    def lose_object(self) -> None:
        """The object leaves the fingers: stopped on it, they carry on to the request."""
        self._object = None
        if self._status in (OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING):
            self._status = OBJ_MOVING

    def request(self, position_register: int, speed_register: int, force_register: int) -> None:
        self._goal = float(np.clip(position_register, self.open_register, self.closed_register))
        self._rate = finger_speed(speed_register) / self.stroke * (self.closed_register - self.open_register)
        self.force = grip_force(force_register)
        self._status = OBJ_MOVING
        self.step(0.0)

    def step(self, dt: float) -> None:
        if self._status != OBJ_MOVING:
            return
        closing = self._goal > self._position
        travel = min(self._rate * dt, abs(self._goal - self._position))
        new = self._position + (travel if closing else -travel)
        if self._object is not None:
            register, between = self._object
            if closing and between and self._position <= register <= new:
                self._position, self._status = register, OBJ_STOPPED_CLOSING
                return
            if not closing and not between and new <= register <= self._position:
                self._position, self._status = register, OBJ_STOPPED_OPENING
                return
        self._position = new
        if self._position == self._goal:
            self._status = OBJ_AT_POSITION

    def position_register(self) -> int:
        return int(round(self._position))

    def object_status(self) -> int:
        return self._status


@dataclass
class _Registers:
    """What the URCap holds besides the fingers."""

    ACT: int = 0
    GTO: int = 0
    ATR: int = 0
    ADR: int = 0
    POS: int = 0  # the last position request
    SPE: int = 0
    FOR: int = 0
    STA: int = STA_RESET
    PRE: int = 0


class RobotiqServer(TcpServer):
    """The URCap socket on `host:port` (0: any free port, read `.port`) in front of `fingers`, serving from
    construction until `close()` (also a context manager). Faults: `inject_fault`, `lose_object`, `set_estop`,
    `garbage` (True: every reply is `GARBAGE`) and the link faults of `TcpServer`; `handlers()` serve the same to
    the control channel."""

    def __init__(self, fingers: FingerModel, host: str = "127.0.0.1", port: int = URCAP_PORT, *,
                 activation_time: float = ACTIVATION_TIME, echo_delay: float = ECHO_DELAY,
                 step_period: float | None = STEP_PERIOD, lock: threading.RLock | None = None) -> None:
        self.fingers = fingers
        self.activation_time, self.echo_delay, self.step_period = activation_time, echo_delay, step_period
        self.lock = lock or threading.RLock()
        self.requests = 0  # request lines answered
        self.garbage = False
        self._regs = _Registers()
        self._estop = False
        self._releasing = False
        self._timers: list[tuple[float, Callable[[], None]]] = []
        self._last_step = time.monotonic()
        self._stop = threading.Event()
        self._clock_thread: threading.Thread | None = None
        super().__init__(host, port)
        if step_period is not None:
            self._clock_thread = threading.Thread(target=self._clock, name="robotiq-clock", daemon=True)
            self._clock_thread.start()
        log.info("Robotiq URCap socket on port %d", self.port)

    def close(self) -> None:
        """Stop listening, drop every client and stop the clock. Idempotent."""
        self._stop.set()
        super().close()
        if self._clock_thread is not None:
            self._clock_thread.join(timeout=2.0)

    def __enter__(self) -> RobotiqServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --------------------------------------------------------------------------------------------- faults
    def inject_fault(self, code: int) -> None:
        """The gripper reports FLT `code` and its fingers stop until a reset (0 clears it at once)."""
        with self.lock:
            self.fingers.fault = int(code)
            if code:
                self._hold()

    def lose_object(self) -> None:
        with self.lock:
            self.fingers.lose_object()

    def set_estop(self, on: bool) -> None:
        """The robot's emergency stop: GETs read '?'; released, the gripper comes back reset."""
        with self.lock:
            self._advance()
            if on and not self._estop:
                self._hold()
            if not on and self._estop:
                self._reset()
            self._estop = bool(on)

    def handlers(self) -> dict[str, Callable[[dict], dict]]:
        """Control-channel commands (sim/lab/control.py: each gets the request dict, returns the reply's fields):
        ``gripper_fault {code}``, ``lose_object``, ``gripper_estop {on}`` (on defaults to true)."""
        def fault(request: dict) -> dict:
            code = request.get("code")
            if not isinstance(code, int) or isinstance(code, bool) or not 0 <= code <= 15:
                raise ValueError(f"gripper_fault needs a code 0-15 (the URCap's FLT), got {code!r}")
            self.inject_fault(code)
            return {"fault": code}

        def lose(request: dict) -> dict:
            self.lose_object()
            return {}

        def estop(request: dict) -> dict:
            on = request.get("on", True)
            if not isinstance(on, bool):
                raise ValueError(f"gripper_estop's on must be true or false, got {on!r}")
            self.set_estop(on)
            return {"estop": on}

        return {"gripper_fault": fault, "lose_object": lose, "gripper_estop": estop}

    # -------------------------------------------------------------------------------------------------- time
    def _clock(self) -> None:
        while not self._stop.wait(self.step_period):
            with self.lock:
                self._advance()

    def _advance(self) -> None:
        """Step the fingers to now, firing the timers that fell due on the way."""
        now = time.monotonic()
        while self._timers and self._timers[0][0] <= now:
            at, action = self._timers.pop(0)
            self._step_to(at)
            action()
        self._step_to(now)
        if self._releasing and self.fingers.object_status() != OBJ_MOVING:
            self._releasing, self.fingers.fault = False, FLT_RELEASED

    def _step_to(self, at: float) -> None:
        if self.step_period is not None and at > self._last_step:
            self.fingers.step(at - self._last_step)
        self._last_step = max(self._last_step, at)

    def _after(self, delay: float, action: Callable[[], None]) -> None:
        self._timers.append((time.monotonic() + delay, action))
        self._timers.sort(key=lambda timer: timer[0])

    # ------------------------------------------------------------------------------------------------ gripper
    def _hold(self) -> None:
        self.fingers.request(self.fingers.position_register(), self._regs.SPE, self._regs.FOR)

    def _reset(self) -> None:
        self._regs.ACT = self._regs.GTO = 0
        self._regs.STA = STA_RESET
        self._timers.clear()
        self._releasing = False
        self.fingers.fault = 0
        self._hold()

    def _activated(self) -> None:
        self._regs.STA = STA_ACTIVE
        if self.fingers.fault == FLT_DELAYED:
            self.fingers.fault = 0
            self._go()

    def _go(self) -> None:
        """A motion to the request, `echo_delay` from now; faults when the gripper cannot move."""
        regs = self._regs
        if not regs.ACT:
            self.fingers.fault = FLT_NOT_ACTIVATED
        elif regs.STA != STA_ACTIVE:
            self.fingers.fault = FLT_DELAYED
        elif self.fingers.fault in (0, FLT_NOT_ACTIVATED):
            self.fingers.fault = 0
            request = (regs.POS, regs.SPE, regs.FOR)
            self._after(self.echo_delay, lambda: self._start(*request))

    def _start(self, position: int, speed: int, force: int) -> None:
        if self._regs.GTO and not self._estop and self.fingers.fault == 0:
            self.fingers.request(position, speed, force)

    def _set(self, pairs: dict[str, int]) -> None:
        regs = self._regs
        was_active = regs.ACT
        for name, value in pairs.items():
            setattr(regs, name, value)
        if "POS" in pairs:
            self._after(self.echo_delay, lambda: setattr(regs, "PRE", pairs["POS"]))
        if not regs.ACT:
            if was_active:
                self._reset()
            if pairs.get("GTO"):
                self.fingers.fault = FLT_NOT_ACTIVATED
            return
        if not was_active:
            regs.STA = STA_ACTIVATING
            self._after(self.activation_time, self._activated)
        if pairs.get("ATR") and regs.STA == STA_ACTIVE and not self._releasing:
            self._releasing, self.fingers.fault = True, FLT_RELEASING
            self.fingers.request(0 if regs.ADR else 255, 0, 0)
        elif "GTO" in pairs and not regs.GTO:
            self._hold()
        elif regs.GTO and pairs.keys() & {"GTO", "POS", "SPE", "FOR"}:
            self._go()

    def _get(self, name: str) -> int:
        if name == "POS":
            return self.fingers.position_register()
        if name == "FLT":
            return self.fingers.fault
        if name == "OBJ":
            return self.fingers.object_status() if self._regs.GTO else OBJ_MOVING
        return getattr(self._regs, name)

    def reply(self, line: str) -> bytes:
        """The answer to one request line (without its newline)."""
        with self.lock:
            self._advance()
            self.requests += 1
            if self.garbage:
                return GARBAGE
            words = line.split()
            if len(words) == 2 and words[0] == "GET" and ALIASES.get(words[1], words[1]) in READABLE:
                value = "?" if self._estop else str(self._get(ALIASES.get(words[1], words[1])))
                return f"{words[1]} {value}\n".encode("ascii")
            pairs = _parse_set(words)
            if pairs is None:
                return b"?"
            if not self._estop:
                self._set(pairs)
            return b"ack"

    def serve_client(self, sock: socket.socket) -> None:
        buffer = b""
        while chunk := sock.recv(4096):
            buffer += chunk
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                if line.strip():
                    sock.sendall(self.reply(line.decode("ascii", errors="replace").strip()))
            if len(buffer) > MAX_LINE:
                log.warning("a request line over %d bytes: closing the connection", MAX_LINE)
                return


def _parse_set(words: list[str]) -> dict[str, int] | None:
    """The variable -> value pairs of a valid SET request, or None."""
    if len(words) < 3 or words[0] != "SET" or len(words) % 2 == 0:
        return None
    pairs = {}
    for name, text in zip(words[1::2], words[2::2]):
        name = ALIASES.get(name, name)
        if name not in WRITABLE or not text.isdigit() or int(text) > (1 if name in FLAGS else 255):
            return None
        pairs[name] = int(text)
    return pairs


def start_gripper_server(fingers: FingerModel, host: str = "127.0.0.1", port: int = URCAP_PORT,
                         **options) -> RobotiqServer:
    """Serve the URCap socket for `fingers` on `host:port` (background threads; `.close()` ends it) and register
    its faults on the control channel. `options`: activation_time, echo_delay, step_period (None when another
    clock steps the fingers) and lock (the one that clock holds while stepping)."""
    server = RobotiqServer(fingers, host, port, **options)
    for name, handler in server.handlers().items():
        control.register(name, handler)
    return server
