"""Cell configuration: the shipped example loads, and every kind of mistake is reported naming its field."""

from __future__ import annotations

import copy

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
    (lambda d: d["limits"].update(max_tool_speed=2.0), "limits.max_tool_speed", "above the 1 m/s"),
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
    (lambda d: d["gripper"].update(force=10.0), "gripper.force", "must be in [20.0, 235.0]"),
    (lambda d: d["gripper"].update(speed=50), "gripper.speed", "must be in [0.02, 0.15]"),
    (lambda d: d["gripper"].update(host="10.0.0.1; rm"), "gripper.host", "IP address or host name"),
    (lambda d: d["limits"].update(min_table_clearance="5e-3"), "limits.min_table_clearance",
     "YAML reads '5e-3' as text"),
    (lambda d: d["robot"].update(home_joints=[True, 0, 0, 0, 0, 0]), "robot.home_joints", "list of 6 numbers"),
    # a box the arm cannot reach, or one reaching into the robot's own base column
    (lambda d: d["workspace"].update(max=[1.2, 0.3, 0.55]), "workspace", "beyond its reach"),
    (lambda d: d["workspace"].update(min=[-0.3, -0.3, 0.0]), "workspace", "inside its base column"),
    (lambda d: d["workspace"].update(min=[0.05, -0.3, 0.0]), "workspace", "inside its base column"),
])
def test_errors_name_the_field(tmp_path, change, field, problem):
    error = mutate(tmp_path, change)
    message = str(error)
    assert message.startswith(f"{tmp_path / 'cell.yaml'}: {field}:"), message
    assert problem in message, message
    assert isinstance(error, ValueError)


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
    with pytest.raises(ConfigError, match="unknown key 'T_world_cams'"):
        load_config(tmp_path / "cell.yaml")


def test_a_serial_yaml_would_read_as_octal_must_be_quoted(tmp_path):
    text = EXAMPLE_CONFIG.read_text().replace('serial: "012345678902"', "serial: 01234567")
    (tmp_path / "cell.yaml").write_text(text)
    with pytest.raises(ConfigError, match="'01234567' is read by YAML as a base-8/base-60 number"):
        load_config(tmp_path / "cell.yaml")
