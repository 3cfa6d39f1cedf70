"""Run a client scenario against a fresh emulated lab cell, in a subprocess, with a hard timeout.

`run_in_lab(code, serve_args)` runs `python -m sim.lab run <serve_args> -- python -c <code>`: the emulator and the
client share a private network namespace and nothing else (ur_rtde's constructors hold the GIL, and its crashes
must not take the test process with them). The result carries the exit code exactly as the shell reports it
(a SIGSEGV in the client is 139), stdout, stderr and the last JSON line of stdout; the whole process group is
killed at the end, so no emulator or client outlives the test.

A scenario prints one JSON line last, e.g.

    from tests.lab_harness import run_in_lab
    run = run_in_lab('''
    import json, rtde_receive
    from sim.lab.control import request
    r = rtde_receive.RTDEReceiveInterface("127.0.0.1")
    print(json.dumps({"q": r.getActualQ(), "truth": request("state")["q"]}))
    ''')
    assert run.returncode == 0, run.stderr
    run.result["q"]
"""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.lab import netns

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class LabRun:
    """What a scenario left: exit code (None when it was killed at the timeout), output and streams."""

    returncode: int | None
    stdout: str
    stderr: str

    @property
    def timed_out(self) -> bool:
        return self.returncode is None

    @property
    def result(self) -> Any:
        """The last line of stdout that parses as JSON (None if there is none)."""
        for line in reversed(self.stdout.splitlines()):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                continue
        return None


def run_command(argv: Sequence[str], timeout: float, env: dict[str, str] | None = None) -> LabRun:
    """Run `argv` in its own process group with a hard timeout; kill the whole group afterwards."""
    process = subprocess.Popen(list(argv), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True, env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})
    try:
        stdout, stderr = process.communicate(timeout=timeout)
        code = process.returncode
        returncode: int | None = code if code >= 0 else 128 - code
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        returncode = None
        stderr += f"\n[lab_harness] killed after the {timeout:g} s timeout"
    finally:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return LabRun(returncode, stdout, stderr)


@functools.cache
def namespace_prefix() -> tuple[str, ...]:
    """The command prefix that runs a program in a new network namespace here (`sim.lab.netns`), () if none."""
    return tuple(netns.unshare_command() or ())


def run_in_lab(code: str, serve_args: Sequence[str] = ("--kinematic",), timeout: float = 60.0,
               env: dict[str, str] | None = None) -> LabRun:
    """Run the Python `code` (dedented) as a client of a fresh emulated cell started with `serve_args`.

    The namespace is entered here already (`sim.lab run` would re-execute itself into it, one more start-up)."""
    argv = [sys.executable, "-m", "sim.lab", "run", *serve_args, "--", sys.executable, "-c", textwrap.dedent(code)]
    prefix = namespace_prefix()
    return run_command([*prefix, *argv], timeout, {**({netns.NETNS_ENV: "1"} if prefix else {}), **(env or {})})
