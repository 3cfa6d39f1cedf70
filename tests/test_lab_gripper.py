"""The real `hardware.robotiq.RobotiqGripper` over a real TCP socket against the emulated URCap (sim/lab/robotiq.py)."""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from hardware.cell import make_guard
from hardware.config import load_config
from hardware.errors import ConnectionLostError, GripperError
from hardware.robotiq import RobotiqGripper
from seggrasp.cell import FINGER_SPEED_RANGE, GRIP_FORCE_RANGE
from sim.lab import control
from sim.lab.robotiq import CLOSED_REGISTER, OPEN_REGISTER, KinematicFingers, RobotiqServer, start_gripper_server

EXAMPLE = Path(__file__).resolve().parents[1] / "hardware" / "cell.example.yaml"
ACTIVATION = 0.3  # s, shorter than the emulator's default to keep the tests quick
SLOW, FAST = FINGER_SPEED_RANGE


@pytest.fixture(scope="module")
def cell_config():
    return load_config(EXAMPLE)


@pytest.fixture
def fingers():
    return KinematicFingers()


@pytest.fixture
def server(fingers):
    with start_gripper_server(fingers, port=0, activation_time=ACTIVATION) as server:
        yield server


@pytest.fixture(scope="module")
def channel():
    """A real control channel (sim/lab/control.py) on a free port: send(cmd, **arguments) -> its reply."""
    server = control.ControlServer(port=0)
    yield lambda cmd, **arguments: control.request(cmd, channel=("127.0.0.1", server.port), timeout=2.0, **arguments)
    server.close()


def connect(cell_config, port: int, timeout: float = 1.0) -> RobotiqGripper:
    """The client as RealCell builds it, on `port` of 127.0.0.1 (the port comes from GripperConfig)."""
    config = replace(cell_config.gripper, host="127.0.0.1", port=port, timeout=timeout)
    gripper = RobotiqGripper(config, make_guard(cell_config))
    gripper.connect()
    return gripper


def active(cell_config, server: RobotiqServer, timeout: float = 1.0) -> RobotiqGripper:
    gripper = connect(cell_config, server.port, timeout)
    gripper.activate()
    gripper.calibrate_range()
    return gripper


def test_activation_takes_the_activation_time(cell_config, server):
    gripper = connect(cell_config, server.port)
    assert not gripper.is_active()
    start = time.monotonic()
    gripper.activate()
    assert time.monotonic() - start >= ACTIVATION
    assert gripper.is_active() and gripper.state().fault == 0
    gripper.disconnect()


def test_calibrate_range_reads_the_units_ends(cell_config, server):
    gripper = connect(cell_config, server.port)
    gripper.activate()
    assert gripper.calibrate_range() == (OPEN_REGISTER, CLOSED_REGISTER)
    assert gripper.width_to_register(0.0) == CLOSED_REGISTER
    assert gripper.width_to_register(cell_config.gripper.stroke) == OPEN_REGISTER


def test_close_and_open_on_nothing(cell_config, server, fingers):
    gripper = active(cell_config, server)
    closed = gripper.close(speed=FAST, force=GRIP_FORCE_RANGE[0])
    assert not closed.object_detected and closed.position == CLOSED_REGISTER
    assert closed.width == pytest.approx(0.0) and fingers.width() == pytest.approx(0.0)
    assert fingers.force == pytest.approx(GRIP_FORCE_RANGE[0])
    opened = gripper.open(speed=FAST)
    assert not opened.object_detected and opened.width == pytest.approx(cell_config.gripper.stroke)
    middle = gripper.move_to_width(0.04, speed=FAST)
    assert middle.width == pytest.approx(0.04, abs=0.0004) and fingers.width() == pytest.approx(0.04, abs=0.0004)


@pytest.mark.slow
def test_close_on_an_object_then_the_object_is_lost(cell_config, server, fingers, channel):
    gripper = active(cell_config, server)
    gripper.open(speed=FAST)
    fingers.set_object(0.050)
    held = gripper.close(speed=FAST, force=GRIP_FORCE_RANGE[1])
    assert held.object_detected and gripper.object_detected()
    assert held.width == pytest.approx(0.050, abs=0.0004)
    assert fingers.force == pytest.approx(GRIP_FORCE_RANGE[1])
    channel("lose_object")  # the object slips out: the fingers carry on to the request
    assert not gripper.object_detected()
    deadline = time.monotonic() + 2.0
    while gripper.state().object_status != 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert gripper.state().object_status == 3 and gripper.width() == pytest.approx(0.0)


@pytest.mark.slow
def test_full_stroke_at_the_slowest_speed_ends_within_its_travel_time(cell_config, server):
    # F10: the 2F-85's full stroke at 20 mm/s takes 4.25 s. The client used one fixed deadline (gripper.timeout,
    # here 1 s) per motion, whatever the speed and stroke: this close failed "did not complete within 1.0 s"
    gripper = active(cell_config, server, timeout=1.0)
    gripper.open(speed=FAST)
    start = time.monotonic()
    closed = gripper.close(speed=SLOW)
    elapsed = time.monotonic() - start
    travel_time = cell_config.gripper.stroke / SLOW
    assert not closed.object_detected and closed.width == pytest.approx(0.0)
    assert travel_time < elapsed < travel_time + 0.5


def test_jammed_fingers_end_at_the_motion_deadline(cell_config):
    class Jammed(KinematicFingers):
        def step(self, dt: float) -> None:  # the fingers never move: OBJ stays 0 (moving)
            pass

    with RobotiqServer(Jammed(), port=0, activation_time=ACTIVATION) as server:
        gripper = connect(cell_config, server.port, timeout=0.5)
        gripper.activate()
        start = time.monotonic()
        with pytest.raises(GripperError, match=r"finger motion did not complete within \d+\.\d+ s"):
            gripper.move_to_width(0.080, speed=FAST)  # 5 mm from open: 0.03 s of travel plus the 0.5 s margin
        assert 0.5 < time.monotonic() - start < 1.5


