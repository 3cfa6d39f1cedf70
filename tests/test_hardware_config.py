"""Cell configuration: the shipped example loads, and every kind of mistake is reported naming its field."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest

from fakes_hardware import EXAMPLE_CONFIG, example_config, write_config
from hardware.config import ConfigError, load_config


def test_the_example_config_loads_with_its_values():
    config = load_config(EXAMPLE_CONFIG)
    assert config.robot.ip == "192.168.1.10" and config.robot.model == "ur5"
    assert config.robot.T_flange_gripper[2, 3] == pytest.approx(0.155)
    assert config.gripper.host == config.robot.ip and config.gripper.port == 63352
    assert [c.serial for c in config.cameras] == ["012345678901", "012345678902"]
    assert config.cameras[0].T_world_cam().shape == (4, 4)
    np.testing.assert_allclose(config.limits.workspace_min, [0.25, -0.30, 0.0])
    assert config.motion.lift_height == pytest.approx(0.2) and config.motion.hold_time == pytest.approx(1.0)
    assert config.interactive is False


def mutate(tmp_path, change) -> ConfigError:
    data = copy.deepcopy(example_config())
    change(data)
    with pytest.raises(ConfigError) as info:
        load_config(write_config(tmp_path / "cell.yaml", data))
    return info.value


@pytest.mark.parametrize("change, field, problem", [
    (lambda d: d.pop("robot"), "robot", "missing section"),
    (lambda d: d["robot"].pop("home_joints"), "robot.home_joints", "missing"),
    (lambda d: d["robot"].update(home_joints=[0, 1, 2]), "robot.home_joints", "6 finite numbers"),
    (lambda d: d["robot"].update(model="ur10"), "robot.model", "must be one of"),
    (lambda d: d["robot"].update(ip="192.168.1.10; rm"), "robot.ip", "IP address or host name"),
    (lambda d: d["robot"].update(tcp_offset={"xyz": [0, 0, -0.1]}), "robot.tcp_offset", "in front of the flange"),
    (lambda d: d["robot"].update(tcp_offset={"xyz": [0, 0, 0.15], "rpy": [0, 0]}), "robot.tcp_offset.rpy",
     "3 finite numbers"),
    (lambda d: d["robot"].update(speed=1.0), "robot.speed", "unknown key"),
    (lambda d: d["gripper"].update(port=70000), "gripper.port", "must be in [1, 65535]"),
    (lambda d: d["gripper"].update(closed_register=2), "gripper.closed_register", "greater than"),
    (lambda d: d["gripper"].update(stroke=85), "gripper.stroke", "metres"),
    (lambda d: d["limits"].update(max_grip_force=80.0), "gripper.force", "exceeds limits.max_grip_force"),
    (lambda d: d["limits"].update(max_tool_speed=-1), "limits.max_tool_speed", "positive number, got -1"),
    (lambda d: d["limits"].update(max_tool_speed="fast"), "limits.max_tool_speed", "finite number"),
    (lambda d: d["limits"].update(max_tool_speed=2.0), "limits.max_tool_speed",
     "above the UR5/UR5e's datasheet tool speed (1 m/s)"),
    (lambda d: d["motion"].update(tool_speed=0.5), "motion.tool_speed", "exceeds limits.max_tool_speed"),
    (lambda d: d["workspace"].update(max=[0.2, 0.3, 0.55]), "workspace.max", "must exceed workspace.min"),
    (lambda d: d["table"].update(height=1.0), "table.height", "inside the workspace"),
    (lambda d: d.update(cameras=[]), "cameras", "non-empty list"),
    (lambda d: d["cameras"].append({"serial": "999"}), "cameras[2].serial",
     "no T_world_cam for table-mounted camera 999"),
    (lambda d: d["cameras"].append(dict(d["cameras"][0], name="again")), "cameras", "distinct"),
    (lambda d: d["cameras"][0].update(fps=0), "cameras[0].fps", "must be in [1, 300]"),
    (lambda d: d["calibration"].update(file="x.yaml"), "calibration", "not both"),
    (lambda d: d["cameras"][0].update(mount="ceiling"), "cameras[0].mount", "must be one of"),
    (lambda d: d["cameras"][0].update(mount="wrist"), "cameras[0].serial",
     "no T_gripper_cam for wrist-mounted camera 012345678901"),
    (lambda d: d["calibration"]["T_world_cam"]["012345678901"][0].__setitem__(0, 2.0),
     "calibration.T_world_cam.012345678901", "not a proper rotation"),
    (lambda d: d.update(interactive="yes"), "interactive", "true or false"),
    (lambda d: d.update(robots={}), "robots", "unknown key"),
    # values the bridge used to clip or misread silently
    (lambda d: d["gripper"].update(force=10.0), "gripper.force", "must be in [20, 235]"),
    (lambda d: d["gripper"].update(speed=50), "gripper.speed", "must be in [0.02, 0.15]"),
    (lambda d: d["gripper"].update(host="10.0.0.1; rm"), "gripper.host", "IP address or host name"),
    (lambda d: d["limits"].update(min_table_clearance="5e-3"), "limits.min_table_clearance",
     "YAML reads '5e-3' as text"),
    (lambda d: d["robot"].update(home_joints=[True, 0, 0, 0, 0, 0]), "robot.home_joints", "list of 6 finite"),
    # a box the arm cannot reach, or one reaching into the robot's own base column
    (lambda d: d["workspace"].update(max=[1.2, 0.3, 0.55]), "workspace", "beyond its reach"),
    (lambda d: d["workspace"].update(min=[-0.3, -0.3, 0.0]), "workspace", "inside its base column"),
    (lambda d: d["workspace"].update(min=[0.05, -0.3, 0.0]), "workspace", "inside its base column"),
])
def test_errors_name_the_field(tmp_path, change, field, problem):
    error = mutate(tmp_path, change)
    message = str(error)
    assert_names_line(message, tmp_path / "cell.yaml", field)
    assert problem in message, message
    assert isinstance(error, ValueError)


def assert_names_line(message: str, path, field: str) -> None:
    """The message starts `path:LINE: field:` with LINE a line of the file that holds part of the field's path (the
    section of a missing key), or `path: field:` for a missing top-level section."""
    found = re.match(rf"{re.escape(str(path))}(?::(\d+))?: {re.escape(field)}: ", message)
    assert found, message
    parts = re.findall(r"[A-Za-z_0-9]+", field)
    if found.group(1) is None:
        assert field in {"robot", "cameras"} and field not in path.read_text(), message  # a missing section
        return
    line = path.read_text().splitlines()[int(found.group(1)) - 1]
    assert any(part in line for part in parts) or line.lstrip().startswith("- "), (message, line)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "absent.yaml")
    with pytest.raises(ConfigError, match="is a folder, not a file"):
        load_config(tmp_path)
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00robot")
    with pytest.raises(ConfigError, match="is not UTF-8 text"):
        load_config(tmp_path / "binary.yaml")
    (tmp_path / "broken.yaml").write_text("robot: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(tmp_path / "broken.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="top level must be a mapping"):
        load_config(tmp_path / "list.yaml")
    data = example_config()
    data["calibration"] = {"file": "missing_calibration.yaml"}
    with pytest.raises(ConfigError, match="calibration.file: calibration file .* not found"):
        load_config(write_config(tmp_path / "cell.yaml", data))


def test_defaults_fill_optional_fields(tmp_path):
    data = example_config()
    data.pop("motion")
    data.pop("interactive")
    data["gripper"] = {}
    data["cameras"] = [{"serial": 12345678901}]  # unquoted serials are read as strings
    data["calibration"] = {"T_world_cam": {"12345678901": {"xyz": [0.0, -0.8, 0.6], "rpy": [-2.2, 0.0, 0.0]}}}
    config = load_config(write_config(tmp_path / "cell.yaml", data))
    assert config.gripper.port == 63352 and config.gripper.host == "192.168.1.10"
    assert config.motion.tool_speed == pytest.approx(0.1) and config.motion.lift_height == pytest.approx(0.2)
    assert config.cameras[0].serial == "12345678901" and config.cameras[0].name == "cam12345678901"
    assert config.cameras[0].T_world_cam()[:3, 3] == pytest.approx([0.0, -0.8, 0.6])


def test_uncalibrated_cameras_are_accepted_only_when_asked(tmp_path):
    data = example_config()
    data["calibration"] = {"file": "not_yet.yaml"}
    path = write_config(tmp_path / "cell.yaml", data)
    with pytest.raises(ConfigError, match="calibration.file"):
        load_config(path)
    config = load_config(path, require_calibration=False)
    np.testing.assert_allclose(config.cameras[0].T_mount_cam, np.eye(4))
    data.pop("calibration")
    config = load_config(write_config(path, data), require_calibration=False)
    assert len(config.cameras) == 2


def test_a_duplicated_key_is_an_error_naming_it_and_both_lines(tmp_path):
    text = EXAMPLE_CONFIG.read_text()
    first = text.splitlines().index("  max_tool_speed: 0.25            # m/s") + 1
    doubled = text.replace("  max_tool_speed: 0.25            # m/s\n",
                           "  max_tool_speed: 0.25            # m/s\n  max_tool_speed: 0.9\n")
    (tmp_path / "cell.yaml").write_text(doubled)
    with pytest.raises(ConfigError, match=f"duplicate key 'max_tool_speed': first at line {first}, "
                                          f"again at line {first + 1}"):
        load_config(tmp_path / "cell.yaml")


def test_a_second_workspace_section_cannot_replace_the_first(tmp_path):
    # the second box would reach into the robot's base column, where a dry-run grasp used to be "reachable"
    text = EXAMPLE_CONFIG.read_text() + "\nworkspace:\n  min: [-0.3, -0.3, 0.0]\n  max: [0.75, 0.3, 0.55]\n"
    (tmp_path / "cell.yaml").write_text(text)
    first = EXAMPLE_CONFIG.read_text().splitlines().index(
        next(line for line in text.splitlines() if line.startswith("workspace:"))) + 1
    with pytest.raises(ConfigError, match=f"duplicate key 'workspace': first at line {first}"):
        load_config(tmp_path / "cell.yaml")


def test_duplicates_in_the_calibration_file_are_errors_too(tmp_path):
    data = example_config()
    data["calibration"] = {"file": "calibration.yaml"}
    T = "[[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.6], [0, 0, 0, 1]]"
    (tmp_path / "calibration.yaml").write_text(
        f'T_world_cam:\n  "012345678901": {T}\n  "012345678902": {T}\n  "012345678901": {T}\n')
    with pytest.raises(ConfigError, match="calibration.file: .*duplicate key '012345678901': first at line 2, "
                                          "again at line 4"):
        load_config(write_config(tmp_path / "cell.yaml", data))
    (tmp_path / "calibration.yaml").write_text(f'T_world_cam: {{"012345678901": {T}, "012345678901": {T}}}\n')
    with pytest.raises(ConfigError, match="duplicate key '012345678901': first at line 1, again at line 1"):
        load_config(tmp_path / "cell.yaml")  # in a one-line mapping too
    (tmp_path / "calibration.yaml").write_text(f'T_world_cam:\n  "012345678901": {T}\nT_world_cams: {{}}\n')
    with pytest.raises(ConfigError, match="calibration.yaml:3: T_world_cams: unknown key"):
        load_config(tmp_path / "cell.yaml")


def test_a_serial_yaml_would_read_as_octal_must_be_quoted(tmp_path):
    text = EXAMPLE_CONFIG.read_text().replace('serial: "012345678902"', "serial: 01234567")
    (tmp_path / "cell.yaml").write_text(text)
    with pytest.raises(ConfigError, match="'01234567' is read by YAML as a base-8/base-60 number"):
        load_config(tmp_path / "cell.yaml")


def edited_example(tmp_path, old: str, new: str) -> tuple:
    """The example config with its line starting `old` replaced by `new`: (path, number of that line)."""
    lines = EXAMPLE_CONFIG.read_text().splitlines()
    index = next(i for i, line in enumerate(lines) if line.startswith(old))
    lines[index] = new
    path = tmp_path / "cell.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path, index + 1


# issue 34: values the UR5/UR5e and the 2F-85 cannot do, or waits no cell needs, used to be accepted (the dry run
# planned a 500 m/s^2 move as reachable); each is refused in one sentence naming the file, the line and the field
@pytest.mark.parametrize("old, new, field, problem", [
    ("  max_tool_acceleration:", "  max_tool_acceleration: 500", "limits.max_tool_acceleration",
     "500 m/s^2 is above the largest tool acceleration the UR controller interface accepts (150 m/s^2)"),
    ("  max_joint_acceleration:", "  max_joint_acceleration: 800", "limits.max_joint_acceleration",
     "800 rad/s^2 is above the largest joint acceleration the UR controller interface accepts (40 rad/s^2)"),
    ("  timeout:", "  timeout: 1.0e+9", "gripper.timeout", "must be at most 60, got 1000000000.0"),
    ("  motion_timeout:", "  motion_timeout: 1.0e+9", "robot.motion_timeout", "must be at most 300"),
    ("  hold_time:", "  hold_time: 1000", "motion.hold_time", "must be in [0, 10], got 1000"),
    ("  ip:", "  ip: 256.300.1.999", "robot.ip", "'256.300.1.999' is not an IPv4 address"),
    ("  ip:", "  ip: 0", "robot.ip", "must be an IP address or host name, got 0"),
    ("  ip:", "  ip: '0'", "robot.ip", "'0' is not an IPv4 address"),
    ("  ip:", "  ip: 10.1.1", "robot.ip", "'10.1.1' is not an IPv4 address"),
    ("  ip:", "  ip: 0.0.0.0", "robot.ip", "not the address of one machine"),
    ("  ip:", "  ip: 255.255.255.255", "robot.ip", "not the address of one machine"),
    ("  ip:", "  ip: ur5-.lab", "robot.ip", "must be an IP address or host name"),
    ("  port: 63352", "  host: 224.0.0.1", "gripper.host", "not the address of one machine"),
    ("  stroke:", "  stroke: 0.0001", "gripper.stroke", "0.0001 m is not a 2F-85's opening between the pads"),
    ("  stroke:", "  stroke: 0.14", "gripper.stroke", "datasheet stroke 0.085"),
    ("  tool_speed:", "  tool_speed: 0.0001", "motion.tool_speed",
     "a straight move across the workspace (0.96 m) at 0.0001 m/s takes 9.55e+03 s, longer than "
     "robot.motion_timeout (30 s)"),
    ("  joint_speed:", "  joint_speed: 0.01", "motion.joint_speed", "half a joint turn at 0.01 rad/s takes 314 s"),
    ("  home_joints:", "  home_joints: [1" + "0" * 400 + ", 0, 0, 0, 0, 0]", "robot.home_joints",
     "must be a list of 6 finite numbers"),
    ("  tcp_offset:", "  tcp_offset: {xyz: [0.0, 0.0, 0.155], rpy: [1.0e+308, 0.0, 0.0]}", "robot.tcp_offset.rpy",
     "angles must be radians within [-2 pi, 2 pi]"),
    ("  tcp_offset:", "  tcp_offset: {xyz: [0.0, 0.0, 155.0]}", "robot.tcp_offset",
     "translation [0.0, 0.0, 155.0] m reaches beyond 10 m: metres are expected"),
], ids=lambda value: value.strip()[:40] if isinstance(value, str) else None)
def test_values_beyond_the_ur5_and_2f85_are_refused_naming_file_and_line(tmp_path, old, new, field, problem):
    path, line = edited_example(tmp_path, old, new)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: {field}: "), message
    assert problem in message, message
    assert "\n" not in message and len(message) < 400, message


@pytest.mark.parametrize("written", ["1:30.0", "1:30", "-0:30.5"])
def test_a_base_60_number_is_refused_naming_file_and_line(tmp_path, written):
    path, line = edited_example(tmp_path, "  hold_time:", f"  hold_time: {written}")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}:{line}: '{written}' is read by YAML"), str(info.value)
    assert "base-60" in str(info.value)


def test_the_limits_of_the_real_arm_are_still_accepted(tmp_path):
    data = example_config()
    data["limits"].update(max_tool_speed=1.0, max_joint_speed=3.14, max_tool_acceleration=150.0,
                          max_joint_acceleration=40.0)
    data["robot"]["motion_timeout"] = 300.0
    data["gripper"].update(timeout=60.0, stroke=0.0425, host="ur5.lab.example")
    data["motion"]["hold_time"] = 10.0
    config = load_config(write_config(tmp_path / "cell.yaml", data))
    assert config.limits.max_joint_acceleration == 40.0 and config.gripper.host == "ur5.lab.example"


@pytest.mark.parametrize("kind, text, problem", [
    ("fifo", None, "is not a regular file"),
    ("huge", "# " + "x" * 1_100_000 + "\n", "larger than 1000 kB"),
    ("deep", "robot: " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
    ("latin-1", "robot:\n  ip: caf\xe9\n", "is not UTF-8 text"),
], ids=["fifo", "huge", "deep", "latin-1"])
def test_files_that_are_not_configs_get_one_sentence(tmp_path, kind, text, problem):
    import os

    path = tmp_path / "cell.yaml"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.write_bytes(text.encode("latin-1"))
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert problem in str(info.value) and str(path) in str(info.value)
    assert "\n" not in str(info.value) and len(str(info.value)) < 300


def test_a_camera_may_play_a_recording_resolved_against_the_config(tmp_path):
    data = example_config()
    data["cameras"][0]["recording"] = "scene/front.db3"
    data["cameras"][1]["recording"] = str(tmp_path / "elsewhere" / "side.db3")
    config = load_config(write_config(tmp_path / "cell.yaml", data))
    assert config.cameras[0].recording == tmp_path / "scene" / "front.db3"  # need not exist yet
    assert config.cameras[1].recording == tmp_path / "elsewhere" / "side.db3"
    data["cameras"][1]["recording"] = "scene.bag"
    error = mutate(tmp_path, lambda d: d.update(cameras=data["cameras"]))
    assert_names_line(str(error), tmp_path / "cell.yaml", "cameras[1].recording")
    assert "must be a .db3 file" in str(error) and "'scene.bag'" in str(error)


def test_an_emulated_cell_declares_itself_in_an_emulator_section(tmp_path):
    data = example_config()
    data["emulator"] = {"controller": "e-series", "polyscope": "5.11.1"}
    config = load_config(write_config(tmp_path / "cell.yaml", data))
    assert config.emulator == {"controller": "e-series", "polyscope": "5.11.1"}
    assert load_config(EXAMPLE_CONFIG).emulator is None
    error = mutate(tmp_path, lambda d: d.update(emulator="yes"))
    assert_names_line(str(error), tmp_path / "cell.yaml", "emulator")
    assert "must be a mapping" in str(error)
