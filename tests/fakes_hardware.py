"""Stand-ins for the real cell's hardware, speaking the same protocols / calls as the real devices.

- `FakeRobotiqServer`: a TCP server on 127.0.0.1 (ephemeral port, one thread, stops by itself after `lifetime`)
  that speaks the Robotiq URCap ASCII protocol (SET/GET, `ack`, `<VAR> <value>`) and simulates activation, finger
  travel, an object between the fingers (OBJ 2), the object slipping out (OBJ 3), faults and dropped connections.
- `FakeUR` with `FakeRTDEControl` / `FakeRTDEReceive`: the ur_rtde calls the arm uses, recording every command,
  simulating asynchronous motions, protective stops (which end the control script), a connection that drops
  mid-motion and a stalled state stream. (tests/test_lab_arm_faults.py runs the real ur_rtde at the wire.)
- `FakePipeline` / `FakeAlign`: pyrealsense2's pipeline and align objects serving prerecorded `Frame`s as raw
  z16 depth + rgb8 colour with intrinsics and a depth scale.
- `synthetic_frames`: RGB-D frames of a box on a table, ray cast with trimesh (until the simulated cameras are used).
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import trimesh
import yaml

from hardware.config import load_config
from hardware.ur import forward_kinematics, matrix_from_ur_pose, ur_pose_from_matrix
from seggrasp.cell import Frame

# ---------------------------------------------------------------------------------------------------- Robotiq


class FakeRobotiqServer:
    """A Robotiq URCap socket on 127.0.0.1. Use as a context manager; it also stops by itself after `lifetime` s."""

    VARIABLES = ("ACT", "GTO", "ATR", "ARD", "POS", "PRE", "SPE", "FOR", "STA", "OBJ", "FLT")

    def __init__(self, *, object_register: int | None = None, open_register: int = 3, closed_register: int = 230,
                 newline: bool = False, activation_time: float = 0.05, travel_time: float = 0.05,
                 lifetime: float = 30.0) -> None:
        self.object_register = object_register
        self.open_register, self.closed_register = open_register, closed_register
        self.newline = newline
        self.activation_time, self.travel_time = activation_time, travel_time
        self.lines: list[str] = []
        self.drop_on: str | None = None  # close the connection when a line starting with this arrives
        self.silent_on: str | None = None  # never answer a line starting with this (timeouts)
        # line prefix -> how to send the reply instead of at once: split_reply / huge_reply / trickle_reply
        self.misbehave: dict[str, Callable[[socket.socket, bytes], None]] = {}
        self.connections = 0
        self.vars = {name: 0 for name in self.VARIABLES}
        self.position = float(open_register)
        self._motion: tuple[float, float, float] | None = None  # (start position, goal position, start time)
        self._activated_at: float | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind(("127.0.0.1", 0))
        self._server.listen(2)
        self._server.settimeout(0.05)
        self.port = self._server.getsockname()[1]
        self._deadline = time.monotonic() + lifetime
        self._thread = threading.Thread(target=self._serve, name="fake-robotiq", daemon=True)
        self._thread.start()

    def __enter__(self) -> FakeRobotiqServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._server.close()

    # --------------------------------------------------------------------------------------------- simulation
    def inject_fault(self, code: int) -> None:
        with self._lock:
            self.vars["FLT"] = code

    def slip(self) -> None:
        """The object slides out of the fingers: they continue towards the requested position."""
        with self._lock:
            self.object_register = None
            if self.vars["OBJ"] == 2:
                goal = float(np.clip(self.vars["PRE"], self.open_register, self.closed_register))
                self._motion = (self.position, goal, time.monotonic())
                self.vars["OBJ"] = 0

    def _update(self) -> None:
        now = time.monotonic()
        if self.vars["ACT"] == 1 and self._activated_at is not None and self.vars["STA"] == 1:
            if now - self._activated_at >= self.activation_time:
                self.vars["STA"] = 3
        if self._motion is not None:
            start, goal, t0 = self._motion
            fraction = min(1.0, (now - t0) / self.travel_time)
            position = start + fraction * (goal - start)
            obj = self.object_register
            if obj is not None and goal > start and start <= obj <= position:
                self.position, self._motion, self.vars["OBJ"] = float(obj), None, 2
            elif obj is not None and goal < start and position <= obj <= start:
                self.position, self._motion, self.vars["OBJ"] = float(obj), None, 1
            else:
                self.position = position
                if fraction >= 1.0:
                    self._motion, self.vars["OBJ"] = None, 3

    def _set(self, name: str, value: int) -> None:
        if name == "ACT":
            if value == 0:
                self.vars.update(ACT=0, STA=0, GTO=0, OBJ=0, FLT=0)
                self._motion, self._activated_at = None, None
            elif self.vars["ACT"] == 0:
                self.vars.update(ACT=1, STA=1)
                self._activated_at = time.monotonic()
            return
        if name == "POS":
            self.vars["PRE"] = value
            return
        self.vars[name] = value
        if name == "GTO" and value == 1:
            if self.vars["ACT"] != 1:
                self.vars["FLT"] = 7
            elif self.vars["STA"] != 3:
                self.vars["FLT"] = 5
            else:
                goal = float(np.clip(self.vars["PRE"], self.open_register, self.closed_register))
                self._motion = (self.position, goal, time.monotonic())
                self.vars["OBJ"] = 0

    def _reply(self, line: str) -> str | None:
        words = line.split()
        with self._lock:
            self._update()
            if len(words) == 2 and words[0] == "GET" and words[1] in self.VARIABLES:
                value = int(round(self.position)) if words[1] == "POS" else self.vars[words[1]]
                return f"{words[1]} {value}"
            if len(words) >= 3 and words[0] == "SET" and len(words) % 2 == 1:
                pairs = list(zip(words[1::2], words[2::2]))
                if not all(name in self.VARIABLES and value.isdigit() and 0 <= int(value) <= 255
                           for name, value in pairs):
                    return "?"
                for name, value in pairs:
                    self._set(name, int(value))
                return "ack"
            return "?"

    # -------------------------------------------------------------------------------------------------- server
    def _serve(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            try:
                client, _ = self._server.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            self.connections += 1
            with client:
                self._talk(client)

    def _talk(self, client: socket.socket) -> None:
        client.settimeout(0.05)
        buffer = b""
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            try:
                chunk = client.recv(1024)
            except socket.timeout:
                continue
            except OSError:
                return
            if not chunk:
                return
            buffer += chunk
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                line = raw.decode("ascii").strip()
                self.lines.append(line)
                if self.drop_on and line.startswith(self.drop_on):
                    return
                if self.silent_on and line.startswith(self.silent_on):
                    continue
                reply = self._reply(line)
                if reply is None:
                    continue
                data = (reply + ("\n" if self.newline else "")).encode("ascii")
                send = next((how for prefix, how in self.misbehave.items() if line.startswith(prefix)),
                            socket.socket.sendall)
                try:
                    send(client, data)
                except OSError:  # the client gave up on the reply and closed the connection
                    return

    # ------------------------------------------------------------------------------------- misbehaving replies
    @staticmethod
    def split_reply(at: int, delay: float) -> Callable[[socket.socket, bytes], None]:
        """Send the first `at` bytes of a reply, wait `delay` s, then the rest (a reply split across packets)."""
        def send(client: socket.socket, data: bytes) -> None:
            client.sendall(data[:at])
            time.sleep(delay)
            client.sendall(data[at:])
        return send

    @staticmethod
    def huge_reply(size: int) -> Callable[[socket.socket, bytes], None]:
        """Send `size` bytes of junk without a newline instead of the reply."""
        def send(client: socket.socket, data: bytes) -> None:
            client.settimeout(10.0)  # a slow reader gets it all, as from a real socket
            try:
                client.sendall(b"x" * size)
            finally:
                client.settimeout(0.05)
        return send

    def trickle_reply(self, period: float) -> Callable[[socket.socket, bytes], None]:
        """Send the reply's first 3 bytes, then a space every `period` s, never the rest nor a newline, until the
        client hangs up (a reply that keeps coming but never ends)."""
        def send(client: socket.socket, data: bytes) -> None:
            client.sendall(data[:3])
            while not self._stop.is_set() and time.monotonic() < self._deadline:
                time.sleep(period)
                client.sendall(b" ")
        return send


# ------------------------------------------------------------------------------------------------------- RTDE


class FakeUR:
    """Shared state of a fake UR controller; `control()` / `receive()` give the two RTDE interfaces."""

    def __init__(self, model: str, q: np.ndarray, *, motion_polls: int = 2, reach: float = 0.85) -> None:
        self.model = model
        self.q = np.asarray(q, dtype=float).copy()
        self.T_flange_tcp = np.eye(4)
        self.tcp = forward_kinematics(model, self.q)
        self.commands: list[tuple[str, tuple]] = []
        self.connected = True
        self.protective_stopped = False
        self.emergency_stopped = False
        self.motion_polls = motion_polls
        self.reach = reach
        self.disconnect_after_polls: int | None = None  # drop the link this many polls into the next motion
        self.disconnect_raises = True  # a dropped link raises on every call (else: calls return stale values)
        self.protective_stop_after_polls: int | None = None
        self.on_motion: Any = None  # called as on_motion(kind, target) when a motion starts (test hooks)
        self.refuse_poses = False  # isPoseWithinSafetyLimits answers False (a safety plane in the way)
        self.refuse_joints = False  # isJointsWithinSafetyLimits answers False (a joint limit)
        self.version = (3, 15, 7, 106331)  # what the controller reports (getControllerVersion): a CB3 for a ur5
        self.program_running = True  # ur_rtde's control script; a protective or emergency stop ends it
        self.streaming = True  # the state timestamp advances on every read (False: a stalled stream)
        self.timestamp = 0.0
        self.control_created = 0
        self.receive_created = 0
        self._pending: tuple[str, np.ndarray, int] | None = None
        self._token = -1

    def control(self, ip: str) -> FakeRTDEControl:
        """A new control interface; building one means the link is up."""
        self.control_created += 1
        self.connected = True
        return FakeRTDEControl(self)

    def receive(self, ip: str) -> FakeRTDEReceive:
        self.receive_created += 1
        self.connected = True
        return FakeRTDEReceive(self)

    @property
    def motions(self) -> list[tuple[str, tuple]]:
        return [c for c in self.commands if c[0] in ("moveL", "moveJ")]

    def check_link(self) -> None:
        if not self.connected and self.disconnect_raises:
            raise RuntimeError("RTDE: connection to the controller lost")

    def progress(self) -> int:
        self.check_link()
        if self._pending is None:
            return self._token
        kind, target, polls = self._pending
        polls += 1
        if self.disconnect_after_polls is not None and polls >= self.disconnect_after_polls:
            self.connected = False
            if self.disconnect_raises:
                self._pending = None
                raise RuntimeError("RTDE: connection to the controller lost")
            return 0  # the last value received before the link went quiet
        if self.protective_stop_after_polls is not None and polls >= self.protective_stop_after_polls:
            self.protective_stopped, self.program_running = True, False
            self._finish()
            return self._token
        if polls < self.motion_polls:
            self._pending = (kind, target, polls)
            return 0
        if kind == "moveJ":
            self.q = target
            self.tcp = forward_kinematics(self.model, target) @ self.T_flange_tcp
        else:
            self.tcp = matrix_from_ur_pose(target)
        self._finish()
        return self._token

    def _finish(self) -> None:
        self._pending = None
        self._token = -2 if self._token == -1 else -1

    def start(self, kind: str, target: list[float]) -> bool:
        self.check_link()
        if self.protective_stopped or self.emergency_stopped or not self.program_running:
            return False
        self._pending = (kind, np.asarray(target, dtype=float), 0)
        if self.on_motion is not None:
            self.on_motion(kind, np.asarray(target, dtype=float))
        return True


class FakeRTDEControl:
    """The `RTDEControlInterface` calls `URArm` makes; every call is recorded in `FakeUR.commands`."""

    def __init__(self, ur: FakeUR) -> None:
        self.ur = ur

    def _record(self, name: str, *args: Any) -> None:
        self.ur.commands.append((name, args))

    def setTcp(self, pose: list[float]) -> bool:
        self.ur.check_link()
        self._record("setTcp", list(pose))
        self.ur.T_flange_tcp = matrix_from_ur_pose(pose)
        self.ur.tcp = forward_kinematics(self.ur.model, self.ur.q) @ self.ur.T_flange_tcp
        return True

    def moveL(self, pose: list[float], speed: float = 0.25, acceleration: float = 1.2,
              asynchronous: bool = False) -> bool:
        self._record("moveL", list(pose), speed, acceleration, asynchronous)
        return self.ur.start("moveL", pose)

    def moveJ(self, q: list[float], speed: float = 1.05, acceleration: float = 1.4,
              asynchronous: bool = False) -> bool:
        self._record("moveJ", list(q), speed, acceleration, asynchronous)
        return self.ur.start("moveJ", q)

    def getAsyncOperationProgress(self) -> int:
        return self.ur.progress()

    def isPoseWithinSafetyLimits(self, pose: list[float]) -> bool:
        self.ur.check_link()
        self._record("isPoseWithinSafetyLimits", list(pose))
        return not self.ur.refuse_poses

    def isJointsWithinSafetyLimits(self, q: list[float]) -> bool:
        self.ur.check_link()
        self._record("isJointsWithinSafetyLimits", list(q))
        return not self.ur.refuse_joints

    def getInverseKinematicsHasSolution(self, pose: list[float]) -> bool:
        self.ur.check_link()
        return float(np.linalg.norm(pose[:2])) <= self.ur.reach

    def isConnected(self) -> bool:
        return self.ur.connected

    def reconnect(self) -> bool:
        self.ur.connected = True
        self._record("reconnect")
        return True

    def isProgramRunning(self) -> bool:
        return self.ur.program_running

    def reuploadScript(self) -> bool:
        """A new program starts with the installation's TCP (the flange), as on the controller."""
        self.ur.check_link()
        self._record("reuploadScript")
        self.ur.program_running = True
        self.ur.T_flange_tcp = np.eye(4)
        self.ur.tcp = forward_kinematics(self.ur.model, self.ur.q)
        return True

    def stopL(self, acceleration: float = 10.0, asynchronous: bool = False) -> None:
        self.ur.check_link()
        self._record("stopL", acceleration)
        self.ur._pending = None

    def stopScript(self) -> None:
        self.ur.check_link()
        self._record("stopScript")

    def disconnect(self) -> None:
        self._record("disconnect")


