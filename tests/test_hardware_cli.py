"""`python -m hardware`: config check, a dry-run first grasp, and clear errors with a non-zero exit."""

from __future__ import annotations

import json
import shutil

import pytest

from fakes_hardware import EXAMPLE_CONFIG, example_config, recorded_cameras_config, write_config
from hardware.__main__ import main


def test_check_prints_a_summary(capsys):
    assert main(["check", str(EXAMPLE_CONFIG)]) == 0
    out = capsys.readouterr().out
    assert "valid" in out and "192.168.1.10" in out and "012345678902" in out


def test_dry_run_grasp_prints_the_outcome_and_moves_nothing(capsys):
    assert main(["grasp", str(EXAMPLE_CONFIG), "--at", "0.52", "0.1", "0.05", "--width", "0.05",
                 "--dry-run"]) == 0
    outcome = json.loads(capsys.readouterr().out)
    assert outcome["reachable"] is True and outcome["lifted"] is False and "dry run" in outcome["message"]


def test_refused_grasp_is_reported_and_exits_non_zero(capsys):
    assert main(["grasp", str(EXAMPLE_CONFIG), "--at", "0.9", "0.1", "0.05", "--width", "0.05",
                 "--dry-run"]) == 1
    captured = capsys.readouterr()
    outcome = json.loads(captured.out)
    assert outcome["reachable"] is False and "outside the workspace" in outcome["message"]
    assert captured.err.startswith("error: grasp refused (dry run): ") and "outside the workspace" in captured.err
    assert main(["grasp", str(EXAMPLE_CONFIG), "--at", "0.52", "0.1", "0.05", "--width", "0.09",
                 "--dry-run"]) == 1
    assert "exceeds the gripper stroke" in capsys.readouterr().err


@pytest.mark.parametrize("args, problem", [
    (["--at", "nan", "0.1", "0.05", "--width", "0.05"], "--at and --yaw must be finite"),
    (["--at", "0.52", "0.1", "0.05", "--yaw", "inf", "--width", "0.05"], "--at and --yaw must be finite"),
    (["--at", "0.52", "0.1", "0.05", "--width", "-0.01"], "--width must be the object's width in metres"),
])
def test_grasp_arguments_out_of_range_exit_non_zero(capsys, args, problem):
    assert main(["grasp", str(EXAMPLE_CONFIG), *args, "--dry-run"]) == 1
    assert problem in capsys.readouterr().err


def test_check_refuses_dry_run_without_connect(capsys):
    assert main(["check", str(EXAMPLE_CONFIG), "--dry-run"]) == 1
    assert "--dry-run only applies with --connect" in capsys.readouterr().err


def test_calibrate_checks_its_output_and_inputs_before_moving(tmp_path, capsys):
    poses = tmp_path / "poses.yaml"
    poses.write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n")
    args = ["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses", str(poses), "--dry-run"]
    (tmp_path / "junk.yaml").write_text("T_world_cam: [1, 2\n")
    assert main([*args, "--square", "0.03", "--out", str(tmp_path / "junk.yaml")]) == 1
    err = capsys.readouterr().err
    assert "calibration file" in err and "not valid YAML" in err
    assert main([*args, "--square", "0.03", "--out", str(tmp_path / "no" / "such" / "c.yaml")]) == 1
    assert "does not exist or is not writable" in capsys.readouterr().err
    assert main([*args, "--square", "nan", "--out", str(tmp_path / "c.yaml")]) == 1
    assert "square size in metres" in capsys.readouterr().err
    poses.write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3]\n")  # broken YAML: an error, not a traceback
    assert main([*args, "--square", "0.03", "--out", str(tmp_path / "c.yaml")]) == 1
    assert "poses file" in capsys.readouterr().err
    poses.write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\nposes: []\n")
    assert main([*args, "--square", "0.03", "--out", str(tmp_path / "c.yaml")]) == 1
    assert "duplicate key 'poses'" in capsys.readouterr().err


def test_a_grasp_inside_the_robots_base_column_is_refused(tmp_path, capsys):
    # finding 4: a second workspace section used to widen the box over the base; now both that and a box that
    # encloses the base are refused before anything is planned
    data = example_config()
    data["workspace"]["min"] = [-0.3, -0.3, 0.0]
    assert main(["grasp", str(write_config(tmp_path / "cell.yaml", data)), "--at", "0.0", "0.0", "0.1",
                 "--width", "0.05", "--dry-run"]) == 1
    assert "inside its base column" in capsys.readouterr().err


def test_bad_input_exits_non_zero_with_a_message(tmp_path, capsys):
    data = example_config()
    data["limits"]["max_tool_speed"] = -1
    assert main(["check", str(write_config(tmp_path / "bad.yaml", data))]) == 1
    assert "limits.max_tool_speed" in capsys.readouterr().err
    (tmp_path / "poses.yaml").write_text("poses: []\n")
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "poses.yaml"), "--square", "0.03", "--dry-run"]) == 1
    assert "expected 'poses:'" in capsys.readouterr().err
    (tmp_path / "poses.yaml").write_text("poses: [{xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}]\n")
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "poses.yaml"), "--square", "0.03", "--board", "7x5", "--dry-run"]) == 1
    assert "ambiguous" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "poses.yaml"), "--square", "0.03", "--board", "7by6", "--dry-run"]) == 1
    assert "--board must be COLUMNSxROWS" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "absent.yaml"), "--square", "0.03", "--dry-run"]) == 1
    assert "poses file" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "999", "--poses", str(tmp_path / "poses.yaml"),
                 "--square", "0.03", "--out", str(tmp_path / "c.yaml"), "--dry-run"]) == 1
    assert "camera '999' is not in" in capsys.readouterr().err


