"""The RTDE server of the emulated UR controller (port 30004), as UR's RTDE guide describes protocol version 2.

Every message is `uint16 size (header included), uint8 type, payload`, big-endian. The server answers protocol
negotiation (V), the controller version (v), output (O) and input (I) recipe setup, start (S) and pause (P); once
started it streams data packages (U) of each output recipe at the controller's rate (125 Hz CB3, 500 Hz e-Series,
or the recipe's lower frequency), and it parses the client's U packages by their input recipe into the
controller's input registers. Variable types follow the RTDE guide, which is also the type table ur_rtde parses
with (vectors are VECTOR6D except the VECTOR3D ones, `joint_mode` VECTOR6INT32, bits UINT64/UINT32).
"""

from __future__ import annotations

import logging
import random
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sim.lab import TcpServer

log = logging.getLogger(__name__)

RTDE_PORT = 30004
PROTOCOL_VERSION = 2

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

#: struct format and value count of each RTDE type.
TYPE_FORMATS = {
    "BOOL": ("?", 1), "UINT8": ("B", 1), "UINT32": ("I", 1), "UINT64": ("Q", 1), "INT32": ("i", 1),
    "DOUBLE": ("d", 1), "VECTOR3D": ("3d", 3), "VECTOR6D": ("6d", 6), "VECTOR6INT32": ("6i", 6),
    "VECTOR6UINT32": ("6I", 6),
}

_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE", "target_q": _V6, "target_qd": _V6, "target_qdd": _V6, "target_current": _V6,
    "target_moment": _V6, "actual_q": _V6, "actual_qd": _V6, "actual_qdd": _V6, "actual_current": _V6,
    "actual_current_window": _V6, "joint_control_output": _V6, "actual_TCP_pose": _V6, "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6, "target_TCP_pose": _V6, "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64", "joint_temperatures": _V6, "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32", "joint_mode": "VECTOR6INT32", "safety_mode": "INT32", "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D", "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE", "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "actual_joint_voltage": _V6, "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32", "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32", "safety_status_bits": "UINT32", "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE", "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE", "io_current": "DOUBLE", "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32", "tool_analog_input0": "DOUBLE", "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32", "tool_output_current": "DOUBLE", "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE", "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32", "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8", "tool_digital_output1_mode": "UINT8", "payload": "DOUBLE",
    "payload_cog": "VECTOR3D", "payload_inertia": _V6, "script_control_line": "UINT32", "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE", "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    **{f"output_int_register_{i}": "INT32" for i in range(48)},
    **{f"output_double_register_{i}": "DOUBLE" for i in range(48)},
    **{f"input_int_register_{i}": "INT32" for i in range(48)},
    **{f"input_double_register_{i}": "DOUBLE" for i in range(48)},
    **{f"output_bit_register_{i}": "BOOL" for i in range(64, 128)},
    **{f"input_bit_register_{i}": "BOOL" for i in range(64, 128)},
}
#: Outputs that exist only from a PolyScope version on: name -> (CB3 minimum or None, e-Series minimum or None).
OUTPUT_MIN_VERSION: dict[str, tuple[tuple[int, int] | None, tuple[int, int] | None]] = {
    "ft_raw_wrench": (None, (5, 9)), "payload": ((3, 11), (5, 5)), "payload_cog": ((3, 11), (5, 5)),
    "payload_inertia": ((3, 15), (5, 11)), "elbow_position": ((3, 5), (5, 0)), "elbow_velocity": ((3, 5), (5, 0)),
}
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE", "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8", "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8", "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6,
    **{f"input_int_register_{i}": "INT32" for i in range(48)},
    **{f"input_double_register_{i}": "DOUBLE" for i in range(48)},
    **{f"input_bit_register_{i}": "BOOL" for i in range(64, 128)},
}


def output_available(name: str, version: tuple[int, int, int, int]) -> bool:
    """Whether the controller of PolyScope `version` offers output `name` at all."""
    if name not in OUTPUT_TYPES:
        return False
    if name not in OUTPUT_MIN_VERSION:
        return True
    cb3, eseries = OUTPUT_MIN_VERSION[name]
    needed = cb3 if version[0] < 5 else eseries
    return needed is not None and tuple(version[:2]) >= needed


def message(kind: int, payload: bytes = b"") -> bytes:
    """One RTDE message: header (size, type) + payload."""
    return struct.pack(">HB", 3 + len(payload), kind) + payload