class FakeRTDEReceive:
    """The `RTDEReceiveInterface` calls `URArm` makes."""

    def __init__(self, ur: FakeUR) -> None:
        self.ur = ur

    def getActualTCPPose(self) -> list[float]:
        self.ur.check_link()
        return ur_pose_from_matrix(self.ur.tcp)

    def getActualQ(self) -> list[float]:
        self.ur.check_link()
        return self.ur.q.tolist()

    def isConnected(self) -> bool:
        return self.ur.connected

    def getTimestamp(self) -> float:
        if self.ur.streaming:
            self.ur.timestamp += 0.002
        return self.ur.timestamp

    def getControllerVersion(self) -> tuple[int, int, int, int]:
        return self.ur.version

    def isProtectiveStopped(self) -> bool:
        self.ur.check_link()
        return self.ur.protective_stopped

    def getSafetyMode(self) -> int:
        self.ur.check_link()
        return 7 if self.ur.emergency_stopped else 3 if self.ur.protective_stopped else 1

    def isEmergencyStopped(self) -> bool:
        self.ur.check_link()
        return self.ur.emergency_stopped

    def reconnect(self) -> bool:
        self.ur.connected = True
        self.ur.commands.append(("receive.reconnect", ()))
        return True

    def disconnect(self) -> None:
        self.ur.commands.append(("receive.disconnect", ()))


