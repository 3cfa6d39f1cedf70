"""The controller's script port (30003) and what the controller reads of the script ur_rtde uploads there.

`ScriptServer` collects each top-level `def name(): ... end` a client sends; `Program.parse` reads from its text
what this PolyScope version left in it (ur_rtde strips calls the version lacks, e.g. `get_inverse_kin_has_solution`
below 5.10 / 3.15, F4); `COMMAND_NAMES` are the register commands of ur_rtde's `rtde_control.script` that the
controller (sim/lab/controller.py) answers.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable
from dataclasses import dataclass

from sim.lab import TcpServer

log = logging.getLogger(__name__)

SCRIPT_PORT = 30003

#: ur_rtde's command numbers (its RobotCommand::Type) that this controller answers.
COMMAND_NAMES = {1: "movej", 2: "movej_ik", 3: "movel", 29: "set_tcp", 30: "get_inverse_kin_args",
                 31: "protective_stop", 33: "stopl", 34: "stopj", 36: "is_pose_within_safety_limits",
                 37: "is_joints_within_safety_limits",
                 40: "get_tcp_offset", 46: "get_inverse_kin_default", 47: "is_steady",
                 60: "get_inverse_kin_has_solution_default", 61: "get_inverse_kin_has_solution_args",
                 255: "stop_script"}
#: Commands the script treats as real-time (processed and answered with "ready" every cycle): not emulated.
REALTIME_COMMANDS = {6, 9, 10, 11, 24, 25, 26, 27, 38, 58}


class ScriptRuntimeError(Exception):
    """A runtime error of the control script: the controller stops the program."""


@dataclass
class Program:
    """The running control script: what the uploaded text contains and the state of its main loop."""

    name: str
    has_ik_check: bool  # get_inverse_kin_has_solution survived ur_rtde's version stripping
    has_protective_stop: bool
    has_tcp_offset: bool
    executing: bool = False
    write_count: int = 0
    operation_id: int = 0
    async_kind: str | None = None  # "move" | "stop" while an async thread runs
    pending: str | None = None  # a synchronous motion or stop the main loop waits for

    @classmethod
    def parse(cls, text: str) -> Program:
        """Read what the controller needs from a script `def name(): ... end`."""
        header = text.lstrip().split("\n", 1)[0]
        name = header.split()[1].split("(")[0] if len(header.split()) > 1 else "program"
        return cls(name=name, has_ik_check="get_inverse_kin_has_solution(" in text,
                   has_protective_stop="protective_stop()" in text, has_tcp_offset="get_tcp_offset()" in text)


class ScriptServer(TcpServer):
    """The script port: collects each top-level `def name(): ... end` a client sends and hands it on."""

    def __init__(self, host: str, on_program: Callable[[str], None], port: int = SCRIPT_PORT) -> None:
        self.on_program = on_program
        super().__init__(host, port)

    def serve_client(self, sock: socket.socket) -> None:
        pending = ""
        while True:
            chunk = sock.recv(65536)
            if not chunk:
                return
            pending = self._take_programs(pending + chunk.decode("utf-8", "replace"))

    def _take_programs(self, text: str) -> str:
        """Hand on every complete program in `text`; return what is left (an incomplete program)."""
        while True:
            stripped = text.lstrip()
            if not stripped.startswith(("def ", "sec ")):
                line, newline, text = stripped.partition("\n")
                if not newline:
                    return stripped
                log.warning("script port: ignored a line outside a program: %.60s", line)
                continue
            lines = stripped.split("\n")
            ends = [i for i, line in enumerate(lines[:-1]) if i > 0 and line.rstrip() == "end"]
            if not ends:
                return stripped
            self.on_program("\n".join(lines[:ends[0] + 1]) + "\n")
            text = "\n".join(lines[ends[0] + 1:])
