"""The emulated UR controller: the ArmModel protocol, the control clock and the program that stands in for
ur_rtde's uploaded `rtde_control.script` (the script port and what is read of the script: sim/lab/script.py).

ur_rtde drives the robot through RTDE registers read by the script it uploads: the command goes in
`input_int_register_0`, its arguments in `input_double_register_0..13` and `input_int_register_1` (the async flag
for motions); the script answers in `output_int_register_0` (1 = ready for a command, 2 = done with it),
`output_int_register_1` (yes/no answers), `output_double_register_0..5` (joint or pose answers) and
`output_int_register_2` (async progress: write count << 16, operation id << 24, bit 15 while an async operation
runs). `Controller` runs that program loop once per controller tick, with the command semantics modelled on an
`ArmModel`. The uploaded script is READ: a call that ur_rtde stripped for this PolyScope version (e.g.
`get_inverse_kin_has_solution` below 5.10 / 3.15, F4) is not answered, so its register keeps what it last held.

Modelled controller behaviour (guesses where UR does not document it): a protective or emergency stop halts the
arm and STOPS the program (runtime_state leaves PLAYING) until a script is uploaded again; a script arriving while
the robot is stopped, or (PolyScope >= 5.6) while remote control is refused, is not started; a runtime error in
the script (no IK solution, joint limit) stops the program; the TCP a program set returns to the flange when the
program ends; pose samples in a data package are taken at the start
of the tick, before the program runs, so a `set_tcp` shows in the pose one package after it is acknowledged.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from typing import Any, Protocol

import numpy as np

from sim.lab.rtde import OUTPUT_TYPES, TYPE_FORMATS, RTDEServer
from sim.lab.script import (
    COMMAND_NAMES,
    REALTIME_COMMANDS,
    Program,
    ScriptRuntimeError,
    ScriptServer,
)
from sim.lab.settings import ControllerSettings
from sim.robot import HOME_Q

log = logging.getLogger(__name__)

#: The twin's home joints on the wire: the RTDE base frame has the table along +x with the shoulder pan at pi.
HOME_Q_WIRE = np.asarray(HOME_Q, dtype=np.float64) + np.array([np.pi, 0.0, 0.0, 0.0, 0.0, 0.0])
#: Deceleration of a stop the controller makes itself (safety stop, program end), in the current motion's units
#: (rad/s^2 for a joint move, m/s^2 for a linear one).
HALT_DECELERATION = 10.0

# runtime_state, robot_mode, safety_mode values and status bits (UR's RTDE guide).
STOPPED, PLAYING, PAUSED = 1, 2, 4
ROBOT_MODE_POWER_OFF, ROBOT_MODE_RUNNING = 3, 7
SAFETY_MODES = {"normal": 1, "protective_stop": 3, "emergency_stop": 7}
SAFETY_BITS = {"normal": 1 << 0, "protective_stop": (1 << 2) | (1 << 10),
               "emergency_stop": (1 << 6) | (1 << 7) | (1 << 10)}
ROBOT_POWER_ON_BIT, ROBOT_PROGRAM_RUNNING_BIT = 1 << 0, 1 << 1
JOINT_MODE_RUNNING = 253



class ArmModel(Protocol):
    """What the controller needs of an arm. Poses are UR pose vectors [x, y, z, rx, ry, rz] in the RTDE base frame
    with the active TCP; joints in rad (home shoulder pan = pi). `move_*` and `stop` return at once; `is_moving()`
    is True from the moment a motion that goes anywhere has been started until the arm is at rest again."""

    safety_status: str  # "normal" | "protective_stop" | "emergency_stop"

    def step(self, dt: float) -> None: ...
    def actual_q(self) -> list[float]: ...
    def actual_qd(self) -> list[float]: ...
    def actual_tcp_pose(self) -> list[float]: ...
    def set_tcp(self, pose: list[float]) -> None: ...
    def move_joints(self, q: list[float], speed: float, acceleration: float) -> None: ...
    def move_linear(self, pose: list[float], speed: float, acceleration: float) -> None: ...
    def stop(self, deceleration: float) -> None: ...
    def is_moving(self) -> bool: ...
    def pose_within_limits(self, pose: list[float]) -> bool: ...
    def joints_within_limits(self, q: list[float]) -> bool: ...
    def ik_has_solution(self, pose: list[float], qnear: list[float] | None) -> bool: ...
    def inverse_kinematics(self, pose: list[float], qnear: list[float] | None) -> list[float] | None: ...


class Controller:
    """The controller: one clock ticking at the RTDE rate steps the arm, runs the program and streams RTDE."""

    def __init__(self, arm: ArmModel, settings: ControllerSettings, host: str = "127.0.0.1") -> None:
        self.arm = arm
        self.settings = settings
        self.lock = threading.RLock()
        self.inputs: dict[str, Any] = {}
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.runtime_state = STOPPED
        self.program: Program | None = None
        self.tcp = [0.0] * 6
        self.remote_control = True
        self.last_stop = ""
        self.safety = arm.safety_status
        self.safety_stop_time = 0.0
        self.uploads = 0
        self.refused_uploads = 0
        self.commands: Counter[str] = Counter()
        self.ticks = 0
        self.late_ticks = 0
        self.max_tick_duration = 0.0
        self._pending_program: tuple[Program, float] | None = None
        self._t0 = time.monotonic()
        self._snapshot: dict[str, Any] = {}
        self._previous_pose: list[float] | None = None
        self._closing = threading.Event()
        self.rtde = RTDEServer(host, settings.polyscope, settings.frequency, self.write_inputs)
        self.script_port = ScriptServer(host, self.upload)
        self._clock = threading.Thread(target=self._run_clock, name="controller-clock", daemon=True)

    # ---------------------------------------------------------------------------------------------------- clock
    def start(self) -> None:
        """Start ticking."""
        self._clock.start()

    def close(self) -> None:
        """Stop the clock and close the RTDE and script ports."""
        self._closing.set()
        if self._clock.is_alive():
            self._clock.join(timeout=2.0)
        self.rtde.close()
        self.script_port.close()

    def _run_clock(self) -> None:
        period = 1.0 / self.settings.frequency
        last = next_tick = time.monotonic()
        while not self._closing.is_set():
            next_tick += period
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -5 * period:  # far behind (machine overloaded): resynchronise rather than burst
                self.late_ticks += 1
                next_tick = time.monotonic()
            now = time.monotonic()
            try:
                self.tick(now - last)
            except Exception:  # keep the controller alive; the failure is in the log
                log.exception("controller tick failed")
            last = now
            self.max_tick_duration = max(self.max_tick_duration, time.monotonic() - now)

    def tick(self, dt: float) -> None:
        """One controller cycle: step the arm, sample it, watch safety, run the program, stream one package."""
        with self.lock:
            now = time.monotonic()
            self.ticks += 1
            self.arm.step(dt)
            q = list(map(float, self.arm.actual_q()))
            qd = list(map(float, self.arm.actual_qd()))
            pose = list(map(float, self.arm.actual_tcp_pose()))
            speed = [0.0] * 6
            if self._previous_pose is not None and dt > 0:
                speed[:3] = [(a - b) / dt for a, b in zip(pose[:3], self._previous_pose[:3])]
            self._previous_pose = pose
            self._watch_safety(now)
            self._start_pending_program(now)
            if self.runtime_state == PLAYING:
                self._program_step()
            self._snapshot = self._state_values(now, q, qd, pose, speed)
        self.rtde.publish(self.value)

    def value(self, name: str) -> Any:
        """The current value of RTDE output `name`."""
        value = self._snapshot.get(name)
        return STATIC_OUTPUTS[name] if value is None else value

    def _state_values(self, now: float, q: list[float], qd: list[float], pose: list[float],
                      speed: list[float]) -> dict[str, Any]:
        safety = self.safety
        running = self.runtime_state == PLAYING
        robot_bits = ((0 if safety == "emergency_stop" else ROBOT_POWER_ON_BIT)
                      | (ROBOT_PROGRAM_RUNNING_BIT if running else 0))
        values: dict[str, Any] = {
            "timestamp": now - self._t0, "actual_q": q, "target_q": q, "actual_qd": qd, "target_qd": qd,
            "actual_TCP_pose": pose, "target_TCP_pose": pose, "actual_TCP_speed": speed, "target_TCP_speed": speed,
            "runtime_state": self.runtime_state, "robot_status_bits": robot_bits,
            "safety_status_bits": SAFETY_BITS[safety], "safety_mode": SAFETY_MODES[safety],
            "safety_status": SAFETY_MODES[safety],
            "robot_mode": ROBOT_MODE_POWER_OFF if safety == "emergency_stop" else ROBOT_MODE_RUNNING,
        }
        values.update(zip(_OUT_INT_NAMES, self.out_int))
        values.update(zip(_OUT_DOUBLE_NAMES, self.out_double))
        values.update(self.inputs)
        return values

    # ------------------------------------------------------------------------------------------------- inputs
    def write_inputs(self, values: dict[str, Any]) -> None:
        """Input registers from an RTDE client's data package."""
        with self.lock:
            self.inputs.update(values)

    def _in_int(self, i: int) -> int:
        return int(self.inputs.get(f"input_int_register_{i}", 0))

    def _in_double(self, i: int) -> float:
        return float(self.inputs.get(f"input_double_register_{i}", 0.0))

    def _in_vector(self, start: int) -> list[float]:
        return [self._in_double(start + k) for k in range(6)]

    # ------------------------------------------------------------------------------------------ safety, program
    def _watch_safety(self, now: float) -> None:
        status = self.arm.safety_status
        if status == self.safety:
            return
        log.warning("safety status %s -> %s", self.safety, status)
        if status != "normal":
            self.safety_stop_time = now
            self.arm.stop(HALT_DECELERATION)
            if self.runtime_state != STOPPED:
                self._end_program(status.replace("_", " "))
        self.safety = status

    def upload(self, text: str) -> None:
        """A complete script arrived on the script port: it starts after the controller's start delay."""
        with self.lock:
            self.uploads += 1
            if self.settings.remote_control_exists and not self.remote_control:
                self.refused_uploads += 1
                log.warning("script %d not started: the robot is in local control", self.uploads)
                return
            self._pending_program = (Program.parse(text), time.monotonic() + self.settings.program_start_delay)

    def _start_pending_program(self, now: float) -> None:
        if self._pending_program is None or now < self._pending_program[1]:
            return
        program, _ = self._pending_program
        self._pending_program = None
        if self.safety != "normal":
            self.refused_uploads += 1
            log.warning("program %s not started: the robot is in a %s", program.name, self.safety.replace("_", " "))
            return
        if self.runtime_state != STOPPED:
            self._end_program("replaced by a new script")
        self.program = program
        self.runtime_state = PLAYING
        self._write_async(-1)  # reset_async_progress()
        self.out_int[0] = 1  # signal_ready()
        log.info("program %s running (IK check %s)", program.name, "present" if program.has_ik_check else "stripped")

    def _end_program(self, reason: str) -> None:
        if self.arm.is_moving() and self.safety == "normal":
            self.arm.stop(HALT_DECELERATION)
        self.program = None
        self.runtime_state = STOPPED
        self.last_stop = reason
        self.tcp = [0.0] * 6  # set_tcp lasts as long as its program: the installation's TCP (the flange) is back
        self.arm.set_tcp(list(self.tcp))
        log.info("program stopped: %s", reason)

    def stop_program(self, reason: str) -> None:
        """Stop the running program (dashboard `stop`)."""
        with self.lock:
            if self.runtime_state != STOPPED:
                self._end_program(reason)

    def pause_program(self) -> bool:
        """Pause a playing program; False if none plays."""
        with self.lock:
            if self.runtime_state != PLAYING:
                return False
            self.runtime_state = PAUSED
            return True

    def resume_program(self) -> bool:
        """Resume a paused program; False if none is paused."""
        with self.lock:
            if self.runtime_state != PAUSED or self.safety != "normal":
                return False
            self.runtime_state = PLAYING
            return True

    def _write_async(self, value: int) -> None:
        program = self.program
        assert program is not None
        program.write_count = 0 if program.write_count >= 127 else program.write_count + 1
        if value == 0:
            program.operation_id = 0 if program.operation_id >= 127 else program.operation_id + 1
        register = program.write_count * 65536 + program.operation_id * 16777216
        if value >= 0:
            register += min(value, 32767) + 32768
        self.out_int[2] = register

    def _program_step(self) -> None:
        """One pass of the script's main loop (one `sync()`), plus its async threads."""
        program = self.program
        assert program is not None
        if program.async_kind and not self.arm.is_moving():
            program.async_kind = None
            self._write_async(-1)
        if program.pending:
            if self.arm.is_moving():
                return
            program.pending = None
            self.out_int[0] = 2
            return
        command = self._in_int(0)
        if command in REALTIME_COMMANDS:
            self.commands[f"not emulated {command}"] += 1
            self.out_int[0] = 1
        elif command == 0:
            program.executing = False
            self.out_int[0] = 1
        elif not program.executing:
            program.executing = True
            self._process(program, command)

    def _process(self, program: Program, command: int) -> None:
        name = COMMAND_NAMES.get(command, f"not emulated {command}")
        self.commands[name] += 1
        if command == 255:
            self._end_program("stop script")
            return
        handler = _HANDLERS.get(command)
        if handler is None:
            log.warning("command %d is not emulated; answered as done", command)
        else:
            try:
                handler(self, program)
            except ScriptRuntimeError as exc:
                self._end_program(f"runtime error: {exc}")
                return
        if program.pending is None:
            self.out_int[0] = 2

    def _stop_async_move(self, program: Program) -> None:
        if program.async_kind == "move":
            program.async_kind = None
            self._write_async(-1)

    # ------------------------------------------------------------------------------------------------ commands
    def _movej(self, program: Program, q: list[float] | None = None) -> None:
        if q is None:
            q = self._in_vector(0)
        if not self.arm.joints_within_limits(q):
            raise ScriptRuntimeError(f"movej target {np.round(q, 4).tolist()} is outside the joint limits")
        self._stop_async_move(program)
        self.arm.move_joints(q, *self._speed_and_acceleration("movej"))
        self._motion_started(program, "movej")

    def _movej_ik(self, program: Program) -> None:
        q = self.arm.inverse_kinematics(self._in_vector(0), None)
        if q is None:
            raise ScriptRuntimeError("movej_ik: no inverse kinematics solution")
        self._movej(program, q)

    def _movel(self, program: Program) -> None:
        pose = self._in_vector(0)
        if self.arm.inverse_kinematics(pose, list(self.arm.actual_q())) is None:
            raise ScriptRuntimeError(f"movel target {np.round(pose, 4).tolist()} has no inverse kinematics solution")
        self._stop_async_move(program)
        self.arm.move_linear(pose, *self._speed_and_acceleration("movel"))
        self._motion_started(program, "movel")

    def _speed_and_acceleration(self, name: str) -> tuple[float, float]:
        speed, acceleration = self._in_double(6), self._in_double(7)
        if not (speed > 0 and acceleration > 0):
            raise ScriptRuntimeError(f"{name} with speed {speed} and acceleration {acceleration}")
        return speed, acceleration

    def _motion_started(self, program: Program, name: str) -> None:
        if self._in_int(1) == 1:
            self._write_async(0)
            program.async_kind = "move"
        else:
            program.pending = name

    def _stop(self, program: Program) -> None:
        deceleration = self._in_double(0)
        if deceleration <= 0:
            raise ScriptRuntimeError(f"stop with deceleration {deceleration}")
        if program.async_kind == "stop":  # a second stop restarts the first one's thread
            program.async_kind = None
            self._write_async(-1)
        else:
            self._stop_async_move(program)
        self.arm.stop(deceleration)
        if self._in_int(1) == 1:
            self._write_async(0)
            program.async_kind = "stop"
        else:
            program.pending = "stop"

    def _set_tcp(self, program: Program) -> None:
        self.tcp = self._in_vector(0)
        self.arm.set_tcp(list(self.tcp))

    def _get_tcp_offset(self, program: Program) -> None:
        if program.has_tcp_offset:
            self.out_double[:6] = self.tcp

    def _pose_within_limits(self, program: Program) -> None:
        self.out_int[1] = int(bool(self.arm.pose_within_limits(self._in_vector(0))))

    def _joints_within_limits(self, program: Program) -> None:
        self.out_int[1] = int(bool(self.arm.joints_within_limits(self._in_vector(0))))

    def _ik_has_solution(self, program: Program, with_qnear: bool) -> None:
        if not program.has_ik_check:  # ur_rtde stripped the call: register 1 keeps its last value (F4)
            return
        qnear = self._in_vector(6) if with_qnear else None
        self.out_int[1] = int(bool(self.arm.ik_has_solution(self._in_vector(0), qnear)))

    def _inverse_kinematics(self, program: Program, with_qnear: bool) -> None:
        q = self.arm.inverse_kinematics(self._in_vector(0), self._in_vector(6) if with_qnear else None)
        if q is None:
            raise ScriptRuntimeError("get_inverse_kin: no solution")
        self.out_double[:6] = list(map(float, q))

    def _protective_stop(self, program: Program) -> None:
        if program.has_protective_stop:
            self.arm.safety_status = "protective_stop"

    def _is_steady(self, program: Program) -> None:
        self.out_int[1] = int(not self.arm.is_moving())

    # --------------------------------------------------------------------------------------------------- report
    def state(self) -> dict[str, Any]:
        """A JSON-able summary for the control channel's `state`."""
        with self.lock:
            elapsed = time.monotonic() - self._t0
            clients = [{"peer": c.peer, "started": c.started, "packages": c.packages,
                        "rate_hz": round(c.packages / max(time.monotonic() - c.connected_at, 1e-9), 1),
                        "inputs_received": c.inputs_received,
                        "outputs": [len(r.names) for r in c.outputs.values()]} for c in self.rtde.connections()]
            return {
                "generation": self.settings.generation, "polyscope": ".".join(map(str, self.settings.polyscope)),
                "frequency": self.settings.frequency, "runtime_state": self.runtime_state,
                "program_running": self.runtime_state == PLAYING,
                "program": self.program.name if self.program else None,
                "ik_check_in_script": self.program.has_ik_check if self.program else None,
                "last_stop": self.last_stop, "safety_status": self.safety, "remote_control": self.remote_control,
                "q": list(map(float, self.arm.actual_q())), "tcp_pose": list(map(float, self.arm.actual_tcp_pose())),
                "tcp": list(self.tcp), "moving": bool(self.arm.is_moving()), "uploads": self.uploads,
                "refused_uploads": self.refused_uploads, "commands": dict(self.commands), "ticks": self.ticks,
                "tick_rate_hz": round(self.ticks / max(elapsed, 1e-9), 1), "late_ticks": self.late_ticks,
                "max_tick_ms": round(1000 * self.max_tick_duration, 3), "streaming": self.rtde.streaming,
                "rtde_clients": clients,
            }