# ---------------------------------------------------------------------------------------------------- RealSense


class _VideoFrame:
    def __init__(self, data: np.ndarray) -> None:
        self._data = data

    def get_data(self) -> np.ndarray:
        return self._data

    def __bool__(self) -> bool:
        return True


class _FrameSet:
    def __init__(self, rgb: np.ndarray, depth_raw: np.ndarray) -> None:
        self._color, self._depth = _VideoFrame(rgb), _VideoFrame(depth_raw)

    def get_color_frame(self) -> _VideoFrame:
        return self._color

    def get_depth_frame(self) -> _VideoFrame:
        return self._depth


class FakePipeline:
    """A pyrealsense2 pipeline replaying `frames` (already in the colour camera) as z16 depth + rgb8 colour."""

    def __init__(self, frames: list[Frame], depth_scale: float = 0.001) -> None:
        if not frames:
            raise ValueError("FakePipeline needs at least one frame")
        self.frames, self.depth_scale = frames, depth_scale
        self.started = self.stopped = False
        self.delivered = 0
        self.fail = False  # raise like a camera that was unplugged
        K, (h, w) = frames[0].K, frames[0].depth.shape
        self.intrinsics = SimpleNamespace(fx=K[0, 0], fy=K[1, 1], ppx=K[0, 2], ppy=K[1, 2], width=w, height=h,
                                          coeffs=[0.0] * 5)

    def start(self, config: Any) -> Any:
        self.started, self.config = True, config
        sensor = SimpleNamespace(get_depth_scale=lambda: self.depth_scale)
        device = SimpleNamespace(first_depth_sensor=lambda: sensor)
        video = SimpleNamespace(get_intrinsics=lambda: self.intrinsics)
        stream = SimpleNamespace(as_video_stream_profile=lambda: video)
        return SimpleNamespace(get_device=lambda: device, get_stream=lambda kind: stream)

    def wait_for_frames(self, timeout_ms: int = 5000) -> _FrameSet:
        if self.fail:
            raise RuntimeError("Frame didn't arrive within 5000")
        frame = self.frames[self.delivered % len(self.frames)]
        self.delivered += 1
        raw = np.round(frame.depth / self.depth_scale).astype(np.uint16)
        return _FrameSet(frame.rgb.copy(), raw)

    def stop(self) -> None:
        self.stopped = True


