"""`python -m sim.lab serve|run`: the emulated lab cell.

    python -m sim.lab serve --kinematic [--controller cb3|e-series] [--polyscope 3.15.7] ...
    python -m sim.lab serve --object mug_classic [--seed 0]          (the PyBullet twin drives the arm)
    python -m sim.lab serve --object mug_classic --calibration-board 7x6:0.03   (a checkerboard on the flange)
    python -m sim.lab run [serve options] -- CMD ...

`serve` listens on --host (127.0.0.1): dashboard 29999, script 30003, RTDE 30004, the Robotiq URCap socket 63352
and, last, the control channel 29990; it runs until SIGTERM or Ctrl-C. `run` re-executes itself in a private
network namespace (`unshare -n`, or `unshare -rn` without root), brings the loopback up, starts the emulator
(within --ready-timeout), runs CMD as a child process there, stops the emulator and exits with CMD's exit code
(128 + N when a signal N killed it). The emulator runs in `run`'s own process (one start-up instead of two) and
the client in another: ur_rtde's constructors hold the GIL and its crashes must not take the emulator along.
Where no namespace can be made, it serves on the host's loopback if every port is free and otherwise exits 2
naming the taken port.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sim.lab import netns

log = logging.getLogger("sim.lab")

def add_serve_options(parser: argparse.ArgumentParser) -> None:
    """The options of `serve` (also accepted by `run`, which passes them on)."""
    from sim.lab.settings import DEFAULT_POLYSCOPE, GENERATIONS

    parser.add_argument("--host", help="address every port listens on (default 127.0.0.1; inside run's private "
                        "namespace 0.0.0.0, so that a client may use any 127.x.y.z)")
    parser.add_argument("--kinematic", action="store_true", help="arm and fingers without physics (no twin)")
    parser.add_argument("--object", help="twin mode: the object placed in the scene, e.g. mug_classic")
    parser.add_argument("--seed", type=int, default=0, help="twin mode: scene seed (default 0)")
    parser.add_argument("--recordings", help="twin mode: folder for the camera recordings (default: a temp dir)")
    parser.add_argument("--calibration-board", metavar="COLSxROWS:SQUARE",
                        help="twin mode: a checkerboard of COLSxROWS inner corners and SQUARE m squares fixed to the "
                        "flange (sim/lab/board.py), e.g. 7x6:0.03; implies --render-at-rest")
    parser.add_argument("--render-at-rest", action="store_true",
                        help="twin mode: render the cameras again after every motion; the motion is reported "
                        "finished once the new recordings are in place (default: once per placement)")
    parser.add_argument("--controller", choices=sorted(GENERATIONS), default="e-series",
                        help="controller generation: cb3 streams RTDE at 125 Hz, e-series at 500 Hz")
    parser.add_argument("--polyscope", help="PolyScope version X.Y.Z (default "
                        + ", ".join(f"{g} {v}" for g, v in DEFAULT_POLYSCOPE.items()) + ")")
    parser.add_argument("--serial", default="20235500001", help="the robot's serial number (dashboard)")
    parser.add_argument("--unlock-delay", type=float, default=5.0,
                        help="seconds after a protective stop before it can be unlocked (default 5, as on the robot)")
    parser.add_argument("--log-level", default="warning", choices=["debug", "info", "warning", "error"])


@dataclass
class Models:
    """What the emulator drives: the arm, the fingers (None without a gripper server) and their lifecycle."""

    arm: Any
    fingers: Any
    start: Callable[[], None] = lambda: None
    close: Callable[[], None] = lambda: None
    gripper_options: dict = field(default_factory=dict)  # start_gripper_server's options (step_period, lock)


def build_models(args: argparse.Namespace) -> Models:
    """The arm and finger models `serve` drives: kinematic ones, or the twin's (sim/lab/twin.py)."""
    if args.kinematic:
        if args.calibration_board or args.render_at_rest:
            raise LabStartError("--calibration-board and --render-at-rest need the twin's cameras, not --kinematic")
        from sim.lab.kinematic import KinematicArm
        from sim.lab.robotiq import KinematicFingers

        return Models(KinematicArm(), KinematicFingers())
    if not args.object:
        raise SystemExit("sim.lab serve: name the object to place (--object mug_classic) or pass --kinematic")
    from sim.lab.board import CalibrationBoard
    from sim.lab.twin import twin_models

    try:
        board = None if args.calibration_board is None else CalibrationBoard.parse(args.calibration_board)
    except ValueError as exc:
        raise LabStartError(str(exc)) from None
    return twin_models(object_id=args.object, seed=args.seed, recordings=args.recordings, board=board,
                       render_at_rest=args.render_at_rest)


class LabStartError(Exception):
    """The emulated cell could not be started (the message says why)."""


