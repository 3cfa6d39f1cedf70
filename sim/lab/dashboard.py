"""The dashboard server of the emulated UR controller (port 29999): one text command per line, one reply line.

Replies follow UR's dashboard server documentation for the commands ur_rtde sends (`PolyscopeVersion`,
`get serial number`, `is in remote control`, `stop`, `unlock protective stop`, ...) and a few more an operator
would. `get serial number` and `is in remote control` exist from PolyScope 5.6 on; a protective stop can be
unlocked only `unlock_delay` seconds after it happened, as on the robot.
"""

from __future__ import annotations

import logging
import random
import socket
import string
import time
from collections import deque
from collections.abc import Callable

from sim.lab import TcpServer
from sim.lab.controller import PAUSED, PLAYING, Controller

log = logging.getLogger(__name__)

DASHBOARD_PORT = 29999
WELCOME = "Connected: Universal Robots Dashboard Server"
_SAFETY_WORDS = {"normal": "NORMAL", "protective_stop": "PROTECTIVE_STOP", "emergency_stop": "ROBOT_EMERGENCY_STOP"}


class DashboardServer(TcpServer):
    """Serves the dashboard for `controller`. Faults: `garbage` replies a line of noise to every command."""

    def __init__(self, controller: Controller, host: str = "127.0.0.1", port: int = DASHBOARD_PORT) -> None:
        self.controller = controller
        self.garbage = False
        self.received: deque[str] = deque(maxlen=200)
        self._rng = random.Random(0)
        self._commands: dict[str, Callable[[], str]] = {
            "polyscopeversion": self._polyscope_version, "get serial number": self._serial,
            "is in remote control": self._remote_control, "play": self._play, "stop": self._stop,
            "pause": self._pause, "unlock protective stop": self._unlock, "robotmode": self._robot_mode,
            "safetymode": lambda: "Safetymode: " + self._safety_word(), "programstate": self._program_state,
            "safetystatus": lambda: "Safetystatus: " + self._safety_word(), "running": self._running,
            "close safety popup": lambda: "closing safety popup", "close popup": lambda: "closing popup",
            "get loaded program": lambda: "No program loaded", "power on": lambda: "Powering on",
            "power off": lambda: "Powering off", "brake release": lambda: "Brake releasing",
            "restart safety": lambda: "Restarting safety", "get robot model": lambda: "UR5",
            "isprogramsaved": lambda: "true", "quit": lambda: "Disconnected",
        }
        super().__init__(host, port)

    def serve_client(self, sock: socket.socket) -> None:
        sock.sendall((WELCOME + "\n").encode())
        pending = b""
        while True:
            chunk = sock.recv(4096)
            if not chunk:
                return
            pending += chunk
            while b"\n" in pending:
                raw, pending = pending.split(b"\n", 1)
                line = raw.decode("utf-8", "replace").strip()
                self.received.append(line)
                sock.sendall((self.reply(line) + "\n").encode())
                if line.lower() == "quit":
                    return

    def reply(self, line: str) -> str:
        """The dashboard's answer to one command line."""
        if self.garbage:
            return "".join(self._rng.choice(string.ascii_letters + string.punctuation) for _ in range(24))
        command = line.lower()
        if command in self._commands:
            return self._commands[command]()
        if command.startswith("load "):
            return f"File not found: {line[5:]}"
        if command.startswith("popup "):
            return "showing popup"
        if command.startswith("addtolog "):
            return "Added log message"
        return f"could not understand: '{line}'"

    def _polyscope_version(self) -> str:
        return "URSoftware {}.{}.{}.{} (emulated)".format(*self.controller.settings.polyscope)

    def _serial(self) -> str:
        if not self.controller.settings.remote_control_exists:
            return "could not understand: 'get serial number'"
        return self.controller.settings.serial

    def _remote_control(self) -> str:
        if not self.controller.settings.remote_control_exists:
            return "could not understand: 'is in remote control'"
        return "true" if self.controller.remote_control else "false"

    def _play(self) -> str:
        return "Starting program" if self.controller.resume_program() else "Failed to execute: play"

    def _stop(self) -> str:
        self.controller.stop_program("stopped from the dashboard")
        return "Stopped"

    def _pause(self) -> str:
        return "Pausing program" if self.controller.pause_program() else "Failed to execute: pause"

    def _unlock(self) -> str:
        controller = self.controller
        with controller.lock:
            if controller.safety != "protective_stop":
                return "Cannot unlock protective stop: the robot is not protective stopped"
            if time.monotonic() - controller.safety_stop_time < controller.settings.unlock_delay:
                return ("Cannot unlock protective stop until 5s after occurrence. Always inspect cause of "
                        "protective stop before unlocking")
            controller.arm.safety_status = "normal"
        return "Protective stop releasing"

    def _safety_word(self) -> str:
        return _SAFETY_WORDS[self.controller.safety]

    def _robot_mode(self) -> str:
        return "Robotmode: " + ("POWER_OFF" if self.controller.safety == "emergency_stop" else "RUNNING")

    def _program_state(self) -> str:
        controller = self.controller
        state = {PLAYING: "PLAYING", PAUSED: "PAUSED"}.get(controller.runtime_state, "STOPPED")
        return f"{state} {controller.program.name if controller.program else 'null'}"

    def _running(self) -> str:
        return "Program running: " + ("true" if self.controller.runtime_state == PLAYING else "false")
