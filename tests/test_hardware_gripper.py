"""The Robotiq client against a fake URCap socket server on 127.0.0.1 speaking the real ASCII protocol."""

from __future__ import annotations

import time
from dataclasses import replace

import pytest

from hardware.cell import make_guard
from hardware.config import load_config
from hardware.errors import ConnectionLostError, GripperError, SafetyError
from hardware.robotiq import RobotiqGripper
from fakes_hardware import EXAMPLE_CONFIG, FakeRobotiqServer


@pytest.fixture(scope="module")
def cell_config():
    return load_config(EXAMPLE_CONFIG)


def make_gripper(cell_config, server: FakeRobotiqServer, timeout: float = 1.0, dry_run: bool = False):
    config = replace(cell_config.gripper, host="127.0.0.1", port=server.port, timeout=timeout)
    gripper = RobotiqGripper(config, make_guard(cell_config), dry_run=dry_run)
    gripper.connect()
    return gripper


@pytest.mark.parametrize("newline", [False, True], ids=["bare-replies", "newline-replies"])
def test_activation_runs_the_reset_sequence_then_activates(cell_config, newline):
    with FakeRobotiqServer(newline=newline) as server:
        gripper = make_gripper(cell_config, server)
        assert not gripper.is_active()
        gripper.activate()
        assert gripper.is_active()
        sets = [line for line in server.lines if line.startswith("SET")]
        assert sets[0] == "SET ACT 0 ATR 0"
        assert sets[1] == "SET ACT 1"
        assert server.vars["STA"] == 3
        gripper.disconnect()