@dataclass
class OutputRecipe:
    """An output recipe: names, their packed layout, and every how many controller ticks it is sent."""

    recipe_id: int
    names: list[str]
    layout: struct.Struct
    every: int


@dataclass
class InputRecipe:
    """An input recipe: the names of the values a client's U package carries, and their packed layout."""

    recipe_id: int
    names: list[str]
    layout: struct.Struct
    counts: list[int]


def _layout(names: list[str], types: dict[str, str]) -> tuple[struct.Struct, list[int]]:
    formats = [TYPE_FORMATS[types[name]] for name in names]
    return struct.Struct(">B" + "".join(f for f, _ in formats)), [n for _, n in formats]


@dataclass
class Connection:
    """One RTDE client: its socket, recipes and streaming state."""

    sock: socket.socket
    peer: str
    outputs: dict[int, OutputRecipe] = field(default_factory=dict)
    inputs: dict[int, InputRecipe] = field(default_factory=dict)
    started: bool = False
    packages: int = 0
    inputs_received: int = 0
    connected_at: float = field(default_factory=time.monotonic)
    delayed: deque[tuple[float, bytes]] = field(default_factory=deque)
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    closed: bool = False

    def send(self, data: bytes) -> bool:
        """Send `data`; False (and the connection closed) when the client is gone or stopped reading."""
        with self.send_lock:
            if self.closed:
                return False
            try:
                self.sock.sendall(data)
                return True
            except OSError:
                self.close()
                return False

    def close(self) -> None:
        """Shut the socket down (the reader thread then ends and closes it)."""
        self.closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class RTDEServer(TcpServer):
    """Serves RTDE to any number of clients. `publish(state)` (the controller's clock) streams one tick.

    `version` is the controller's (major, minor, bugfix, build); `frequency` its RTDE rate (Hz); `write_inputs`
    receives {input name: value} from each client U package. Faults: `streaming = False` answers every setup but
    never sends a data package (F3); `garbage` = "values" sends data packages of the right size filled with random
    bytes, "bytes" sends a stream of random bytes instead of packages; `state_delay` (s) holds back the packages
    of every client whose recipes lack `output_int_register_0` (ur_rtde's receive interface, not its control
    interface), so that the receive interface lags the control interface.
    """

    def __init__(self, host: str, version: tuple[int, int, int, int], frequency: float,
                 write_inputs: Callable[[dict[str, Any]], None], port: int = RTDE_PORT) -> None:
        self.version = version
        self.frequency = frequency
        self.write_inputs = write_inputs
        self.streaming = True
        self.garbage: str | None = None
        self.state_delay = 0.0
        self._rng = random.Random(0)
        self._connections: list[Connection] = []
        self._tick = 0
        super().__init__(host, port)

    # ----------------------------------------------------------------------------------------------- connections
    def connections(self) -> list[Connection]:
        """The clients connected now."""
        with self._lock:
            return list(self._connections)

    def serve_client(self, sock: socket.socket) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(1.0)  # a client that stops reading is dropped after 1 s instead of stalling the clock
        peer = "{}:{}".format(*sock.getpeername()[:2])
        connection = Connection(sock, peer)
        with self._lock:
            self._connections.append(connection)
        log.info("RTDE client %s connected", peer)
        buffer = b""
        try:
            while not connection.closed:
                try:
                    chunk = sock.recv(65536)
                except TimeoutError:
                    continue
                if not chunk:
                    break
                buffer += chunk
                while len(buffer) >= 3:
                    size, kind = struct.unpack_from(">HB", buffer)
                    if size < 3:
                        raise ValueError(f"message of size {size}")
                    if len(buffer) < size:
                        break
                    payload, buffer = buffer[3:size], buffer[size:]
                    self._handle(connection, kind, payload)
        except (ValueError, struct.error) as exc:
            log.warning("RTDE client %s: %s", peer, exc)
        finally:
            connection.closed = True
            with self._lock:
                self._connections.remove(connection)
            log.info("RTDE client %s disconnected", peer)

    # -------------------------------------------------------------------------------------------------- messages
    def _handle(self, connection: Connection, kind: int, payload: bytes) -> None:
        if kind == REQUEST_PROTOCOL_VERSION:
            (requested,) = struct.unpack(">H", payload[:2])
            connection.send(message(kind, struct.pack(">B", requested == PROTOCOL_VERSION)))
        elif kind == GET_URCONTROL_VERSION:
            connection.send(message(kind, struct.pack(">IIII", *self.version)))
        elif kind == SETUP_OUTPUTS:
            self._setup_outputs(connection, payload)
        elif kind == SETUP_INPUTS:
            self._setup_inputs(connection, payload)
        elif kind == START:
            connection.started = True
            connection.send(message(kind, b"\x01"))
        elif kind == PAUSE:
            connection.started = False
            connection.send(message(kind, b"\x01"))
        elif kind == DATA_PACKAGE:
            self._receive_inputs(connection, payload)
        else:
            log.warning("RTDE client %s sent unknown message type %r", connection.peer, chr(kind))

    def _setup_outputs(self, connection: Connection, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = [n for n in payload[8:].decode("ascii", "replace").split(",") if n]
        types = [OUTPUT_TYPES[n] if output_available(n, self.version) else "NOT_FOUND" for n in names]
        recipe_id = 0
        if "NOT_FOUND" not in types and names:
            recipe_id = len(connection.outputs) + 1
            layout, _ = _layout(names, OUTPUT_TYPES)
            every = max(1, round(self.frequency / frequency)) if 0 < frequency < self.frequency else 1
            connection.outputs[recipe_id] = OutputRecipe(recipe_id, names, layout, every)
        log.info("RTDE client %s output recipe %d at %g Hz: %s", connection.peer, recipe_id, frequency, ",".join(names))
        connection.send(message(SETUP_OUTPUTS, bytes([recipe_id]) + ",".join(types).encode()))

    def _setup_inputs(self, connection: Connection, payload: bytes) -> None:
        names = [n for n in payload.decode("ascii", "replace").split(",") if n]
        types = [INPUT_TYPES.get(n, "NOT_FOUND") for n in names]
        recipe_id = 0
        if "NOT_FOUND" not in types and names:
            recipe_id = len(connection.inputs) + 1
            layout, counts = _layout(names, INPUT_TYPES)
            connection.inputs[recipe_id] = InputRecipe(recipe_id, names, layout, counts)
        log.debug("RTDE client %s input recipe %d: %s", connection.peer, recipe_id, ",".join(names))
        connection.send(message(SETUP_INPUTS, bytes([recipe_id]) + ",".join(types).encode()))

    def _receive_inputs(self, connection: Connection, payload: bytes) -> None:
        recipe = connection.inputs.get(payload[0]) if payload else None
        if recipe is None or len(payload) != recipe.layout.size:
            log.warning("RTDE client %s sent a data package for unknown input recipe or of wrong size (%d bytes)",
                        connection.peer, len(payload))
            return
        flat = recipe.layout.unpack(payload)[1:]
        values: dict[str, Any] = {}
        index = 0
        for name, count in zip(recipe.names, recipe.counts):
            values[name] = flat[index] if count == 1 else list(flat[index:index + count])
            index += count
        connection.inputs_received += 1
        self.write_inputs(values)

    # ------------------------------------------------------------------------------------------------- streaming
    def publish(self, state: Callable[[str], Any]) -> None:
        """Send one tick's data package to every started client whose recipe is due; `state(name)` gives a value."""
        self._tick += 1
        if not self.streaming:
            return
        now = time.monotonic()
        for connection in self.connections():
            if not connection.started:
                continue
            delay = self.state_delay if not any("output_int_register_0" in r.names
                                                for r in connection.outputs.values()) else 0.0
            while connection.delayed and connection.delayed[0][0] <= now:
                if connection.send(connection.delayed.popleft()[1]):
                    connection.packages += 1
            for recipe in connection.outputs.values():
                if self._tick % recipe.every:
                    continue
                if self.garbage == "bytes":
                    data = bytes(self._rng.getrandbits(8) for _ in range(recipe.layout.size))
                elif self.garbage == "values":
                    data = message(DATA_PACKAGE, bytes([recipe.recipe_id])
                                   + bytes(self._rng.getrandbits(8) for _ in range(recipe.layout.size - 1)))
                else:
                    flat: list[Any] = [recipe.recipe_id]
                    for name in recipe.names:
                        value = state(name)
                        if isinstance(value, (list, tuple)):
                            flat.extend(value)
                        else:
                            flat.append(value)
                    data = message(DATA_PACKAGE, recipe.layout.pack(*flat))
                if delay > 0 or connection.delayed:
                    connection.delayed.append((now + delay, data))
                elif connection.send(data):
                    connection.packages += 1