class FakeAlign:
    """rs.align stand-in: the replayed depth is already registered to colour, so it passes frames through."""

    def __init__(self) -> None:
        self.processed = 0

    def process(self, frameset: _FrameSet) -> _FrameSet:
        self.processed += 1
        return frameset


# ------------------------------------------------------------------------------------------------ synthetic scene


def box_on_table(center_xy: tuple[float, float], size: tuple[float, float, float], table_height: float = 0.0
                 ) -> trimesh.Trimesh:
    """An axis-aligned box standing on the table (world frame)."""
    box = trimesh.creation.box(extents=size)
    box.apply_translation([center_xy[0], center_xy[1], table_height + size[2] / 2])
    return box


def synthetic_frames(scene_mesh: trimesh.Trimesh, camera_poses: list[np.ndarray], K: np.ndarray,
                     size: tuple[int, int], table_height: float = 0.0, names: list[str] | None = None
                     ) -> list[Frame]:
    """Ray-cast RGB-D frames of `scene_mesh` on an infinite table plane (object red, table grey)."""
    h, w = size
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    rays_cam = pixels @ np.linalg.inv(K).T
    frames = []
    for index, T in enumerate(camera_poses):
        directions = rays_cam @ T[:3, :3].T
        origins = np.repeat(T[:3, 3][None], len(directions), axis=0)
        z_along_axis = np.full(len(directions), np.inf)
        # table plane: origin_z + t * dir_z = table_height, depth = t (rays have unit z in the camera)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_table = (table_height - origins[:, 2]) / directions[:, 2]
        z_along_axis[t_table > 0] = t_table[t_table > 0]
        rgb = np.zeros((len(directions), 3), dtype=np.uint8)
        rgb[np.isfinite(z_along_axis)] = (120, 120, 120)
        locations, ray_index, _ = scene_mesh.ray.intersects_location(origins, directions, multiple_hits=False)
        t_object = np.einsum("ij,ij->i", locations - origins[ray_index], directions[ray_index]) / \
            np.einsum("ij,ij->i", directions[ray_index], directions[ray_index])
        closer = t_object < z_along_axis[ray_index]
        z_along_axis[ray_index[closer]] = t_object[closer]
        rgb[ray_index[closer]] = (200, 40, 40)
        depth = np.where(np.isfinite(z_along_axis) & (z_along_axis < 3.0), z_along_axis, 0.0).astype(np.float32)
        frames.append(Frame(name=names[index] if names else f"cam{index}", rgb=rgb.reshape(h, w, 3),
                            depth=depth.reshape(h, w), K=K.copy(), T_world_cam=np.asarray(T, float).copy()))
    return frames


