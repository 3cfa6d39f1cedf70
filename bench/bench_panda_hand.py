"""The Franka Hand in the twin, measured the way the 2F-85 was (docs/results/twin-physics.md): closing on boxes and
cylinders (width error, penetration, symmetry, the squeeze), the Panda's IK error, and grasp-and-lift trials of
twin objects with the sampler's grasps for the Franka Hand, beside the UR5 + 2F-85 on the same scenes.

    python bench/bench_panda_hand.py [--objects hammer_claw,mug_classic,screwdriver_flat,spatula_turner] [--grasps 5]
        [--out docs/results/panda-hand.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scipy.spatial.transform import Rotation  # noqa: E402

from seggrasp.grasp import AntipodalSampler  # noqa: E402
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85  # noqa: E402
from seggrasp.io import atomic_write_text  # noqa: E402
from seggrasp.objects import load_asset  # noqa: E402
from sim.cell import ROBOTS, SimCell  # noqa: E402
from sim.gripper import GripperSettings  # noqa: E402
from sim.primitives import primitive_object, top_down_grasp  # noqa: E402
from sim.robot import pose_error  # noqa: E402
from sim.world import COLLISION_SKIN  # noqa: E402

SIZES_MM = (10, 30, 60)
SMALL = dict(image_size=(64, 48), n_cameras=1)
#: Grasps looked at per object for the lift trials (best first; the unreachable ones are skipped).
MAX_CANDIDATES = 60


def close_on(robot: str, kind: str, size_mm: int, force: float, directory: str) -> tuple[float, ...]:
    """(width error, penetration, asymmetry, pad normal force) after closing on a resting box or cylinder: the
    Panda's hand placed by the arm, the 2F-85 on the floating gripper (as tests/test_sim_gripper.py)."""
    s = size_mm / 1000
    shape = ("box", (s, 0.05, 0.06)) if kind == "box" else ("cylinder", (s / 2, 0.06))
    obj = primitive_object(*shape, directory, mass=0.2)
    hand = ROBOTS[robot]
    embodiment = "arm" if robot == "panda" else "floating"
    with SimCell([obj], embodiment=embodiment, robot=robot, seed=0, gripper=GripperSettings(force, hand=hand),
                 **SMALL) as cell:
        cell.reset(seed=1)
        _, T_world_obj = cell.object_mesh()
        gripper = cell.robot.gripper
        T_base = top_down_grasp(T_world_obj, 0.04) @ np.linalg.inv(gripper.T_base_tcp(s))
        cell.robot.place(cell.robot.ik(T_base)[0] if robot == "panda" else T_base)
        gripper.set_width(min(s + 0.02, gripper.max_width))
        gripper.close_until_stall()
        cell.world.step(60)
        T_base_world = np.linalg.inv(cell.world.link_pose(gripper.body, gripper.base_link))
        left, right = (T_base_world @ cell.world.link_pose(gripper.body, link) for link in gripper.pad_links)
        axis = 1 if robot == "panda" else 0  # the Franka Hand closes along its link's y, the 2F-85 along x
        gap = abs(left[axis, 3] - right[axis, 3]) - hand.pad_thickness
        contacts = [p for side in gripper.fingertip_links for link in side
                    for p in cell.world.client.getContactPoints(gripper.body, cell.object_body, linkIndexA=link)]
        return (gap - s - 2 * COLLISION_SKIN, -min((p[8] for p in contacts), default=0.0), gripper.finger_asymmetry(),
                sum(p[9] for p in contacts))


def ik_errors(n: int, directory: str) -> tuple[int, float, float, float]:
    """(poses reached of n, max position error m, max angle error deg, median solve time s) over random grasp
    poses above the workspace (tilted up to 35 deg from straight down)."""
    rng = np.random.default_rng(0)
    obj = primitive_object("box", (0.03, 0.03, 0.03), directory)
    reached, position, angle, times = 0, 0.0, 0.0, []
    with SimCell([obj], robot="panda", **SMALL) as cell:
        arm = cell.robot
        for _ in range(n):
            T = np.eye(4)
            T[:3, :3] = (Rotation.from_euler("z", rng.uniform(-np.pi, np.pi))
                         * Rotation.from_euler("xy", rng.uniform(-0.6, 0.6, 2)) * Rotation.from_euler("x", np.pi)
                         ).as_matrix()
            T[:3, 3] = [rng.uniform(0.35, 0.65), rng.uniform(-0.2, 0.2), rng.uniform(0.12, 0.35)]
            start = time.perf_counter()
            q, _ = arm.ik(T)
            times.append(time.perf_counter() - start)
            if q is None:
                continue
            reached += 1
            p, a = pose_error(arm.fk(q), T)
            position, angle = max(position, p), max(angle, np.rad2deg(a))
    return reached, position, angle, float(np.median(times))


