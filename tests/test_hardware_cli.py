"""`python -m hardware`: config check, a dry-run first grasp, and clear errors with a non-zero exit."""

from __future__ import annotations

import json

from fakes_hardware import EXAMPLE_CONFIG, example_config, write_config
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


def test_refused_grasp_is_reported_not_raised(capsys):
    assert main(["grasp", str(EXAMPLE_CONFIG), "--at", "0.9", "0.1", "0.05", "--width", "0.05",
                 "--dry-run"]) == 0
    outcome = json.loads(capsys.readouterr().out)
    assert outcome["reachable"] is False and "outside the workspace" in outcome["message"]


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
                 str(tmp_path / "poses.yaml"), "--square", "0.03", "--dry-run"]) == 1
    assert "give --out" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "poses.yaml"), "--square", "0.03", "--board", "7by6", "--dry-run"]) == 1
    assert "--board must be COLUMNSxROWS" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--poses",
                 str(tmp_path / "absent.yaml"), "--square", "0.03", "--dry-run"]) == 1
    assert "poses file" in capsys.readouterr().err
    assert main(["calibrate", str(EXAMPLE_CONFIG), "--serial", "999", "--poses", str(tmp_path / "poses.yaml"),
                 "--square", "0.03", "--out", str(tmp_path / "c.yaml"), "--dry-run"]) == 1
    assert "camera 999 is not in" in capsys.readouterr().err


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