def open_lab(args: argparse.Namespace) -> Callable[[], None]:
    """Build and start the emulated cell; return the function that stops it. The control channel opens last."""
    from sim.lab.control import ControlServer, install_controller_commands
    from sim.lab.controller import Controller
    from sim.lab.dashboard import DashboardServer
    from sim.lab.robotiq import start_gripper_server
    from sim.lab.settings import DEFAULT_POLYSCOPE, ControllerSettings, parse_polyscope

    args.host = args.host or ("0.0.0.0" if netns.in_private_namespace() else "127.0.0.1")
    try:
        settings = ControllerSettings(generation=args.controller,
                                      polyscope=parse_polyscope(args.polyscope or DEFAULT_POLYSCOPE[args.controller],
                                                                args.controller),
                                      serial=args.serial, unlock_delay=args.unlock_delay)
    except ValueError as exc:
        raise LabStartError(str(exc)) from None
    closers: list[Callable[[], None]] = []

    def close() -> None:
        for closer in reversed(closers):
            closer()

    try:
        models = build_models(args)
        closers.append(models.close)
        controller = Controller(models.arm, settings, host=args.host)
        closers.append(controller.close)
        dashboard = DashboardServer(controller, host=args.host)
        closers.append(dashboard.close)
        servers = {dashboard.port: dashboard, controller.script_port.port: controller.script_port,
                   controller.rtde.port: controller.rtde}
        gripper = None
        if models.fingers is not None:
            gripper = start_gripper_server(models.fingers, host=args.host, **models.gripper_options)
            closers.append(gripper.close)
            servers[gripper.port] = gripper
        install_controller_commands(controller, dashboard, servers, gripper)
        controller.start()
        models.start()
        closers.append(ControlServer(host=args.host).close)
    except OSError as exc:
        close()
        taken = " (the port is taken)" if exc.errno == errno.EADDRINUSE else ""
        raise LabStartError(f"cannot listen on {args.host}: {exc.strerror or exc}{taken}") from None
    log.info("serving %s PolyScope %s on %s", settings.generation, ".".join(map(str, settings.polyscope)), args.host)
    return close


def serve(args: argparse.Namespace) -> int:
    """Serve the emulated cell until SIGTERM/SIGINT."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        close = open_lab(args)
    except LabStartError as exc:
        print(f"sim.lab serve: {exc}", file=sys.stderr)
        return 2
    stop.wait()
    close()
    return 0


def run(args: argparse.Namespace, command: list[str]) -> int:
    """Run `command` against a fresh emulated cell (in a private network namespace where one can be made)."""
    from sim.lab.control import CONTROL_PORT

    if not command:
        print("sim.lab run: give the command after --, e.g. python -m sim.lab run --kinematic -- python x.py",
              file=sys.stderr)
        return 2
    if not netns.in_private_namespace():
        prefix = netns.unshare_command()
        if prefix is not None:
            os.execvpe(prefix[0], [*prefix, sys.executable, "-m", "sim.lab", "run", *sys.argv[2:]],
                       {**os.environ, netns.NETNS_ENV: "1"})
        host = args.host or "127.0.0.1"
        taken = netns.taken_port(host, [29999, 30003, 30004, 63352, CONTROL_PORT])
        if taken is not None:
            print(f"sim.lab run: no private network namespace here (unshare -n failed) and port {taken} on "
                  f"{host} is taken; free it or run as root", file=sys.stderr)
            return 2
        print(f"sim.lab run: no private network namespace here; serving on the host's {host}", file=sys.stderr)
    else:
        netns.loopback_up()
    watchdog = threading.Timer(args.ready_timeout, lambda: (
        print(f"sim.lab run: the emulator was not up within {args.ready_timeout:g} s", file=sys.stderr),
        os._exit(2)))
    watchdog.daemon = True
    watchdog.start()
    try:
        close = open_lab(args)
    except LabStartError as exc:
        print(f"sim.lab run: {exc}", file=sys.stderr)
        return 2
    finally:
        watchdog.cancel()
    try:
        client = subprocess.Popen(command)
        signal.signal(signal.SIGTERM, lambda signum, _frame: client.send_signal(signum))
        signal.signal(signal.SIGINT, lambda signum, _frame: client.send_signal(signum))
        code = client.wait()
    finally:
        close()
    return code if code >= 0 else 128 - code


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="python -m sim.lab", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    add_serve_options(commands.add_parser("serve", help="serve the emulated cell until stopped"))
    run_parser = commands.add_parser("run", help="run a command against a fresh emulated cell, then stop it")
    add_serve_options(run_parser)
    run_parser.add_argument("--ready-timeout", type=float, default=60.0,
                            help="seconds the emulator may take to start (default 60)")
    head, command = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, [])
    args = parser.parse_args(head)
    logging.basicConfig(level=args.log_level.upper(), format="sim.lab %(levelname)s %(name)s: %(message)s")
    return serve(args) if args.command == "serve" else run(args, command)


if __name__ == "__main__":
    sys.exit(main())