def test_calibration_dry_run_checks_the_tour(tmp_path, capsys):
    (tmp_path / "poses.yaml").write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n"
                                         "  - {xyz: [0.45, 0.05, 0.28], rpy: [2.8, 0.3, 0.2]}\n")
    args = ["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses", str(tmp_path / "poses.yaml"),
            "--square", "0.03", "--out", str(tmp_path / "calibration.yaml"), "--dry-run"]
    assert main(args) == 0
    assert "all 2 calibration poses are within the limits" in capsys.readouterr().out
    assert not (tmp_path / "calibration.yaml").exists()
    (tmp_path / "poses.yaml").write_text("poses:\n  - {xyz: [0.5, 0.1, 0.9], rpy: [3.14159, 0, 0]}\n")
    assert main(args) == 1
    assert "outside the workspace" in capsys.readouterr().err


def test_check_refuses_a_home_pose_outside_the_limits(tmp_path, capsys):
    data = example_config()
    data["robot"]["home_joints"][0] = 1.5708  # base turned a quarter: the gripper is beside the robot, off the table
    assert main(["check", str(write_config(tmp_path / "cell.yaml", data))]) == 1
    assert "the home pose (robot.home_joints, gripper fully open): gripper origin x = 0.109 m is outside" in \
        capsys.readouterr().err


# ------------------------------------------------------------------------------------------- issue 34, the CLI
@pytest.mark.parametrize("at", [["0.52", "-.1", "0.05"], ["0.52", "-1e-1", "0.05"], ["5.2e-1", "-0.1", "5e-2"]])
def test_grasp_reads_negative_numbers_in_any_notation(capsys, at):
    assert main(["grasp", str(EXAMPLE_CONFIG), "--at", *at, "--width", "0.05", "--dry-run"]) == 0
    assert json.loads(capsys.readouterr().out)["reachable"] is True


@pytest.mark.parametrize("args, problem", [
    (["--at", "-1e308", "0", "0"], "--at [-1e+308, 0.0, 0.0] is 1e+308 m from the UR5's shoulder, beyond its reach "
                                   "(1.005 m with the tool)"),
    (["--at", "0.52", "-inf", "0.05"], "--at and --yaw must be finite numbers"),
    (["--at", "0.52", "0.1", "0.05", "--yaw", "-1e9"], "--yaw must be within [-2 pi, 2 pi] rad, got -1e+09"),
    (["--at", "0.52", "0.1", "0.05", "--width", "1e308"], "--width must be the object's width in metres (0-1"),
])
def test_grasp_bounds_its_numbers_in_one_sentence(capsys, args, problem):
    # `--at -1e308 ...` used to be read as an option: "argument --at: expected 3 arguments"
    if "--width" not in args:
        args = [*args, "--width", "0.05"]
    assert main(["grasp", str(EXAMPLE_CONFIG), *args, "--dry-run"]) == 1
    err = capsys.readouterr().err
    assert err == f"error: {problem}\n" or (err.startswith("error: ") and problem in err), err
    assert err.count("\n") == 1


def test_calibrate_on_the_example_config_needs_no_out(tmp_path, capsys):
    # README: `python -m hardware calibrate cell.yaml --serial ... --poses poses.yaml --square 0.03` on a copy of the
    # example config used to fail with "give --out"; the result now goes beside the config, and the run says so
    config = tmp_path / "cell.yaml"
    shutil.copy(EXAMPLE_CONFIG, config)
    (tmp_path / "poses.yaml").write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n")
    assert main(["calibrate", str(config), "--serial", "012345678901", "--poses", str(tmp_path / "poses.yaml"),
                 "--square", "0.03", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"the result would go to {tmp_path / 'calibration.yaml'}" in out
    assert "does not read it yet: make its calibration section `file: calibration.yaml`" in out
    assert not (tmp_path / "calibration.yaml").exists()


def test_calibrate_refuses_oversized_boards_and_tours(tmp_path, capsys):
    (tmp_path / "poses.yaml").write_text("poses:\n" + "  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n" * 201)
    args = ["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--square", "0.03", "--dry-run",
            "--out", str(tmp_path / "c.yaml")]
    assert main([*args, "--poses", str(tmp_path / "poses.yaml")]) == 1
    assert "201 poses are more than the 200" in capsys.readouterr().err
    (tmp_path / "poses.yaml").write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n")
    assert main([*args, "--poses", str(tmp_path / "poses.yaml"), "--board", "100000x100001"]) == 1
    assert "3-50 inner corners a side" in capsys.readouterr().err


@pytest.mark.slow
def test_a_dry_run_check_without_cameras_names_them_in_one_sentence(capsys):
    assert main(["check", str(EXAMPLE_CONFIG), "--connect", "--dry-run"]) == 1
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith("error: the check failed: ") and "012345678901" in err and "012345678902" in err
    assert "(a dry run still uses the cameras)" in err


def test_a_dry_run_check_plays_recorded_cameras(tmp_path, capsys):
    data, paths = recorded_cameras_config(tmp_path / "rec")
    path = write_config(tmp_path / "cell.yaml", data)
    assert main(["check", str(path), "--connect", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"(plays {paths['012345678901']})" in out
    assert "camera front: 160x120" in out and "camera side: 160x120" in out
