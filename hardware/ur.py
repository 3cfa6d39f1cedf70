"""The UR arm over ur_rtde: guarded joint and Cartesian moves, state, stop detection, reconnect and shutdown.

This module is the ONE place where the project's 4x4 poses meet UR's pose vectors `[x, y, z, rx, ry, rz]`
(position in metres, orientation as an axis-angle rotation vector): `ur_pose_from_matrix` and
`matrix_from_ur_pose`. The world frame is the robot's base frame as RTDE reports it (docs/design.md section 3: robot base at the
origin, z up). The controller's TCP is set to the project's gripper frame (`robot.tcp_offset` = `T_flange_gripper`:
z = approach, x = closing direction, origin between the fingertips), so every pose the arm takes or reports is
`T_world_gripper`.

`URArm` talks to an `RTDEControlInterface` / `RTDEReceiveInterface` pair made by the factories it is given (by
default the real ur_rtde classes, each in a process of its own: `RTDEClient`; tests inject fakes). Each motion is
checked by `SafetyGuard` first, then sent asynchronously and watched: a protective or emergency stop raises
`RobotStoppedError`, a lost or stalled link stops the robot (as far as it can still be reached) and raises
`ConnectionLostError`. In dry-run mode nothing connects to the controller: motions are checked, logged and recorded
in `planned_motions`, and the arm's state follows the plan.

What ur_rtde 1.6.5 does on the wire, and why the arm guards against it (docs/results of the bridge audit, F1-F7):
its constructors can wait for ever and hold the GIL, and its `reconnect()` can kill the process with SIGSEGV when the
link is up or when its own receive thread is already reconnecting after a drop. So every interface lives in a host
process with a deadline on every call; `reconnect()` replaces only interfaces whose link is down; no command is sent
on a control interface whose link dropped; a state that stops advancing is an error, not a pose; the control
script, which a protective or emergency stop ends, is uploaded again once the stop has been released; and the IK
check runs locally on controllers too old to answer it (PolyScope < 5.10 e-Series, < 3.15 CB3).
"""

from __future__ import annotations

import functools
import logging
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Callable, NoReturn

import numpy as np
from scipy.spatial.transform import Rotation

from hardware.config import RobotConfig
from hardware.errors import ConnectionLostError, MotionError, RobotStoppedError, SafetyError
from hardware.kinematics import ARM_MODELS, forward_kinematics, inverse_kinematics
from hardware.safety import SafetyGuard

log = logging.getLogger(__name__)

#: How close (m, rad) the arm must end to its target for a motion to count as done.
POSITION_TOLERANCE = 0.005
ORIENTATION_TOLERANCE = 0.01
JOINT_TOLERANCE = 0.01
_POLL_PERIOD = 0.01
#: Deadline (s) for building one ur_rtde interface; its constructor waits for ever on a controller that accepts and
#: never streams (F3). A healthy one takes well under a second, plus up to 5 s for the control script to start.
CONNECT_TIMEOUT = 10.0
#: Deadline (s) for one call into ur_rtde (its own waits: 3 s for the control script to be ready for a command),
#: and for its disconnect (a 0.5 s sleep; after a drop its threads may never let it finish).
CALL_TIMEOUT = 10.0
DISCONNECT_TIMEOUT = 1.5
#: The state is stale when the controller's timestamp has not advanced for this long (s); it streams at 125 or
#: 500 Hz, and ur_rtde itself gives up on a silent link only after 2.5 s (F7).
STALE_STATE = 1.0
#: Deadline (s) for the state to show a new TCP (F6; the stream may trail by up to ur_rtde's 2.5 s) and for the
#: control script to start after an upload (ur_rtde's own wait).
STATE_TIMEOUT = 3.0
PROGRAM_START_TIMEOUT = 5.0
#: How far (m; twice this in rad) the reported tool pose may be from the nominal kinematics' at the reported joints
#: (a calibrated UR differs by about a millimetre; a missing TCP offset by the whole offset).
KINEMATICS_AGREEMENT = 0.01
#: RTDE's safety_mode values (UR's RTDE guide); anything else is a garbled state.
SAFETY_MODES = {1: "normal", 2: "reduced", 3: "protective stop", 4: "recovery", 5: "safeguard stop",
                6: "system emergency stop", 7: "robot emergency stop", 8: "violation", 9: "fault",
                10: "validate joint id", 11: "undefined safety mode", 12: "automatic mode safeguard stop",
                13: "three-position enabling stop"}