# ------------------------------------------------------------------------------------------------------- config

EXAMPLE_CONFIG = Path(__file__).resolve().parents[1] / "hardware" / "cell.example.yaml"


def example_config() -> dict:
    """The shipped example configuration as a dict (tests modify it and write it with `write_config`)."""
    return yaml.safe_load(EXAMPLE_CONFIG.read_text())


def recorded_cameras_config(folder: Path) -> tuple[dict, dict[str, Path]]:
    """The example config with both cameras played from .db3 recordings (in `folder`) of a box on the table, at
    160x120; returns the config's data and each serial's recording."""
    from sim.lab.cameras import write_recordings

    config = load_config(EXAMPLE_CONFIG)
    K = np.array([[300.0, 0.0, 79.5], [0.0, 300.0, 59.5], [0.0, 0.0, 1.0]])
    box = trimesh.creation.box([0.06, 0.06, 0.1])
    box.apply_translation([0.5, 0.0, 0.05])
    frames = synthetic_frames(box, [c.T_world_cam() for c in config.cameras], K, (120, 160))
    paths = write_recordings({c.serial: frame for c, frame in zip(config.cameras, frames)}, folder,
                             n_frames=60)  # spares: playback drops frame sets on a loaded machine
    data = example_config()
    for camera in data["cameras"]:
        camera.update(width=160, height=120, recording=str(paths[camera["serial"]]))
    return data, paths


def write_config(path: Path, data: dict) -> Path:
    """Write a config dict as YAML and return the path."""
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def cell_config_for_fakes(path: Path, gripper_port: int, **motion: float) -> Path:
    """The example config pointed at a fake gripper on 127.0.0.1, with a short hold (tests)."""
    data = example_config()
    data["gripper"].update(host="127.0.0.1", port=gripper_port, timeout=2.0)
    data["motion"].update({"hold_time": 0.05, **motion})
    return write_config(path, data)