def test_close_on_nothing_and_open(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        closed = gripper.close(speed=0.1, force=50.0)
        assert not closed.object_detected
        assert closed.position == 230 and closed.width == pytest.approx(0.0)
        opened = gripper.open()
        assert not opened.object_detected
        assert opened.width == pytest.approx(cell_config.gripper.stroke)
        # speed and force reach the gripper as registers 0-255 on the same SET line as GTO
        close_line = next(line for line in server.lines if line.startswith("SET POS 255"))
        assert close_line == (f"SET POS 255 SPE {gripper.speed_to_register(0.1)} "
                              f"FOR {gripper.force_to_register(50.0)} GTO 1")
        assert gripper.force_to_register(20.0) == 0 and gripper.force_to_register(235.0) == 255


def test_close_on_an_object_reports_detection_and_width(cell_config):
    with FakeRobotiqServer(object_register=150) as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        result = gripper.close(force=40.0)
        assert result.object_detected and gripper.object_detected()
        assert result.position == 150
        assert result.width == pytest.approx(gripper.register_to_width(150))
        assert 0.02 < result.width < 0.04  # (230 - 150) / 227 * 85 mm = 30 mm
        server.slip()
        time.sleep(0.1)
        assert not gripper.object_detected()
        assert gripper.state().object_status == 3


def test_width_register_mapping_round_trips(cell_config):
    gripper = RobotiqGripper(cell_config.gripper, make_guard(cell_config), dry_run=True)
    assert gripper.width_to_register(cell_config.gripper.stroke) == 3
    assert gripper.width_to_register(0.0) == 230
    assert gripper.width_to_register(1.0) == 3  # clipped
    for width in (0.0, 0.01, 0.042, 0.085):
        assert gripper.register_to_width(gripper.width_to_register(width)) == pytest.approx(width, abs=0.0004)


def test_move_to_width_sends_the_mapped_register(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        result = gripper.move_to_width(0.05)
        expected = gripper.width_to_register(0.05)
        assert any(line.startswith(f"SET POS {expected} ") for line in server.lines)
        assert result.width == pytest.approx(0.05, abs=0.0005)
        with pytest.raises(SafetyError, match="outside"):
            gripper.move_to_width(0.2)


def test_calibrate_range_reads_the_mechanical_ends(cell_config):
    with FakeRobotiqServer(open_register=6, closed_register=221) as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        assert gripper.calibrate_range() == (6, 221)
        assert gripper.width_to_register(0.0) == 221
        assert gripper.width_to_register(cell_config.gripper.stroke) == 6


def test_fault_is_reported_and_cleared(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        server.inject_fault(14)
        with pytest.raises(GripperError, match="overcurrent"):
            gripper.close()
        gripper.clear_fault()
        assert gripper.state().fault == 0 and gripper.is_active()
        assert not gripper.close().object_detected


def test_moving_before_activation_is_a_clear_fault(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        with pytest.raises(GripperError, match="activation bit"):
            gripper.close()


@pytest.mark.parametrize("command, problem", [
    (dict(force=101.0), "grip force 101 N exceeds the limit 100 N"),  # limits.max_grip_force
    (dict(force=10.0), "grip force 10.0 N is outside the 2F-85's range"),  # used to be clipped to 20 N
    (dict(speed=0.5), "finger speed 0.5 m/s is outside the 2F-85's range"),  # used to be clipped to 0.15 m/s
])
def test_force_and_speed_out_of_range_are_refused_before_sending(cell_config, command, problem):
    # a lab's safety limit, and the force it grips with
    limited = replace(cell_config, gripper=replace(cell_config.gripper, force=100.0),
                      limits=replace(cell_config.limits, max_grip_force=100.0))
    with FakeRobotiqServer() as server:
        gripper = make_gripper(limited, server)
        gripper.activate()
        before = list(server.lines)
        with pytest.raises(SafetyError, match=problem):
            gripper.close(**command)
        assert server.lines == before


@pytest.mark.parametrize("misbehave", ["silent", "never-ending"])
def test_no_complete_reply_times_out_and_disconnects(cell_config, misbehave):
    # never-ending: the reply starts ("STA"), then a space every 5 ms, never the value nor a newline; each recv
    # returns within the settle time, so only one deadline for the whole request stops it
    with FakeRobotiqServer(lifetime=8.0) as server:
        if misbehave == "silent":
            server.silent_on = "GET STA"
        else:
            server.misbehave["GET STA"] = server.trickle_reply(0.005)
        gripper = make_gripper(cell_config, server, timeout=0.3)
        start = time.monotonic()
        with pytest.raises(GripperError, match="no reply from the gripper to 'GET STA' within 0.3 s; disconnected"):
            gripper.is_active()
        assert time.monotonic() - start < 1.5
        with pytest.raises(ConnectionLostError, match="not connected"):
            gripper.is_active()
        server.silent_on = None
        server.misbehave.clear()
        gripper.connect()
        assert not gripper.is_active()


def test_dropped_connection_is_reported(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        server.drop_on = "SET POS"
        with pytest.raises(ConnectionLostError, match="closed the connection"):
            gripper.close()
        with pytest.raises(ConnectionLostError, match="not connected"):
            gripper.open()


def test_dry_run_sends_nothing(cell_config):
    with FakeRobotiqServer() as server:
        config = replace(cell_config.gripper, host="127.0.0.1", port=server.port)
        gripper = RobotiqGripper(config, make_guard(cell_config), dry_run=True)
        gripper.connect()
        gripper.activate()
        assert gripper.close().object_detected is False
        assert gripper.open().width == pytest.approx(cell_config.gripper.stroke)
        assert server.connections == 0 and server.lines == []
        assert gripper.commands[-1].startswith("SET POS 0 ")


def test_a_huge_reply_is_refused_quickly_and_the_link_resynchronised(cell_config):
    with FakeRobotiqServer() as server:
        server.misbehave["GET POS"] = server.huge_reply(8 * 1024 * 1024)
        gripper = make_gripper(cell_config, server, timeout=2.0)
        start = time.monotonic()
        with pytest.raises(GripperError, match="longer than 256 bytes"):
            gripper.get("POS")
        assert time.monotonic() - start < 1.0
        assert gripper._socket is None  # dropped: the rest of the junk can never answer a later request
        server.misbehave.clear()
        gripper.connect()
        assert gripper.get("POS") == 3 and gripper.get("STA") == 0


@pytest.mark.slow
@pytest.mark.parametrize("newline", [False, True], ids=["bare-replies", "newline-replies"])
def test_replies_split_across_packets_are_reassembled(cell_config, newline):
    with FakeRobotiqServer(newline=newline) as server:
        gripper = make_gripper(cell_config, server)
        server.misbehave["SET"] = server.split_reply(1, 0.1)  # "a" ... "ck"
        server.misbehave["GET"] = server.split_reply(2, 0.1)  # "PO" ... "S 230"
        gripper.activate()
        gripper.close()
        # every later request is answered by its own reply, not by the rest of an earlier one
        assert gripper.get("POS") == 230
        assert gripper.get("STA") == 3
        assert gripper.get("OBJ") == 3
        assert gripper.get("FLT") == 0


def test_a_late_end_of_a_reply_never_answers_the_next_request(cell_config):
    # bare replies end by silence: "STA 3" looks complete, then a stray "0" arrives late. The next request must not
    # read it as (part of) its own reply
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        gripper.activate()
        server.misbehave["GET STA"] = lambda client, data: (client.sendall(data), time.sleep(0.1),
                                                            client.sendall(b"0"))
        assert gripper.get("STA") == 3
        time.sleep(0.2)
        server.misbehave.clear()
        with pytest.raises(GripperError, match=r"late reply to an earlier request\); disconnected"):
            gripper.get("POS")
        gripper.connect()
        assert gripper.get("POS") == 3


def test_an_unexpected_reply_drops_the_connection(cell_config):
    with FakeRobotiqServer() as server:
        gripper = make_gripper(cell_config, server)
        with pytest.raises(GripperError, match=r"answered '\?' to 'GET XYZ'"):
            gripper.get("XYZ")
        with pytest.raises(ConnectionLostError, match="not connected"):
            gripper.get("POS")


@pytest.mark.parametrize("reply", ["POS 999", "PRE 256", "STA 7", "OBJ 4", "FLT 16", "ACT 2"])
def test_a_value_out_of_its_range_is_a_protocol_error(cell_config, reply):
    # issue 34: POS 999 used to become a clipped width
    name = reply.split()[0]
    with FakeRobotiqServer() as server:
        server.misbehave[f"GET {name}"] = lambda client, data: client.sendall(reply.encode())
        gripper = make_gripper(cell_config, server)
        problem = rf"answered '{reply}' to 'GET {name}' \({name} is 0-\d+\); disconnected"
        with pytest.raises(GripperError, match=problem):
            gripper.get(name)
        with pytest.raises(ConnectionLostError, match="not connected"):
            gripper.get("POS")
