"""The real cell: a UR5/UR5e over ur_rtde, a Robotiq 2F-85 over its URCap socket and RealSense cameras.

`RealCell.from_config("cell.yaml", dry_run=False)` builds a `seggrasp.cell.Cell`; see docs/robot.md and
hardware/cell.example.yaml.
"""

from hardware.cell import RealCell
from hardware.config import CellConfig, ConfigError, load_config
from hardware.errors import (ConnectionLostError, GripperError, HardwareError, MotionError, RobotStoppedError,
                             SafetyError)

__all__ = ["RealCell", "CellConfig", "ConfigError", "load_config", "HardwareError", "SafetyError",
           "ConnectionLostError", "RobotStoppedError", "GripperError", "MotionError"]
