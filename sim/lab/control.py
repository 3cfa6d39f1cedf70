"""The emulated cell's control channel (port 29990): tests inject faults and read the truth through it.

One JSON object per line, `{"cmd": NAME, ...arguments}`; one reply line, `{"ok": true, ...}` or
`{"ok": false, "error": "..."}`. Handlers live in a registry: `register(name, handler)` with
`handler(request: dict) -> dict`; an exception in a handler becomes the error reply. `install_controller_commands`
registers the controller's own commands:

- `ping` -> `{"pong": true}`
- `state` -> the controller's state: program, safety, joints, pose, TCP, RTDE clients and their rates, commands
  seen (by ur_rtde name), dashboard commands received, clock statistics
- `protective_stop`, `emergency_stop`: the arm halts and the program stops (the reply comes once the controller
  has seen it); `release` clears either (the program stays stopped until a script is uploaded again)
- `drop_link {port: 30004, down_for: 0}`: closes every client of that port and refuses new ones for down_for s
- `stop_streaming` / `start_streaming`: RTDE answers every setup but sends no data packages (F3) / streams again
- `delay_state {seconds}`: RTDE packages to clients without output_int_register_0 (ur_rtde's receive interface,
  not its control interface) lag by `seconds` (0 ends it)
- `refuse_remote_control {refuse: true}`: the dashboard reports local control, uploaded scripts do not start
  (PolyScope 5.6+)
- `garbage {port: 30004, mode: "values" | "bytes" | "off"}`: RTDE data packages of random bytes ("values") or a
  random byte stream ("bytes"); on other ports every reply is noise

`request(cmd, **arguments)` is the client side.
"""

from __future__ import annotations

import json
import logging
import socket
import time
from collections.abc import Callable
from typing import Any

from sim.lab import TcpServer

log = logging.getLogger(__name__)

CONTROL_PORT = 29990
Handler = Callable[[dict], dict]
_HANDLERS: dict[str, Handler] = {}


class LabError(RuntimeError):
    """The emulated cell refused a control request."""


def register(name: str, handler: Handler) -> None:
    """Make `handler` answer control requests `{"cmd": name, ...}` (a later registration replaces an earlier one)."""
    _HANDLERS[name] = handler


def dispatch(line: str) -> dict:
    """The reply to one request line."""
    try:
        request_ = json.loads(line)
    except json.JSONDecodeError as exc:
        return {"ok": False, "error": f"the request is not JSON ({exc}): {line[:80]!r}"}
    if not isinstance(request_, dict) or not isinstance(request_.get("cmd"), str):
        return {"ok": False, "error": f'a request is a JSON object with a "cmd" string, got {line[:80]!r}'}
    handler = _HANDLERS.get(request_["cmd"])
    if handler is None:
        return {"ok": False, "error": f"unknown command {request_['cmd']!r}; known: {', '.join(sorted(_HANDLERS))}"}
    try:
        return {"ok": True, **handler(request_)}
    except Exception as exc:  # noqa: BLE001 -- every handler failure is the error reply, never the channel's death
        log.warning("control %s failed: %s", request_["cmd"], exc)
        prefix = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
        return {"ok": False, "error": prefix + str(exc)}


class ControlServer(TcpServer):
    """Serves the control channel."""

    def __init__(self, host: str = "127.0.0.1", port: int = CONTROL_PORT) -> None:
        super().__init__(host, port)

    def serve_client(self, sock: socket.socket) -> None:
        with sock.makefile("rwb") as stream:
            for raw in stream:
                line = raw.decode("utf-8", "replace").strip()
                if line:
                    stream.write((json.dumps(dispatch(line)) + "\n").encode())
                    stream.flush()


def request(cmd: str, /, *, channel: tuple[str, int] = ("127.0.0.1", CONTROL_PORT), timeout: float = 30.0,
            **arguments: Any) -> dict:
    """Send `{"cmd": cmd, **arguments}` to the control channel at `channel` (host, port) and return the reply;
    raise `LabError` if the cell refused it."""
    with socket.create_connection(channel, timeout=timeout) as sock, sock.makefile("rwb") as stream:
        stream.write((json.dumps({"cmd": cmd, **arguments}) + "\n").encode())
        stream.flush()
        line = stream.readline()
    if not line:
        raise LabError(f"the emulated cell closed the control channel without answering {cmd!r}")
    reply = json.loads(line)
    if not reply.get("ok"):
        raise LabError(f"{cmd}: {reply.get('error')}")
    return reply


def install_controller_commands(controller: Any, dashboard: Any, servers: dict[int, Any], gripper: Any = None) -> None:
    """Register ping, state and the controller's faults; `servers` maps a port to its server (for drop/garbage);
    the gripper server, if any, follows the robot's emergency stop."""

    def wait_for_safety(status: str) -> dict:
        if gripper is not None and (status == "emergency_stop" or controller.safety == "emergency_stop"):
            gripper.set_estop(status == "emergency_stop")
        controller.arm.safety_status = status
        deadline = time.monotonic() + 2.0
        while controller.safety != status:
            if time.monotonic() > deadline:
                raise RuntimeError(f"the controller did not reach safety status {status!r} within 2 s")
            time.sleep(0.005)
        return {"safety_status": status}

    def server(request_: dict) -> Any:
        port = int(request_.get("port", 30004))
        if port not in servers:
            raise ValueError(f"no server on port {port}; ports: {sorted(servers)}")
        return servers[port]

    def drop_link(request_: dict) -> dict:
        target = server(request_)
        if not hasattr(target, "drop_clients"):
            raise ValueError(f"the server on port {target.port} cannot drop its links")
        target.down_until = time.monotonic() + float(request_.get("down_for", 0.0))
        return {"dropped": target.drop_clients()}

    def garbage(request_: dict) -> dict:
        mode = request_.get("mode", "values")
        if mode not in ("values", "bytes", "off"):
            raise ValueError(f"garbage mode must be values, bytes or off, got {mode!r}")
        target = server(request_)
        if target is controller.rtde:
            target.garbage = None if mode == "off" else mode
        else:
            target.garbage = mode != "off"
        return {"port": target.port, "mode": mode}

    def set_streaming(on: bool) -> Handler:
        def handler(request_: dict) -> dict:
            controller.rtde.streaming = on
            return {"streaming": on}
        return handler

    def delay_state(request_: dict) -> dict:
        seconds = float(request_.get("seconds", 0.0))
        if not 0 <= seconds <= 2.0:
            raise ValueError(f"delay_state seconds must be within 0-2 (ur_rtde gives up after 2.5 s), got {seconds}")
        controller.rtde.state_delay = seconds
        return {"seconds": seconds}

    def refuse_remote_control(request_: dict) -> dict:
        controller.remote_control = not bool(request_.get("refuse", True))
        return {"remote_control": controller.remote_control}

    register("ping", lambda request_: {"pong": True})
    register("state", lambda request_: {**controller.state(), "dashboard_commands": list(dashboard.received)})
    register("protective_stop", lambda request_: wait_for_safety("protective_stop"))
    register("emergency_stop", lambda request_: wait_for_safety("emergency_stop"))
    register("release", lambda request_: wait_for_safety("normal"))
    register("drop_link", drop_link)
    register("stop_streaming", set_streaming(False))
    register("start_streaming", set_streaming(True))
    register("delay_state", delay_state)
    register("refuse_remote_control", refuse_remote_control)
    register("garbage", garbage)