#: The first PolyScope version whose controller answers `getInverseKinematicsHasSolution`, per major version (CB3,
#: e-Series); below it ur_rtde strips the query from its script and the answer is an arbitrary register (F4).
IK_QUERY_SINCE = {3: (3, 15), 5: (5, 10)}
#: Largest magnitudes a sane state reports: joints turn +-360 deg; a pose within metres, a rotation vector.
_STATE_BOUNDS = {"getActualQ": np.full(6, 2 * np.pi + 0.1),
                 "getActualTCPPose": np.r_[[5.0] * 3, [np.pi + 1e-6] * 3]}


def ur_pose_from_matrix(T: np.ndarray) -> list[float]:
    """4x4 homogeneous pose -> UR pose vector [x, y, z, rx, ry, rz] (rotation vector, radians)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"expected a 4x4 pose, got shape {T.shape}")
    return [*map(float, T[:3, 3]), *map(float, Rotation.from_matrix(T[:3, :3]).as_rotvec())]


def matrix_from_ur_pose(pose: Any) -> np.ndarray:
    """UR pose vector [x, y, z, rx, ry, rz] -> 4x4 homogeneous pose."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (6,):
        raise ValueError(f"expected a UR pose [x, y, z, rx, ry, rz], got {pose.tolist()}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def _close_to(T: np.ndarray, target: np.ndarray) -> bool:
    """Whether pose `T` is within the position and orientation tolerances of `target`."""
    angle = Rotation.from_matrix(T[:3, :3].T @ target[:3, :3]).magnitude()
    return bool(np.linalg.norm(T[:3, 3] - target[:3, 3]) <= POSITION_TOLERANCE and angle <= ORIENTATION_TOLERANCE)


@dataclass(frozen=True)
class PlannedMotion:
    """One motion as checked (and, unless dry-run, sent): kind is "moveJ" or "moveL"."""

    kind: str
    target: tuple[float, ...]  # joints (rad) for moveJ, UR pose vector for moveL
    speed: float
    acceleration: float


_HOST = Path(__file__).with_name("rtde_host.py")


class RTDEClient:
    """One ur_rtde interface ("control" or "receive") in a host process of its own (hardware/rtde_host.py).

    ur_rtde's methods are called by name (`client.getActualQ()`), each with a deadline. Building the interface, a
    call that misses its deadline, or a host that dies (ur_rtde's SIGSEGV) raises `ConnectionLostError`, and the
    host is ended; `isConnected()` is then False. `reconnect()` builds a fresh interface in a fresh host rather
    than calling ur_rtde's own reconnect (it crashes on a live link and races its receive thread after a drop).
    What ur_rtde prints goes to this module's log. The receive host also answers `getControllerVersion()`."""

    def __init__(self, kind: str, host: str, *, connect_timeout: float = CONNECT_TIMEOUT,
                 call_timeout: float = CALL_TIMEOUT) -> None:
        self.kind, self.host = kind, host
        self.connect_timeout, self.call_timeout = connect_timeout, call_timeout
        self._lock = threading.Lock()
        self._process: subprocess.Popen | None = None
        self._connection: Connection | None = None
        self._output: deque[str] = deque(maxlen=3)
        self._start()

    def __getattr__(self, name: str) -> Callable[..., Any]:
        if name.startswith("_"):
            raise AttributeError(name)
        return functools.partial(self._invoke, name)

    def isConnected(self) -> bool:
        """False once the host has ended; otherwise ur_rtde's answer."""
        return self._alive() and bool(self._invoke("isConnected"))

    def reconnect(self) -> bool:
        """End the host and build the interface again in a new one (raises `ConnectionLostError` on failure)."""
        with self._lock:
            self._end()
            self._start()
        return True

    def disconnect(self) -> None:
        """ur_rtde's disconnect (it sleeps 0.5 s; given `DISCONNECT_TIMEOUT`), then end the host. Safe to call more
        than once; the host is ended even when the call fails."""
        try:
            if self._alive():
                self._call_within(DISCONNECT_TIMEOUT, "disconnect")
        finally:
            with self._lock:
                self._end()

    # ------------------------------------------------------------------------------------------------ the host
    def _start(self) -> None:
        parent_end, child_end = socket.socketpair()
        with child_end:
            self._process = subprocess.Popen(
                [sys.executable, str(_HOST), self.kind, self.host, str(child_end.fileno()), str(self.connect_timeout)],
                pass_fds=(child_end.fileno(),), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, errors="replace")
        self._connection = Connection(parent_end.detach())
        threading.Thread(target=self._forward_output, args=(self._process,), name=f"ur_rtde-{self.kind}-output",
                         daemon=True).start()
        status, *detail = self._reply(self.connect_timeout, f"did not connect within {self.connect_timeout:g} s")
        if status != "ok":
            self._end()
            raise RuntimeError(detail[1])

    def _forward_output(self, process: subprocess.Popen) -> None:
        for line in process.stdout:
            if line.strip():
                self._output.append(line.strip())
                log.warning("ur_rtde %s: %s", self.kind, line.strip())

    def _alive(self) -> bool:
        return self._process is not None and self._process.poll() is None and self._connection is not None

    def _invoke(self, name: str, *args: Any) -> Any:
        return self._call_within(self.call_timeout, name, *args)

    def _call_within(self, timeout: float, name: str, *args: Any) -> Any:
        with self._lock:
            if not self._alive():
                raise ConnectionLostError(f"the ur_rtde {self.kind} client is not running{self._fate()}")
            try:
                self._connection.send((name, args))
            except OSError:
                self._end()
                raise ConnectionLostError(f"the ur_rtde {self.kind} client died during {name}{self._fate()}")
            status, *detail = self._reply(timeout, f"did not answer {name} within {timeout:g} s")
        if status == "ok":
            return detail[0]
        kind, message = detail
        raise (ValueError if kind == "ValueError" else RuntimeError)(message)

    def _reply(self, timeout: float, missed: str) -> tuple:
        """The host's next message; a missed deadline or a dead host ends it and raises `ConnectionLostError`."""
        try:
            if self._connection.poll(timeout):
                return self._connection.recv()
        except (EOFError, OSError):
            self._end()
            raise ConnectionLostError(f"the ur_rtde {self.kind} client died{self._fate()}") from None
        self._end(kill=True)
        raise ConnectionLostError(f"the ur_rtde {self.kind} client {missed}; it was ended{self._last_words()}")

    def _end(self, kill: bool = False) -> None:
        """Close the socket and end the host: it exits by itself when the socket closes, and is killed when it
        does not within 2 s or at once with `kill` (a hung ur_rtde call)."""
        if self._connection is not None:
            self._connection.close()
            self._connection = None
        if self._process is not None and self._process.poll() is None:
            try:
                if kill:
                    self._process.kill()
                self._process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()

    def _fate(self) -> str:
        """How the host ended, for messages: its exit code or signal, and what ur_rtde said last."""
        if self._process is None:
            return ""
        try:
            code = self._process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            return self._last_words()
        how = f"exit code {code}"
        if code < 0:
            try:
                how = f"killed by {signal.Signals(-code).name}"
            except ValueError:
                how = f"killed by signal {-code}"
        return f" ({how}){self._last_words()}"

    def _last_words(self) -> str:
        return f"; ur_rtde said: {' | '.join(self._output)}" if self._output else ""


def _default_control_factory(ip: str) -> RTDEClient:
    return RTDEClient("control", ip)


def _default_receive_factory(ip: str) -> RTDEClient:
    return RTDEClient("receive", ip)


class URArm:
    """A UR5/UR5e driven over RTDE with every motion checked by a `SafetyGuard` before it is sent."""

    def __init__(self, config: RobotConfig, guard: SafetyGuard, *, dry_run: bool = False,
                 control_factory: Callable[[str], Any] | None = None,
                 receive_factory: Callable[[str], Any] | None = None) -> None:
        self.config = config
        self.guard = guard
        self.dry_run = dry_run
        self.planned_motions: list[PlannedMotion] = []
        #: (major, minor, bugfix, build) the controller reported at connect; None in dry run
        self.controller_version: tuple[int, ...] | None = None
        self._control_factory = control_factory or _default_control_factory
        self._receive_factory = receive_factory or _default_receive_factory
        self._control: Any = None
        self._receive: Any = None
        self._planned_q = np.asarray(config.home_joints, dtype=np.float64).copy()
        self._planned_T: np.ndarray | None = None
        self._stamp: float | None = None  # the controller's last timestamp seen, and when (monotonic) it was new
        self._stamp_seen = 0.0
        self._stop_seen = False  # a protective/emergency stop was seen since the control script last ran
        self._lost = ""  # why the interfaces were ended (a dropped or stalled link), for messages

    # ---------------------------------------------------------------------------------------------------- connection
    def connect(self) -> None:
        """Open the RTDE receive and control connections, read the controller version and set the TCP to the
        gripper frame (not in dry run). Ends within `CONNECT_TIMEOUT` per interface or raises
        `ConnectionLostError`."""
        if self.dry_run:
            log.info("[dry run] not connecting to the robot at %s; planning from the home joints", self.config.ip)
            self.guard.tool_pose = self.tcp_pose()
            return
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        log.info("connected to the UR at %s (PolyScope %s; IK %s)", self.config.ip, self.polyscope,
                 "asked of the controller" if self.controller_answers_ik else "computed locally")

    def _open(self) -> None:
        """Build the interfaces that are missing, then check the robot, the control script and the TCP."""
        ip = self.config.ip
        try:
            if self._receive is None:
                self._receive = self._receive_factory(ip)
                if not self._receive.isConnected():  # ur_rtde gives up on a silent controller after 2.5 s
                    raise RuntimeError("the controller accepted the RTDE connection but sent no data")
                self.controller_version = tuple(int(v) for v in self._receive.getControllerVersion())
            if self._control is None:
                self._control = self._control_factory(ip)
        except RuntimeError as exc:
            raise ConnectionLostError(f"cannot connect to the UR controller at {ip}: {exc}") from exc
        self._lost = ""
        self._stamp = None
        self.check_state()
        self._ensure_program(upload=True)
        self._apply_tcp()
        self.guard.tool_pose = self.tcp_pose()

    @property
    def polyscope(self) -> str:
        """The controller's version as text ("5.11.1.108318"; "unknown" before connect)."""
        return ".".join(map(str, self.controller_version)) if self.controller_version else "unknown"

    @property
    def controller_answers_ik(self) -> bool:
        """Whether the controller's `getInverseKinematicsHasSolution` works (PolyScope >= 5.10 / 3.15, F4)."""
        if self.controller_version is None:
            return False
        since = IK_QUERY_SINCE.get(self.controller_version[0])
        return since is not None and tuple(self.controller_version[:2]) >= since

    def _apply_tcp(self) -> None:
        """Set the controller's TCP to the gripper frame and wait until the state shows it (F6)."""
        tcp = ur_pose_from_matrix(self.config.T_flange_gripper)
        if not self._call(self._control, "setTcp", tcp):
            raise MotionError(f"the controller refused the TCP offset {np.round(tcp, 4).tolist()}")
        self._wait_for_tool_pose()

    def _wait_for_tool_pose(self) -> None:
        """Wait until the reported tool pose is the gripper frame at the reported joints (nominal kinematics).

        The receive interface can still hold packages from before `setTcp` (one at least, more when its stream
        trails the control interface's), and a newer timestamp alone does not say the TCP change is in it; the
        pose itself does. Raises when the two disagree for `STATE_TIMEOUT` (a wrong `robot.model` or TCP)."""
        deadline = time.monotonic() + STATE_TIMEOUT
        while True:
            reported, expected = self._actual_pose(), self._gripper_pose_at(self._actual_q())
            distance = float(np.linalg.norm(reported[:3, 3] - expected[:3, 3]))
            angle = float(Rotation.from_matrix(reported[:3, :3].T @ expected[:3, :3]).magnitude())
            if distance <= KINEMATICS_AGREEMENT and angle <= 2 * KINEMATICS_AGREEMENT:
                return
            if time.monotonic() > deadline:
                raise ConnectionLostError(
                    f"the UR at {self.config.ip} reports the tool {distance * 100:.1f} cm and {np.degrees(angle):.1f} "
                    f"deg away from where robot.model {self.config.model!r} and robot.tcp_offset put it, "
                    f"{STATE_TIMEOUT:g} s after setTcp: check the model and the TCP offset")
            time.sleep(0.002)

    def _ensure_program(self, upload: bool) -> bool:
        """Make sure ur_rtde's control script runs on the controller, which ends it on a protective or emergency
        stop (F5): upload it again when `upload` or when such a stop was seen (and has been released, the
        caller checked); otherwise say what to do. True when it was uploaded (the TCP must then be set again)."""
        if self._call(self._control, "isProgramRunning"):
            self._stop_seen = False
            return False
        if not (upload or self._stop_seen):
            raise RobotStoppedError(f"the ur_rtde control script is not running on the UR at {self.config.ip} "
                                    "(stopped from the teach pendant?); cell.arm.reconnect() uploads it again")
        log.warning("the ur_rtde control script is not running on the UR at %s%s; uploading it again",
                    self.config.ip, " after the stop was released" if self._stop_seen else "")
        if not self._call(self._control, "reuploadScript"):
            raise ConnectionLostError(f"could not upload the control script to the UR at {self.config.ip}")
        deadline = time.monotonic() + PROGRAM_START_TIMEOUT
        while not self._call(self._control, "isProgramRunning"):
            if time.monotonic() > deadline:
                raise ConnectionLostError(f"the control script did not start on the UR at {self.config.ip} "
                                          f"within {PROGRAM_START_TIMEOUT:g} s of uploading it")
            time.sleep(0.01)
        self._stop_seen = False
        return True

    def reconnect(self) -> None:
        """Connect again after a lost link, or recover after a released protective/emergency stop.

        Interfaces whose link is up are kept (ur_rtde's `reconnect()` on a live interface kills the process, F1);
        those that were ended when their link dropped are built anew. The control script is uploaded again if it
        is not running (a stop ends it, F5) and the TCP re-applied. Raises `RobotStoppedError` while a stop is
        still active."""
        if self.dry_run:
            return
        for name in ("_control", "_receive"):
            interface = getattr(self, name)
            if interface is not None and not self._link_up(interface):
                self._end(interface)
                setattr(self, name, None)
        self._open()
        log.info("reconnected to the UR at %s", self.config.ip)

    @staticmethod
    def _link_up(interface: Any) -> bool:
        try:
            return bool(interface.isConnected())
        except RuntimeError:
            return False

    @staticmethod
    def _end(*interfaces: Any) -> None:
        """Disconnect interfaces (None skipped), whatever state their links are in, side by side (each ur_rtde
        disconnect sleeps 0.5 s)."""
        def end(interface: Any) -> None:
            try:
                interface.disconnect()
            except RuntimeError as exc:
                log.warning("disconnecting a UR RTDE interface failed: %s", exc)

        threads = [threading.Thread(target=end, args=(interface,)) for interface in interfaces if interface is not None]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    def is_connected(self) -> bool:
        """True when both RTDE connections are up (always True in dry run)."""
        if self.dry_run:
            return True
        return (self._control is not None and self._receive is not None and self._link_up(self._control)
                and self._link_up(self._receive))

    def close(self) -> None:
        """Stop the RTDE script on the controller and disconnect. Safe to call more than once."""
        if self.dry_run:
            return
        if self._control is not None and self._receive is not None and self._link_up(self._control):
            try:
                self._control.stopScript()
            except RuntimeError as exc:  # already gone: nothing left to stop
                log.warning("UR control.stopScript failed during shutdown: %s", exc)
        self._end(self._control, self._receive)
        self._control = self._receive = None

    def _lose_link(self, message: str) -> NoReturn:
        """End both interfaces and raise: after a drop ur_rtde's control interface reconnects on its own, over and
        over, restarting the control script each time, and a command on it races that (SIGSEGV, F2)."""
        self._end(self._control, self._receive)
        self._control = self._receive = None
        self._lost = message
        raise ConnectionLostError(f"{message}; the arm was disconnected (cell.arm.reconnect() connects again)")

    # --------------------------------------------------------------------------------------------------------- state
    def tcp_pose(self) -> np.ndarray:
        """Current `T_world_gripper` (the planned one in dry run), from a state package newer than the call;
        `ConnectionLostError` when the link is down or no new package comes (F7)."""
        if self.dry_run:
            if self._planned_T is None:
                self._planned_T = self._gripper_pose_at(self._planned_q)
            return self._planned_T.copy()
        self._wait_for_new_state()
        return self._actual_pose()

    def joints(self) -> np.ndarray:
        """Current joint angles in radians (the planned ones in dry run); as fresh as `tcp_pose`."""
        if self.dry_run:
            return self._planned_q.copy()
        self._wait_for_new_state()
        return self._actual_q()

    def _actual_pose(self) -> np.ndarray:
        return matrix_from_ur_pose(self._state("getActualTCPPose", "tool pose"))

    def _actual_q(self) -> np.ndarray:
        return self._state("getActualQ", "joint angles")

    def _state(self, getter: str, what: str) -> np.ndarray:
        values = np.asarray(self._call(self._receive, getter), dtype=np.float64)
        if values.shape != (6,):
            raise ConnectionLostError(f"the UR at {self.config.ip} has sent no {what} (got {values.tolist()})")
        if not np.all(np.abs(values) <= _STATE_BOUNDS[getter]):
            self._garbage(f"{what} {values.tolist()}")
        return values

    def _wait_for_new_state(self) -> None:
        """Wait (at most `STALE_STATE`) for a state package that arrived after this call began."""
        self._check_link()
        stamp = self._stamp
        while self._stamp == stamp:
            time.sleep(0.001)
            self._check_link()

    def _check_link(self) -> None:
        """Raise `ConnectionLostError` (ending both interfaces) when a link is down or the controller's timestamp
        has not advanced for `STALE_STATE`."""
        if self._control is None or self._receive is None:
            raise ConnectionLostError(f"the arm is not connected ({self._lost or 'call connect() first'})")
        if not self.is_connected():
            self._lose_link(f"lost the RTDE connection to the UR at {self.config.ip}")
        stamp, now = self._call(self._receive, "getTimestamp"), time.monotonic()
        if not np.isfinite(stamp) or (self._stamp is not None and stamp < self._stamp):
            self._garbage(f"its timestamp went from {self._stamp} to {stamp}")
        if stamp != self._stamp:
            self._stamp, self._stamp_seen = stamp, now
        elif now - self._stamp_seen > STALE_STATE:
            self._lose_link(f"the UR at {self.config.ip} has sent no new state for {now - self._stamp_seen:.1f} s "
                            "(the link is up but the stream stalled)")

    def _garbage(self, what: str) -> NoReturn:
        self._lose_link(f"the UR at {self.config.ip} sends a state that makes no sense ({what}): a corrupt link, or "
                        "not a UR controller on port 30004")

    def check_state(self) -> None:
        """Raise if the connection is down or stale, or the robot is protective/emergency stopped."""
        if self.dry_run:
            return
        self._check_link()
        emergency = self._call(self._receive, "isEmergencyStopped")
        if emergency or self._call(self._receive, "isProtectiveStopped"):
            mode = self._call(self._receive, "getSafetyMode")
            if mode not in SAFETY_MODES:  # a stop bit in a garbled package is no stop
                self._garbage(f"safety mode {mode}")
            self._stop_seen = True
            if emergency:
                raise RobotStoppedError(f"the robot is emergency stopped ({SAFETY_MODES[mode]}); release the e-stop "
                                        "and restart the program")
            raise RobotStoppedError(f"the robot is in a protective stop ({SAFETY_MODES[mode]}); unlock it on the "
                                    "teach pendant")

    def home_pose(self) -> np.ndarray:
        """`T_world_gripper` at the home joints (nominal kinematics)."""
        return self._gripper_pose_at(self.config.home_joints)

    def _gripper_pose_at(self, q: np.ndarray) -> np.ndarray:
        return forward_kinematics(self.config.model, q) @ self.config.T_flange_gripper

    # ------------------------------------------------------------------------------------------------------- motions
    def move_joints(self, q: Any, speed: float, acceleration: float) -> None:
        """moveJ to joint angles `q` (rad); the tool path (nominal kinematics) is checked against the limits, and
        the controller is asked whether the joints and the tool pose there are within its safety limits."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise SafetyError(f"moveJ target must be 6 finite joint angles, got {q.tolist()}")
        self.guard.check_joint_motion(speed, acceleration)
        start = self.joints()
        for s in np.linspace(0.0, 1.0, 21)[1:]:
            self.guard.check_pose(self._gripper_pose_at((1 - s) * start + s * q), f"moveJ (at {s:.0%} of the path)",
                                  self.guard.finger_opening)
        motion = PlannedMotion("moveJ", tuple(map(float, q)), float(speed), float(acceleration))
        goal = self._gripper_pose_at(q)
        if self.dry_run:
            self._record_dry_run(motion)
            self._planned_q = q.copy()
            self._planned_T = self.guard.tool_pose = goal
            return
        if not self._command("isJointsWithinSafetyLimits", list(motion.target)):
            raise SafetyError(f"moveJ: the controller reports joints {np.round(q, 4).tolist()} as outside its "
                              "safety limits")
        self._check_controller_pose(goal, "moveJ")
        self.planned_motions.append(motion)
        self._run(motion, lambda: np.max(np.abs(self._actual_q() - q)) <= JOINT_TOLERANCE)
        self.guard.tool_pose = goal

    def move_linear(self, T_world_gripper: np.ndarray, speed: float, acceleration: float) -> None:
        """moveL the gripper frame to `T_world_gripper` in a straight line; the path is checked first."""
        target = np.asarray(T_world_gripper, dtype=np.float64)
        self.guard.check_tool_motion(speed, acceleration)
        start = self.tcp_pose()
        self.guard.check_linear_path(start, target, "moveL", opening=self.guard.finger_opening)
        pose = ur_pose_from_matrix(target)
        motion = PlannedMotion("moveL", tuple(pose), float(speed), float(acceleration))
        if self.dry_run:
            self._record_dry_run(motion)
            self._planned_T = target.copy()
            self.guard.tool_pose = target.copy()
            return
        self._check_controller_pose(target, "moveL")
        self.planned_motions.append(motion)
        self._run(motion, lambda: _close_to(self._actual_pose(), target))
        self.guard.tool_pose = target.copy()

    def _check_controller_pose(self, T_world_gripper: np.ndarray, what: str) -> None:
        """Ask the controller's own safety configuration (planes, tool limits) about a gripper pose."""
        pose = ur_pose_from_matrix(T_world_gripper)
        if not self._command("isPoseWithinSafetyLimits", pose):
            raise SafetyError(f"{what}: the controller reports {np.round(pose, 4).tolist()} as outside its safety "
                              "limits or unreachable")

    def has_ik_solution(self, T_world_gripper: np.ndarray) -> bool:
        """Whether the arm has joint angles for this gripper pose: the controller's answer where it can give one
        (PolyScope >= 5.10 / 3.15), else (older controllers, dry run) the nominal kinematics' closed-form IK, with
        the flange kept out of the robot's base column."""
        if self.dry_run or not self.controller_answers_ik:
            arm = ARM_MODELS[self.config.model]
            flange = np.asarray(T_world_gripper, dtype=np.float64) @ np.linalg.inv(self.config.T_flange_gripper)
            return bool(np.linalg.norm(flange[:2, 3]) >= arm.base_radius
                        and inverse_kinematics(self.config.model, flange))
        return bool(self._command("getInverseKinematicsHasSolution", ur_pose_from_matrix(T_world_gripper)))

    def stop(self) -> None:
        """Decelerate the arm to rest (best effort: the connection may already be gone). Nothing is sent on a
        control link that is down: ur_rtde reconnects inside the command, racing its own receive thread (F2)."""
        if self.dry_run:
            return
        if not self.is_connected():  # a link is down: the other shares its path, and ur_rtde may be reconnecting
            log.error("cannot tell the arm to stop: the RTDE link to the UR at %s is down (the controller finishes "
                      "or aborts the motion on its own)", self.config.ip)
            return
        try:
            self._control.stopL(self.guard.limits.max_tool_acceleration)
        except RuntimeError as exc:
            log.error("stopping the arm failed: %s", exc)

    def _record_dry_run(self, motion: PlannedMotion) -> None:
        self.planned_motions.append(motion)
        log.info("[dry run] %s target=%s speed=%g acceleration=%g", motion.kind,
                 np.round(motion.target, 4).tolist(), motion.speed, motion.acceleration)

    def _run(self, motion: PlannedMotion, at_target: Callable[[], bool]) -> None:
        """Send `motion` asynchronously and watch it until it ends at its target, stops, or the link drops."""
        self.check_state()
        self.guard.tool_pose = None  # unknown until the motion has ended at its target
        token = self._call(self._control, "getAsyncOperationProgress")
        method = getattr(self._control, motion.kind)
        log.info("%s target=%s speed=%g acceleration=%g", motion.kind, np.round(motion.target, 4).tolist(),
                 motion.speed, motion.acceleration)
        accepted = self._call_motion(method, list(motion.target), motion.speed, motion.acceleration, True)
        if not accepted:
            self.check_state()
            raise MotionError(f"the controller rejected {motion.kind} to {np.round(motion.target, 4).tolist()}")
        deadline = time.monotonic() + self.config.motion_timeout
        while True:
            try:
                self.check_state()
            except ConnectionLostError:
                self.stop()
                raise
            progress = self._call(self._control, "getAsyncOperationProgress")
            if progress < 0 and (progress != token or at_target()):
                break
            if time.monotonic() > deadline:
                self.stop()
                raise MotionError(f"{motion.kind} did not finish within its time limit; the arm was stopped")
            time.sleep(_POLL_PERIOD)
        self.check_state()
        if not at_target():
            raise MotionError(f"{motion.kind} ended away from its target {np.round(motion.target, 4).tolist()}")

    def _call_motion(self, method: Callable, *args: Any) -> Any:
        try:
            return method(*args)
        except RuntimeError as exc:
            self.stop()
            raise ConnectionLostError(f"the UR connection failed while sending a motion: {exc}") from exc

    def _command(self, name: str, *args: Any) -> Any:
        """A command of ur_rtde's control script: the link and the robot are checked first, and the script is
        uploaded again when a released stop ended it (else its answers are False: F5)."""
        self.check_state()
        if self._ensure_program(upload=False):
            self._apply_tcp()
        return self._call(self._control, name, *args)

    def _call(self, interface: Any, name: str, *args: Any) -> Any:
        if interface is None:
            raise ConnectionLostError("the arm is not connected (call connect() first)")
        try:
            return getattr(interface, name)(*args)
        except RuntimeError as exc:
            self.stop()
            raise ConnectionLostError(f"the UR connection failed during {name}: {exc}") from exc