def lift_trials(object_id: str, robot: str, grasps: int, scene_seed: int = 3) -> list[str]:
    """The outcomes of the sampler's best `grasps` reachable grasps (among its best `MAX_CANDIDATES`) for the robot's
    hand on one twin object."""
    model = load_asset(object_id)
    hand = ROBOTS[robot]
    outcomes = []
    with SimCell([model], robot=robot, seed=0, **SMALL) as cell:
        cell.reset(seed=scene_seed, object_id=object_id)
        mesh, T = cell.object_mesh()
        up = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        plane = np.r_[up, T[2, 3]]
        candidates = AntipodalSampler(gripper=hand).generate(mesh, seed=0, table_plane=plane, mass=model.mass)
        candidates = candidates.transformed(T)
        for pose, width in zip(candidates.poses[:MAX_CANDIDATES], candidates.widths[:MAX_CANDIDATES]):
            if len(outcomes) == grasps:
                break
            cell.reset(seed=scene_seed, object_id=object_id)  # the checks and each grasp start from the scene
            if cell.check_reach(pose, width):
                continue
            outcome = cell.execute(pose, width)
            outcomes.append(f"{width * 1000:.0f} mm " + ("lifted" if outcome.lifted else outcome.failure))
    return outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", default="hammer_claw,mug_classic,screwdriver_flat,spatula_turner")
    parser.add_argument("--grasps", type=int, default=5)
    parser.add_argument("--ik-poses", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("docs/results/panda-hand.md"))
    args = parser.parse_args()
    started = time.perf_counter()
    lines = [f"load average before the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", ""]
    lines += ["## Closing on a resting box or cylinder", "",
              "Pad gap minus the true width (after PyBullet's 1 mm contact margin on each side), the deepest "
              "penetration, the pads' distance from mirror symmetry, and the fingers' total normal force, 0.25 s "
              "after they stall. The Franka Hand on the Panda; the 2F-85 on the floating gripper.", "",
              "| hand | force N | object | width error mm | penetration mm | asymmetry mm | squeeze N |",
              "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for robot, forces in (("panda", (FRANKA_HAND.grip_force_range[0], FRANKA_HAND.continuous_grip_force,
                                         FRANKA_HAND.grip_force_range[1])),
                              ("ur5", (ROBOTIQ_2F85.grip_force_range[0], ROBOTIQ_2F85.default_grip_force))):
            for force in forces:
                for kind in ("box", "cylinder"):
                    for size in SIZES_MM:
                        e, p, a, f = close_on(robot, kind, size, force, tmp)
                        lines.append(f"| {ROBOTS[robot].name} | {force:g} | {kind} {size} mm | {e * 1000:+.2f} | "
                                     f"{p * 1000:.2f} | {a * 1000:.3f} | {f:.0f} |")
                        print(lines[-1], flush=True)
        reached, position, angle, solve = ik_errors(args.ik_poses, tmp)
    lines += ["", "## The Panda's IK", "",
              f"{reached} of {args.ik_poses} random grasp poses above the workspace reached (x 0.35-0.65 m, y +-0.2 m, "
              f"z 0.12-0.35 m, up to 35 deg from straight down); the largest error of an accepted solution "
              f"{position * 1000:.3f} mm and {angle:.3f} deg (accepted within 5 mm / 3 deg, as the UR5's); median "
              f"solve {solve * 1000:.1f} ms.", ""]
    print("\n".join(lines[-3:]), flush=True)
    lines += ["## Grasp-and-lift of twin objects", "",
              f"The sampler's best {args.grasps} reachable grasps for each hand (`AntipodalSampler(gripper=hand)`, "
              "seed 0) on one scene (scene seed 3), each from a reset, at each hand's default force (Franka "
              f"{FRANKA_HAND.default_grip_force:g} N, 2F-85 {ROBOTIQ_2F85.default_grip_force:g} N).", "",
              "| object | Panda + Franka Hand | UR5 + 2F-85 |", "|---|---|---|"]
    for object_id in args.objects.split(","):
        row = [", ".join(lift_trials(object_id, robot, args.grasps)) for robot in ("panda", "ur5")]
        lines.append(f"| {object_id} | {row[0]} | {row[1]} |")
        print(lines[-1], flush=True)
    lines += ["", f"({time.perf_counter() - started:.0f} s)"]
    command = f"python bench/bench_panda_hand.py --objects {args.objects} --grasps {args.grasps} --ik-poses {args.ik_poses}"
    atomic_write_text(args.out, f"# The Franka Hand in the twin\n\n`{command}`\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
