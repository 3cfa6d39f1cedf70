"""Exceptions raised by the hardware bridge. All derive from `HardwareError`."""

from __future__ import annotations


class HardwareError(RuntimeError):
    """Something went wrong while talking to the real cell. Raised after a grasp was judged (while putting the
    object back), `outcome` holds that judgement (a `seggrasp.cell.GraspOutcome`); None otherwise."""

    outcome = None


class SafetyError(HardwareError):
    """A motion or command was refused because it breaks a configured limit; nothing was sent."""


class ConnectionLostError(HardwareError):
    """The connection to the robot, gripper or a camera was lost; the cell stopped what it was doing."""


class RobotStoppedError(HardwareError):
    """The robot is in a protective stop or an emergency stop and needs a person to clear it."""


class GripperError(HardwareError):
    """The gripper refused a command, reported a fault or did not finish in time."""


class MotionError(HardwareError):
    """A motion command was rejected by the controller, timed out or ended away from its target."""