def test_an_emergency_stop_is_named_and_recovered_from(cell_config, server, channel):
    gripper = active(cell_config, server)
    channel("gripper_estop", on=True)
    # the URCap answers 'STA ?': the client used to say "expected 'STA ' and a number" and drop the link
    with pytest.raises(GripperError, match="emergency stop"):
        gripper.is_active()
    with pytest.raises(GripperError, match="emergency stop"):
        gripper.close(speed=FAST)
    channel("gripper_estop", on=False)
    assert not gripper.is_active()  # released, the gripper comes back reset, on the same connection
    gripper.activate()
    assert not gripper.close(speed=FAST).object_detected


def test_an_emergency_stop_mid_motion_is_named(cell_config, server):
    gripper = active(cell_config, server)
    gripper.open(speed=FAST)
    threading.Timer(0.3, server.set_estop, (True,)).start()
    with pytest.raises(GripperError, match="emergency stop"):
        gripper.close(speed=SLOW)


@pytest.mark.slow
def test_fault_13_mid_grasp_is_named_and_cleared(cell_config, server, channel):
    gripper = active(cell_config, server)
    gripper.open(speed=FAST)
    threading.Timer(0.3, channel, ("gripper_fault",), {"code": 13}).start()
    start = time.monotonic()
    named = r"gripper fault 13 (while waiting for|in the) finger motion.*: activation fault"
    with pytest.raises(GripperError, match=named):
        gripper.close(speed=SLOW)
    assert time.monotonic() - start < 1.0
    gripper.clear_fault()
    assert gripper.state().fault == 0 and gripper.is_active()
    assert not gripper.close(speed=FAST).object_detected


def test_a_garbage_reply_is_named_and_the_link_resynchronised(cell_config, server):
    gripper = active(cell_config, server)
    server.garbage = True  # the control channel's `garbage {port: 63352}`
    with pytest.raises(GripperError, match=r"answered .* to 'GET POS' \(expected 'POS ' and a number\); disconnected"):
        gripper.width()
    server.garbage = False
    gripper.connect()
    assert gripper.is_active() and gripper.get("POS") == CLOSED_REGISTER


def test_a_socket_that_accepts_and_never_answers_ends_in_bounded_time(cell_config):
    with socket.create_server(("127.0.0.1", 0)) as mute:
        gripper = connect(cell_config, mute.getsockname()[1], timeout=0.5)
        start = time.monotonic()
        with pytest.raises(GripperError, match=r"no reply from the gripper to 'SET ACT 0 ATR 0' within 0.5 s"):
            gripper.activate()
        assert time.monotonic() - start < 1.5


def test_clients_one_after_another_and_at_once_share_one_gripper(cell_config, server):
    first = active(cell_config, server)
    second = connect(cell_config, server.port)
    assert second.is_active()  # connected while the first still is
    first.disconnect()
    second.close(speed=FAST)
    second.disconnect()
    third = connect(cell_config, server.port)
    assert third.get("POS") == CLOSED_REGISTER


@pytest.mark.parametrize("line", ["HELLO", "GET XYZ", "SET POS 256", "SET STA 3", "SET GTO 2", "SET POS", "get sta"])
def test_a_request_the_urcap_cannot_parse_is_answered_with_a_question_mark(server, line):
    with socket.create_connection(("127.0.0.1", server.port), timeout=1.0) as raw:
        raw.sendall(line.encode() + b"\n")
        assert raw.recv(64) == b"?"
        raw.sendall(b"GET STA\n")  # the connection stays usable
        assert raw.recv(64) == b"STA 0\n"


def test_an_endless_request_line_closes_the_connection(server):
    with socket.create_connection(("127.0.0.1", server.port), timeout=1.0) as raw:
        raw.sendall(b"G" * 4096)
        assert raw.recv(64) == b""


def test_a_bad_fault_request_is_refused_by_the_control_channel(server, channel):
    with pytest.raises(control.LabError, match="gripper_fault needs a code 0-15"):
        channel("gripper_fault", code="13")
    with pytest.raises(control.LabError, match="gripper_estop's on must be true or false"):
        channel("gripper_estop", on="yes")


def test_a_link_dropped_mid_motion_is_named(cell_config, server):
    gripper = active(cell_config, server)
    gripper.open(speed=FAST)
    threading.Timer(0.3, server.drop_clients).start()  # the control channel's `drop_link {port: 63352}`
    with pytest.raises(ConnectionLostError, match="the gripper closed the connection"):
        gripper.close(speed=SLOW)
    gripper.connect()
    assert gripper.is_active()


def test_moving_before_activation_is_fault_7(cell_config, server, fingers):
    gripper = connect(cell_config, server.port)
    with pytest.raises(GripperError, match="gripper fault 7 .*: the activation bit must be set before moving"):
        gripper.close(speed=FAST)
    assert fingers.width() == pytest.approx(cell_config.gripper.stroke)  # nothing moved


@pytest.mark.slow
def test_automatic_release_opens_the_fingers_and_reports_15(cell_config, server, fingers):
    gripper = active(cell_config, server)
    gripper.move_to_width(0.080, speed=FAST)
    gripper.set(ATR=1, ADR=1)
    assert gripper.get("FLT") == 11  # release in progress, at the slowest speed
    deadline = time.monotonic() + 2.0
    while gripper.get("FLT") != 15 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert gripper.get("FLT") == 15 and fingers.width() == pytest.approx(cell_config.gripper.stroke)
    gripper.clear_fault()
    assert gripper.state().fault == 0 and gripper.is_active()
