"""A checkerboard calibration target carried by the twin's gripper (`python -m sim.lab run --calibration-board ...`).

The board is a flat plate, visual only (no collision shape: it does not touch the physics), fixed to the UR5's
flange at `T_flange_board`: its plane is the flange's x-z plane moved `BOARD_STANDOFF` along the flange's -y
(beside the 2F-85's body, across its closing direction x), its printed face looking along the flange's -y, the
centre of its grid of inner corners level with the TCP (`TCP_DEPTH` along the flange's z). At home (tool pointing
down) that face looks along the world's +x, away from the robot, towards the cameras.

The board frame is OpenCV's (`hardware.calibration.Checkerboard.object_points`): origin at the first inner corner,
x along the `columns` inner corners, y along the `rows`, z into the plate (away from a camera that sees its face).
Squares are real geometry: `columns + 1` by `rows + 1` squares of `square` metres, black ones 1 mm proud of a white
plate that leaves a white margin of one square all round (OpenCV's detector wants a quiet border). The black squares'
faces are at z = -1 mm in the board frame; hand-eye calibration solves the target's pose in the gripper itself, so
that millimetre is part of what it estimates, not an error.

`tour(T_world_cam, ...)` is a list of TCP poses (tool pointing down, tilted and turned) that show the board to a
table-mounted camera: what hardware/calibration_poses.emulated.yaml holds for the twin's cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from sim.world import pose_to_pb

#: The plate's standoff from the flange axis (m, along the flange's -y): clear of the 2F-85's body.
BOARD_STANDOFF = 0.06
#: The grid's centre along the flange's z (m): the twin's TCP (hardware/cell.emulated.yaml tcp_offset).
TCP_DEPTH = 0.144224
#: Thickness of the white plate and of the black squares on it (m).
PLATE_THICKNESS = 0.004
SQUARE_THICKNESS = 0.001


@dataclass(frozen=True)
class CalibrationBoard:
    """A checkerboard of `columns` x `rows` inner corners, squares of `square` m (one count even, one odd)."""

    columns: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if not (3 <= self.columns <= 20 and 3 <= self.rows <= 20 and 0.005 <= self.square <= 0.1):
            raise ValueError(f"calibration board: 3-20 inner corners a side and squares of 5-100 mm, got "
                             f"{self.columns}x{self.rows}:{self.square:g}")
        if (self.columns + self.rows) % 2 == 0:
            raise ValueError(f"calibration board {self.columns}x{self.rows}: one count even and one odd (else its "
                             "pose is ambiguous by 180 degrees)")

    @classmethod
    def parse(cls, text: str) -> CalibrationBoard:
        """`COLUMNSxROWS:SQUARE`, e.g. `7x6:0.03` (inner corners, square size in metres)."""
        try:
            corners, square = text.lower().split(":")
            columns, rows = (int(n) for n in corners.split("x"))
            return cls(columns, rows, float(square))
        except ValueError as exc:
            raise ValueError(f"--calibration-board wants COLUMNSxROWS:SQUARE_M such as 7x6:0.03, got {text!r}"
                             + (f" ({exc})" if "calibration board" in str(exc) else "")) from None

    @property
    def size(self) -> tuple[float, float]:
        """The plate's width (along the board's x) and height (y), with a one-square margin (m)."""
        return (self.columns + 3) * self.square, (self.rows + 3) * self.square

    @property
    def centre(self) -> np.ndarray:
        """The centre of the grid of inner corners in the board frame (m)."""
        return np.array([(self.columns - 1) * self.square / 2, (self.rows - 1) * self.square / 2, 0.0])

    @property
    def T_flange_board(self) -> np.ndarray:
        """The board frame in the flange frame (module docstring)."""
        T = np.eye(4)
        T[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # x = fx, y = -fz, z = fy
        T[:3, 3] = np.array([0.0, -BOARD_STANDOFF, TCP_DEPTH]) - T[:3, :3] @ self.centre
        return T

    def squares(self) -> list[tuple[float, float]]:
        """Centres (board x, y) of the black squares; the square before the first inner corner is black."""
        s = self.square
        return [((i - 0.5) * s, (j - 0.5) * s) for i in range(self.columns + 1) for j in range(self.rows + 1)
                if (i + j) % 2 == 0]


class BoardBodies:
    """The board in a PyBullet world: a white plate and the black squares, visual-only bodies moved together."""

    def __init__(self, client, board: CalibrationBoard) -> None:
        self.client, self.board = client, board
        width, height = board.size
        centre = board.centre[:2]
        plate = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=[width / 2, height / 2, PLATE_THICKNESS / 2],
                                         rgbaColor=[1.0, 1.0, 1.0, 1.0], specularColor=[0.0, 0.0, 0.0])
        black = client.createVisualShape(pybullet.GEOM_BOX,
                                         halfExtents=[board.square / 2, board.square / 2, SQUARE_THICKNESS / 2],
                                         rgbaColor=[0.02, 0.02, 0.02, 1.0], specularColor=[0.0, 0.0, 0.0])
        #: (body, its centre in the board frame)
        self.parts = [(client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=plate),
                       np.array([*centre, PLATE_THICKNESS / 2]))]
        for x, y in board.squares():
            self.parts.append((client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=black),
                               np.array([x, y, -SQUARE_THICKNESS / 2])))

    def place(self, T_world_flange: np.ndarray) -> np.ndarray:
        """Move the board with the flange; returns T_world_board."""
        T_world_board = np.asarray(T_world_flange, dtype=float) @ self.board.T_flange_board
        _, orientation = pose_to_pb(T_world_board)
        for body, centre in self.parts:
            position = T_world_board[:3, :3] @ centre + T_world_board[:3, 3]
            self.client.resetBasePositionAndOrientation(body, position.tolist(), orientation)
        return T_world_board


#: (tilt towards the camera about the tool's x, about its y, turn about its z) in degrees, and the board centre's
#: offset (m, world x, y, z) from the tour's centre, per pose of `tour`.
TOUR = ((15, 0, 0, (0.0, 0.0, 0.0)), (30, 0, 15, (0.04, -0.05, 0.03)), (5, 15, -15, (-0.05, 0.04, -0.03)),
        (25, -15, 10, (0.05, 0.04, 0.02)), (20, 10, -20, (-0.04, -0.05, 0.03)), (10, -10, 25, (0.0, 0.06, -0.02)),
        (35, 5, -5, (-0.06, 0.0, 0.01)), (15, -15, 0, (0.03, -0.03, 0.04)))


def tour(T_world_cam: np.ndarray, board: CalibrationBoard, distance: float = 0.6, height: float = 0.17,
         tcp_depth: float = TCP_DEPTH) -> list[np.ndarray]:
    """TCP poses (T_world_tcp, the TCP `tcp_depth` along the flange's z) that show the board to a fixed camera:
    its centre near the camera's optical axis `distance` m away, raised to `height`, the tool pointing down and
    the board turned towards the camera, then tilted and turned by each of `TOUR`'s angles."""
    T_world_cam = np.asarray(T_world_cam, dtype=float)
    eye, axis = T_world_cam[:3, 3], T_world_cam[:3, 2]
    centre = eye + distance * axis
    centre[2] = height
    a = np.arctan2(eye[1] - centre[1], eye[0] - centre[0])  # the camera's azimuth seen from the board
    R0 = np.column_stack([[np.sin(a), -np.cos(a), 0.0], [-np.cos(a), -np.sin(a), 0.0], [0.0, 0.0, -1.0]])
    T_flange_board = board.T_flange_board
    grid_centre = T_flange_board[:3, :3] @ board.centre + T_flange_board[:3, 3]  # in the flange frame
    poses = []
    for tilt, side, turn, offset in TOUR:
        R = R0 @ Rotation.from_euler("xyz", [tilt, side, turn], degrees=True).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        flange = centre + np.asarray(offset) - R @ grid_centre
        T[:3, 3] = flange + R @ np.array([0.0, 0.0, tcp_depth])
        poses.append(T)
    return poses
