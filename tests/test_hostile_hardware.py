"""`python -m hardware` against hostile controllers, grippers and files (issue 34): every run ends in bounded time
with one line `error: ...` and a non-zero exit, never a traceback or a hang.

The controller stand-ins are tiny socket servers on the UR's fixed ports, run with the CLI in a private network
namespace (`unshare -n`): one accepts and never answers, one answers garbage, one trickles a byte every half
second. The CLI runs in a subprocess through the real ur_rtde (its connect deadline is hardware/ur.py's). The
gripper cases use the emulated lab cell (`python -m sim.lab run --kinematic`, tests/lab_harness.py) for the arm and
either its URCap socket (fault 13 injected on the control channel) or a stand-in that reports `POS 999`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from fakes_hardware import EXAMPLE_CONFIG, example_config, recorded_cameras_config, write_config
from lab_harness import namespace_prefix, run_command, run_in_lab

#: Every hostile run must end within this (issue 34: "every command ends within 60 s with a clear message").
BOUND = 60.0


needs_netns = pytest.mark.skipif(not namespace_prefix(), reason="needs a network namespace (unshare -n)")

# Runs in a fresh network namespace: loopback up, the stand-in on every UR port, then the CLI in a subprocess with a
# hard timeout beyond BOUND (so a hang is measured, not waited for); with `interrupt`, SIGINT reaches the CLI half a
# second after its first connection (SIGINT restored to its default: a background job inherits it ignored).
_CONTROLLER = textwrap.dedent('''
    import json, signal, socket, subprocess, sys, threading, time
    mode, config, interrupt = sys.argv[1], sys.argv[2], sys.argv[3] == "interrupt"
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    contacted = threading.Event()

    def talk(client):
        contacted.set()
        try:
            if mode == "silent":
                while client.recv(4096):
                    pass
            elif mode == "garbage":
                while True:
                    client.sendall(bytes(range(256)) + b"garbage\\r\\n")
                    time.sleep(0.05)
            else:  # trickle
                while True:
                    client.sendall(b"x")
                    time.sleep(0.5)
        except OSError:
            pass

    def serve(port):
        server = socket.socket()
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen(16)
        while True:
            client, _ = server.accept()
            threading.Thread(target=talk, args=(client,), daemon=True).start()

    for port in (29999, 30001, 30002, 30003, 30004, 63352):
        threading.Thread(target=serve, args=(port,), daemon=True).start()
    time.sleep(0.2)
    start = time.monotonic()
    cli = subprocess.Popen([sys.executable, "-m", "hardware", "check", config, "--connect"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        if interrupt and contacted.wait(%(hard)r):
            time.sleep(0.5)
            start = time.monotonic()
            cli.send_signal(signal.SIGINT)
        out, err = cli.communicate(timeout=%(hard)r)
        code = cli.returncode
    except subprocess.TimeoutExpired:
        cli.kill()
        out, err = cli.communicate()
        code = None
    seconds = time.monotonic() - start
    time.sleep(1.0)  # what the CLI started must be gone by now: list what is left in this namespace
    import os
    ours, left = os.readlink("/proc/self/ns/net"), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if int(pid) != os.getpid() and os.readlink(f"/proc/{pid}/ns/net") == ours:
                left.append(open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\\0", b" ").decode()[:200])
        except OSError:
            pass
    print(json.dumps({"returncode": code, "seconds": seconds, "stdout": out, "stderr": err, "left": left}))
''' % {"hard": BOUND + 20.0})


def _local_config(tmp_path, **gripper) -> str:
    data = example_config()
    data["robot"]["ip"] = "127.0.0.1"
    data["gripper"].update(gripper)
    return str(write_config(tmp_path / "cell.yaml", data))


def _one_line_error(stderr: str) -> str:
    """The `error: ...` line the CLI ends with; fails on a traceback or a message spread over lines."""
    assert "Traceback" not in stderr, stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("error: "), stderr
    return last


@pytest.mark.slow
@needs_netns
@pytest.mark.parametrize("mode", ["silent", "garbage", "trickle"])
def test_check_connect_ends_in_bounded_time_against_a_hostile_controller(tmp_path, mode):
    # on 5cb5eaf all three were still running at 120 s: URArm.connect had no deadline (F3)
    run = run_command([*namespace_prefix(), sys.executable, "-c", _CONTROLLER, mode, _local_config(tmp_path), "-"],
                      timeout=BOUND + 40.0)
    assert run.returncode == 0, run.stderr
    result = run.result
    assert result["returncode"] is not None, f"still running after {result['seconds']:.0f} s: {result['stderr'][-800:]}"
    assert result["seconds"] < BOUND, result
    assert result["returncode"] == 1, result
    line = _one_line_error(result["stderr"])
    assert line.startswith("error: cannot connect to the UR controller at 127.0.0.1: "), line
    assert result["left"] == [], result["left"]


@pytest.mark.slow
@needs_netns
def test_ctrl_c_while_connecting_ends_with_one_line(tmp_path):
    # seconds counted from the SIGINT
    run = run_command([*namespace_prefix(), sys.executable, "-c", _CONTROLLER, "silent", _local_config(tmp_path),
                       "interrupt"], timeout=BOUND + 40.0)
    result = run.result
    assert result["returncode"] == 130 and result["seconds"] < 5, result
    assert _one_line_error(result["stderr"]) == "error: interrupted"
    assert result["left"] == [], result["left"]


def _recorded_cameras(tmp_path) -> dict:
    """The example config on 127.0.0.1 with both cameras played from recordings of a box on the table."""
    data, _ = recorded_cameras_config(tmp_path / "rec")
    data["robot"]["ip"] = "127.0.0.1"
    return data


# Runs inside the emulated cell: `check --connect` as a user runs it, then with the gripper faulted (fault 13 on
# the emulator's URCap socket), then against a URCap stand-in on another port that reports POS 999.
_GRIPPER = '''
import contextlib, io, json, socket, threading, time
from hardware.__main__ import main
from sim.lab.control import request

def check(config):
    out, err = io.StringIO(), io.StringIO()
    start = time.monotonic()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["check", config, "--connect"])
    return {"returncode": code, "seconds": time.monotonic() - start, "stdout": out.getvalue(), "stderr": err.getvalue()}

def urcap_reporting_pos_999(port):
    values = {"ACT": 1, "STA": 3, "OBJ": 3, "FLT": 0, "POS": 999, "PRE": 3, "GTO": 1}
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port))
    server.listen(4)
    def talk(client):
        with client, client.makefile("rwb") as stream:
            for line in stream:
                words = line.decode().split()
                reply = f"{words[1]} {values.get(words[1], 0)}" if words[:1] == ["GET"] else "ack"
                stream.write(reply.encode() + b"\\n")
                stream.flush()
    def serve():
        while True:
            threading.Thread(target=talk, args=(server.accept()[0],), daemon=True).start()
    threading.Thread(target=serve, daemon=True).start()

result = {"healthy": check(%(config)r)}
request("gripper_fault", code=13)
result["fault 13"] = check(%(config)r)
urcap_reporting_pos_999(63399)
result["POS 999"] = check(%(pos_config)r)
print(json.dumps(result))
'''


@pytest.mark.slow
def test_check_connect_fails_on_a_faulted_gripper_or_an_impossible_position(tmp_path):
    # on 5cb5eaf `check --connect` printed fault=13 (or the POS 999 clipped to a 0 mm width) and exited 0
    data = _recorded_cameras(tmp_path)
    config = write_config(tmp_path / "cell.yaml", data)
    data["gripper"]["port"] = 63399
    pos_config = write_config(tmp_path / "cell_pos.yaml", data)
    run = run_in_lab(_GRIPPER % {"config": str(config), "pos_config": str(pos_config)}, timeout=150.0)
    assert run.returncode == 0, run.stderr[-2000:]
    result = run.result
    healthy = result["healthy"]
    assert healthy["returncode"] == 0, healthy["stderr"][-1500:]
    assert "camera front: 160x120" in healthy["stdout"] and "fault=0" in healthy["stdout"]
    for case, expected in (("fault 13", "error: the check failed: the gripper reports fault 13 (activation fault"),
                           ("POS 999", "error: the gripper answered 'POS 999' to 'GET POS' (POS is 0-255)")):
        outcome = result[case]
        assert outcome["returncode"] == 1 and outcome["seconds"] < BOUND, (case, outcome)
        assert _one_line_error(outcome["stderr"]).startswith(expected), (case, outcome["stderr"])


# Bad files and arguments, end to end through `python -m hardware` in a subprocess: one line, exit 1 (2 for argparse)
@pytest.mark.parametrize("case", ["config is /dev/zero", "config is a FIFO", "config is a folder", "config is binary",
                                  "base-60 hold time", "poses file is a FIFO", "out is a folder", "at -1e308",
                                  "board of a billion corners", "config path too long"])
def test_hostile_files_and_arguments_get_one_line(tmp_path, case):
    poses = tmp_path / "poses.yaml"
    poses.write_text("poses:\n  - {xyz: [0.5, 0.1, 0.3], rpy: [3.14159, 0, 0]}\n")
    calibrate = ["calibrate", str(EXAMPLE_CONFIG), "--serial", "012345678901", "--square", "0.03", "--dry-run"]
    fifo = tmp_path / "fifo.yaml"
    if "FIFO" in case:
        os.mkfifo(fifo)
    (tmp_path / "binary.yaml").write_bytes(bytes(range(256)) * 8)
    (tmp_path / "sexagesimal.yaml").write_text(EXAMPLE_CONFIG.read_text().replace("hold_time: 1.0 ",
                                                                                  "hold_time: 1:30.0 "))
    args, expected = {
        "config is /dev/zero": (["check", "/dev/zero"], "is not a regular file"),
        "config is a FIFO": (["check", str(fifo)], "is not a regular file"),
        "config is a folder": (["check", str(tmp_path)], "is a folder, not a file"),
        "config is binary": (["check", str(tmp_path / "binary.yaml")], "is not UTF-8 text"),
        "base-60 hold time": (["check", str(tmp_path / "sexagesimal.yaml")],
                              "'1:30.0' is read by YAML 1.1 as a base-60"),
        "poses file is a FIFO": ([*calibrate, "--poses", str(fifo), "--out", str(tmp_path / "c.yaml")],
                                 "is not a regular file"),
        "out is a folder": ([*calibrate, "--poses", str(poses), "--out", str(tmp_path)], "is a folder"),
        "at -1e308": (["grasp", str(EXAMPLE_CONFIG), "--at", "-1e308", "0", "0", "--width", "0.05", "--dry-run"],
                      "beyond its reach"),
        "board of a billion corners": ([*calibrate, "--poses", str(poses), "--board", "1000000000x3",
                                        "--out", str(tmp_path / "c.yaml")], "3-50 inner corners a side"),
        "config path too long": (["check", str(tmp_path / ("x" * 300) / "cell.yaml")],
                                 "cannot read cell configuration file"),
    }[case]
    run = subprocess.run([sys.executable, "-m", "hardware", *args], capture_output=True, text=True, timeout=BOUND)
    assert run.returncode == 1, (run.returncode, run.stderr[-1500:])
    line = _one_line_error(run.stderr)
    assert expected in line, line
