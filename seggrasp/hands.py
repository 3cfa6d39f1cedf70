"""The hands: one description per parallel gripper, the only place a hand's numbers are written.

Everything the method and the twin know about a gripper comes from its `Hand`: the stroke, the pads, the box model
of its fingers and body that the grasp sampler checks for collisions, the contact depths it tries along the pads,
its margins below the stroke and above the table, the grip force range and the finger speed. The grasp sampler,
the pad footprint, the pinch and envelope poses, the ShapeGrasp baseline, the learned-generator adapter, the twin's
drive, its grasp primitive, `check_reach` and the gym action space read it (`seggrasp.grasp`, `sim.gripper`,
`sim.panda_hand`, `sim.cell`, `sim.env`).

Gripper frame (docs/design.md section 3): z = approach, x = closing direction (finger to finger), origin between the
pad centres with the fingers open. Box models are in that frame, in metres.

Two hands:

- `ROBOTIQ_2F85`: the Robotiq 2F-85 of the UR5 cell. Datasheet: 85 mm stroke, grip force 20-235 N, finger speed
  20-150 mm/s; pads 22 x 37.5 mm. Its box model is a ray-probed profile of the simulated gripper's collision
  geometry (sim/gripper_urdf.py).
- `FRANKA_HAND`: the Franka Hand of the Franka Panda. Grip force and stroke as issue 36 quotes Franka's datasheet:
  70 N continuous and 140 N maximum grip force, 80 mm stroke (40 mm per finger; pybullet_data's panda.urdf gives
  each finger joint 0-0.04 m). Finger speed: libfranka's `Gripper::move(width, speed)` and
  `grasp(width, speed, force)` take the closing speed in m/s, and frankx, a wrapper of libfranka, caps it at
  `Gripper::max_speed = 0.1` m/s (https://pantor.github.io/frankx/classfrankx_1_1_gripper.html, "max_speed {0.1}
  // [m/s]", with `max_width {0.081 + width_calibration}`, a 4 mm jaw calibration), i.e. 50 mm/s per finger, which
  the twin closes at. The lower ends of the force and speed ranges are not datasheet figures (none was found in
  the references this was written from): 20 N, the force frankx's `Gripper` grasps with by default
  (`Gripper(fci_ip, speed=0.04, force=20.0)`), and 5 mm/s per finger. Franka's own datasheet page was not among
  those references; 70 N is also what NVlabs used on their Panda's hand for every object
  (https://github.com/NVlabs/6dof-graspnet/issues/12). Pads: the fingertip's flat inner face in pybullet_data's
  franka_panda/meshes/collision/finger.obj, 17.4 mm wide (x +-8.7 mm) and 17.6 mm long (z 36.1-53.7 mm of the
  finger); the box model is that finger and the hand body (hand.obj: 208 mm across the closing direction, 63 mm
  deep) with the wrist behind it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Hand:
    """One parallel gripper (module docstring).

    - `stroke`: the widest pad gap (m);
    - `pad_half_width`, `pad_half_length`: the pad's footprint across the closing plane (y) and along the approach
      (z); `pad_thickness`: how far the two pad links' frames stand behind their contact faces together (the
      simulated description's pad gap is the distance between those frames minus this);
    - `tip_beyond_origin`: how far the fingertips reach past the origin along +z;
    - `finger_boxes` move with the fingers; each is (inner x, outer x, half y, z min, z max) with x measured
      outwards from the finger's inner face at half the opening (mirrored for the other finger);
      `centre_boxes` are fixed and centred on the z axis: (half x, half y, z min, z max);
    - `pre_grasp_margin`: extra opening on each side of the contacts while approaching; `width_margin`: how far
      below the stroke a planned grasp's contact distance stays (the fingers open no wider than the stroke, so this
      is the least they clear the contacts by on the way in, both sides together);
    - `contact_depths`: where along the pads (m from their centre, + towards the fingertips) the sampler tries the
      contacts, deepest first; `pinch_contact_depths`: those of a fingertip pinch of a part lying flat, and
      `pinch_table_clearance` how far above the table the fingertips stay in one (the cell must allow them that
      close: sim.grasp_primitive.GraspSettings.fingertip_table_clearance, the real cell's limits.min_table_clearance);
    - `pad_end_margin`: a pad whose first touch lies only within this much of its fingertip end does not hold (m);
    - `grip_force_range` (N) and `default_grip_force`; `continuous_grip_force` where the hand distinguishes a
      force it holds indefinitely from its maximum;
    - `finger_speed_range` (m/s) and `closing_speed`, the twin's closing speed of each pad (m/s).
    """

    name: str
    stroke: float
    pad_half_width: float
    pad_half_length: float
    pad_thickness: float
    tip_beyond_origin: float
    finger_boxes: tuple[tuple[float, float, float, float, float], ...]
    centre_boxes: tuple[tuple[float, float, float, float], ...]
    pre_grasp_margin: float
    width_margin: float
    contact_depths: tuple[float, ...]
    pinch_contact_depths: tuple[float, ...]
    pinch_table_clearance: float
    grip_force_range: tuple[float, float]
    default_grip_force: float
    finger_speed_range: tuple[float, float]
    closing_speed: float
    pad_end_margin: float = 0.0
    continuous_grip_force: float | None = None

    def __post_init__(self) -> None:
        low, high = self.grip_force_range
        if not 0 < low <= self.default_grip_force <= high:
            raise ValueError(f"{self.name}: default grip force {self.default_grip_force} outside {low}-{high} N")
        if any(abs(d) >= self.pad_half_length for d in self.contact_depths + self.pinch_contact_depths):
            raise ValueError(f"{self.name}: contact depths must lie on the pad (|d| < {self.pad_half_length})")
        if min(self.stroke, self.pad_half_width, self.pad_half_length) <= 0:
            raise ValueError(f"{self.name}: stroke and pad size must be positive")
        if not 0 <= self.width_margin < self.stroke:
            raise ValueError(f"{self.name}: width_margin must lie within the stroke (0 to {self.stroke} m)")
        if self.pinch_table_clearance < 0:
            raise ValueError(f"{self.name}: pinch_table_clearance must not be negative")
        if not 0 <= self.pad_end_margin < 2 * self.pad_half_length:
            raise ValueError(f"{self.name}: pad_end_margin must lie on the pad (0 to {2 * self.pad_half_length} m)")

    @property
    def torsion_radius(self) -> float:
        """The mean contact radius (m) of the narrowest patch a pad makes: a line across its width, width / 4."""
        return self.pad_half_width / 2.0

    @property
    def whole_pad_torsion_radius(self) -> float:
        """The mean contact radius (m) of the widest patch a pad makes, its whole face (a flat wall): the mean
        distance of the pad's rectangle from its centre, an upper bound on what its torsional friction holds."""
        a, b = self.pad_half_width, self.pad_half_length
        d = np.hypot(a, b)
        return float((2 * a * b * d + a**3 * np.log((b + d) / a) + b**3 * np.log((a + d) / b)) / (6 * a * b))

    def pre_grasp_opening(self, width: np.ndarray | float) -> np.ndarray:
        """Finger separation while approaching a grasp of contact distance `width` (capped at the stroke)."""
        return np.minimum(np.asarray(width, dtype=np.float64) + 2.0 * self.pre_grasp_margin, self.stroke)

    def boxes(self, opening: float) -> np.ndarray:
        """Axis-aligned boxes (B, 2, 3) [min corner, max corner] of the gripper opened to `opening`: both fingers'
        boxes (-x finger first), then the centre boxes."""
        half = 0.5 * float(opening)
        boxes = []
        for sign in (-1.0, 1.0):
            for inner, outer, half_y, z_min, z_max in self.finger_boxes:
                x0, x1 = sign * (half + inner), sign * (half + outer)
                boxes.append([[min(x0, x1), -half_y, z_min], [max(x0, x1), half_y, z_max]])
        for half_x, half_y, z_min, z_max in self.centre_boxes:
            boxes.append([[-half_x, -half_y, z_min], [half_x, half_y, z_max]])
        return np.array(boxes, dtype=np.float64)


ROBOTIQ_2F85 = Hand(
    name="robotiq_2f85",
    stroke=0.085,
    pad_half_width=0.011,
    pad_half_length=0.01875,
    pad_thickness=0.00635,
    tip_beyond_origin=0.020,
    finger_boxes=(
        (0.0, 0.024, 0.012, -0.020, 0.020),  # the pad and the tip of the finger
        (-0.008, 0.036, 0.018, -0.045, -0.020),  # its wedge-shaped base, leaning inwards toward the knuckles
    ),
    centre_boxes=(
        (0.078, 0.022, -0.095, -0.045),  # the knuckles
        (0.047, 0.043, -0.150, -0.045),  # the gripper body
        (0.045, 0.045, -0.270, -0.150),  # the wrist behind it
    ),
    pre_grasp_margin=0.012,
    width_margin=0.005,
    # 3 mm steps, never within 6.75 mm of either end of the 37.5 mm pads
    contact_depths=(-0.012, -0.009, -0.006, -0.003, 0.0, 0.003, 0.006, 0.009, 0.012),
    # 3.75 / 2.25 mm from the pad's end (the pad still touches the part's side from there to its top)
    pinch_contact_depths=(0.015, 0.0165),
    # 0.5 mm above the least the cell allows: its pinches from 1.0 mm lifted none of the parts this judges too low
    # (docs/results/infeasible-requests.md)
    pinch_table_clearance=0.0015,
    # its inner finger curves away past the pad's end: what the pad's last 2 mm alone land on (an eyeglass rim's top,
    # a chef's blade's edge) squeezes out, 51 of 131 oracle grasps lifted, against 84 of 85 from 2-3 mm in
    # (docs/results/pad-reach.md)
    pad_end_margin=0.002,
    grip_force_range=(20.0, 235.0),
    # its full force: pans, kettles and hammers held by their handles turn in the fingers under their own weight
    # at 100 N (docs/results/archive/twin-physics-rounds.md, fifth round)
    default_grip_force=235.0,
    finger_speed_range=(0.020, 0.150),
    closing_speed=0.075,
)

FRANKA_HAND = Hand(
    name="franka_hand",
    stroke=0.080,
    pad_half_width=0.0087,
    pad_half_length=0.0088,
    # the finger links' frames lie on their inner faces (finger.obj: y = 0 from z 36 to 54 mm)
    pad_thickness=0.0,
    tip_beyond_origin=0.0089,
    finger_boxes=(
        (0.0, 0.0145, 0.0105, -0.009, 0.0089),  # the fingertip, 14.3 mm thick behind its pad
        (0.0, 0.0265, 0.0105, -0.045, -0.009),  # the finger's base, 26.4 mm thick at the hand
    ),
    centre_boxes=(
        (0.1045, 0.032, -0.1295, -0.0370),  # the hand body (hand.obj), 45 mm behind the fingers' root
        (0.050, 0.050, -0.2600, -0.1295),  # the wrist (panda_link7 and the flange) behind it
    ),
    pre_grasp_margin=0.012,
    # 1 mm less than the 2F-85's: the gooseneck kettle's body is held only across its top, 75.1-75.9 mm wide
    # (docs/results/panda-width-margin-oracle-seeds0-4.md)
    width_margin=0.004,
    # 3 mm steps within the 17.6 mm pad, 2.8 mm clear of either end
    contact_depths=(-0.006, -0.003, 0.0, 0.003, 0.006),
    pinch_contact_depths=(0.0065,),
    # the least the cell allows: its pinch contact sits 2.4 mm from the fingertip (the 2F-85's 3.5-5 mm), and from
    # 1.5 mm (as the 2F-85 pinches) or 1.2 mm the judgement refused scissor blades and eyeglass rims that its
    # pinches from 1.1 mm lift (docs/results/infeasible-requests.md)
    pinch_table_clearance=0.001,
    # none: its flat pad runs to the finger's end; what it lands on within 1 mm of that end lifts as often as what
    # it lands on deeper, but for the kettles' bodies, which fail at the handle's junction (docs/results/pad-reach.md)
    pad_end_margin=0.0,
    grip_force_range=(20.0, 140.0),
    default_grip_force=70.0,
    continuous_grip_force=70.0,
    finger_speed_range=(0.005, 0.050),
    closing_speed=0.050,
)

HANDS = {hand.name: hand for hand in (ROBOTIQ_2F85, FRANKA_HAND)}