_HANDLERS = {
    1: Controller._movej, 2: Controller._movej_ik, 3: Controller._movel, 29: Controller._set_tcp,
    30: lambda c, p: c._inverse_kinematics(p, True), 31: Controller._protective_stop, 33: Controller._stop,
    34: Controller._stop, 36: Controller._pose_within_limits, 37: Controller._joints_within_limits,
    40: Controller._get_tcp_offset, 46: lambda c, p: c._inverse_kinematics(p, False), 47: Controller._is_steady,
    60: lambda c, p: c._ik_has_solution(p, False), 61: lambda c, p: c._ik_has_solution(p, True),
}
_OUT_INT_NAMES = [f"output_int_register_{i}" for i in range(48)]
_OUT_DOUBLE_NAMES = [f"output_double_register_{i}" for i in range(48)]


def _static_value(name: str, kind: str) -> Any:
    fmt, count = TYPE_FORMATS[kind]
    zero: Any = 0.0 if fmt[-1] == "d" else (False if fmt == "?" else 0)
    return [zero] * count if count > 1 else zero


#: Values of the outputs the emulator does not model: zeros, except plausible supply voltages and joint modes.
STATIC_OUTPUTS: dict[str, Any] = {name: _static_value(name, kind) for name, kind in OUTPUT_TYPES.items()}
STATIC_OUTPUTS.update({"speed_scaling": 1.0, "target_speed_fraction": 1.0, "actual_main_voltage": 48.0,
                       "actual_robot_voltage": 48.0, "joint_mode": [JOINT_MODE_RUNNING] * 6,
                       "joint_temperatures": [30.0] * 6, "actual_joint_voltage": [47.5] * 6})
