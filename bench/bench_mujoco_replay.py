"""Replay a run's executed twin trials in a second physics engine, MuJoCo (soft contacts, elliptic friction cones),
to tell a grasp the twin drops because of how PyBullet resolves its contacts from one that fails in physics.

    python bench/bench_mujoco_replay.py --run DIR --requests knife_chef:blade,knife_bread:blade [--limit 10]
        [--out docs/results/mujoco-replay.md]

The scene: the object as the twin has it (its collision hulls, mass, inertia, friction) at the pose the trial's
scene seed settles it in, on a plane at the twin's table top; the trial's hand (`seggrasp.hands`, by the record's
robot) as its two fingertip boxes (`Hand.finger_boxes[0]`: pad and tip) on slides under a hand body welded to a
kinematic target. The trial follows the twin's grasp primitive (`sim.grasp_primitive.GraspSettings`): pre-grasp
`pregrasp_distance` back along the approach with the fingers open at the width + `width_margin`, approach, close at
the hand's closing speed with the run's grip force as the servo's limit (so the pads squeeze with it once they
stall), lift `lift_height` at `lift_speed`, hold `hold_time`. It succeeds as in the twin: the grasped point rose at
least `LIFT_SUCCESS` and the prompted part carries most of the pads' normal force (contact points to the nearest
mesh face, `GroundTruth.touched_on_part`). Left out: the arm (the hand goes where it is commanded), the fingers'
bodies behind the tips, and the twin's slip and turn limits in the fingers.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_lab import command_line, commit, publish  # noqa: E402
from seggrasp.cell import LIFT_SUCCESS, GraspOutcome  # noqa: E402
from seggrasp.hands import Hand  # noqa: E402
from seggrasp.objects import ObjectModel, asset_ids, load_asset  # noqa: E402
from seggrasp.truth import GroundTruth  # noqa: E402
from sim.cell import SimCell  # noqa: E402
from sim.evaluate.config import RunConfig  # noqa: E402
from sim.evaluate.records import JsonLines, load_run, robot_of, seed_of  # noqa: E402
from sim.grasp_primitive import GraspSettings, touched_faces  # noqa: E402
from sim.gripper import PAD_FRICTION  # noqa: E402
from sim.world import TABLE_FRICTION, TABLE_TOP_Z  # noqa: E402

#: Integration step (s) and the contacts' solver reference (time constant s, damping ratio): stiff enough that
#: the squeeze sinks the pads well under a millimetre into the object.
TIME_STEP = 0.0005
CONTACT_SOLREF = "0.002 1"
#: Stiffness (N/m) and damping (N s/m) of each finger's slide servo; its force saturates at the grip force.
SERVO_KP = 20000.0
SLIDE_DAMPING = 20.0
#: Mass (kg) of each fingertip and of the hand body (both weightless: gravity compensated, as a servoed hand is).
FINGER_MASS = 0.05
HAND_MASS = 1.0
#: Time (s) the object rests on the table before the approach.
SETTLE_TIME = 0.2


@dataclass(frozen=True)
class Replay:
    """One trial in MuJoCo: how far the grasped point rose (m), whether the prompted part carried most of the
    squeeze (None: the pads touched nothing at the end), and the twin's success."""

    rise: float
    on_part: bool | None
    twin_success: bool

    @property
    def success(self) -> bool:
        return self.rise >= LIFT_SUCCESS and bool(self.on_part)

    @property
    def failure(self) -> str:
        """"" for a success; `dropped` (not risen enough) or `wrong_part`."""
        return "" if self.success else ("dropped" if self.rise < LIFT_SUCCESS else "wrong_part")


def _quat(rotation: np.ndarray) -> str:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return f"{w:.9f} {x:.9f} {y:.9f} {z:.9f}"


def _vector(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def scene_xml(model: ObjectModel, T_world_obj: np.ndarray, T_world_grasp: np.ndarray, opening: float, hand: Hand,
              grip_force: float) -> str:
    """The MJCF of one trial (module doc): `T_world_grasp` is the grasp's TCP pose (x closing, z approach), the
    fingers open at `opening`."""
    mu = model.friction * PAD_FRICTION  # PyBullet multiplies the two bodies' coefficients
    torsion = hand.torsion_radius
    meshes = "".join(f'<mesh name="hull{k}" vertex="{_vector(h.vertices.ravel())}"/>'
                     for k, h in enumerate(model.collision_hulls))
    hulls = "".join(f'<geom type="mesh" mesh="hull{k}" friction="{mu:g} {torsion:g} 0.0001" condim="4" priority="1" '
                    f'solref="{CONTACT_SOLREF}"/>' for k in range(len(model.collision_hulls)))
    inner, outer, half_y, z_min, z_max = hand.finger_boxes[0]
    half = ((outer - inner) / 2, half_y, (z_max - z_min) / 2)
    centre_x, centre_z = opening / 2 + (inner + outer) / 2, (z_min + z_max) / 2
    fingers = "".join(
        f'<body name="finger{side}" gravcomp="1"><joint name="slide{side}" type="slide" axis="{-sign} 0 0" '
        f'damping="{SLIDE_DAMPING:g}"/><geom type="box" size="{_vector(half)}" pos="{sign * centre_x:.9g} 0 '
        f'{centre_z:.9g}" mass="{FINGER_MASS:g}" friction="{PAD_FRICTION:g} {torsion:g} 0.0001" condim="4" '
        f'solref="{CONTACT_SOLREF}"/></body>' for side, sign in ((0, -1), (1, 1)))
    servos = "".join(f'<position joint="slide{side}" kp="{SERVO_KP:g}" forcelimited="true" '
                     f'forcerange="{-grip_force:g} {grip_force:g}"/>' for side in (0, 1))
    inertia = np.maximum(np.diag(model.inertia), 1e-9)
    grasp = f'pos="{_vector(T_world_grasp[:3, 3])}" quat="{_quat(T_world_grasp[:3, :3])}"'
    return f"""<mujoco>
<option timestep="{TIME_STEP:g}" cone="elliptic" impratio="10" integrator="implicitfast"/>
<asset>{meshes}</asset>
<worldbody>
 <geom type="plane" size="2 2 0.1" pos="0 0 {TABLE_TOP_Z:g}" priority="2"
  friction="{TABLE_FRICTION * model.friction:g} 0.001 0.0001"/>
 <body name="object" pos="{_vector(T_world_obj[:3, 3])}" quat="{_quat(T_world_obj[:3, :3])}"><freejoint/>
  <inertial pos="{_vector(model.center_of_mass)}" mass="{model.mass:g}" diaginertia="{_vector(inertia)}"/>{hulls}</body>
 <body name="target" mocap="true" {grasp}/>
 <body name="hand" {grasp} gravcomp="1"><freejoint/>
  <inertial pos="0 0 0" mass="{HAND_MASS:g}" diaginertia="0.01 0.01 0.01"/>{fingers}</body>
</worldbody>
<equality><weld body1="hand" body2="target" solref="{CONTACT_SOLREF}"/></equality>
<actuator>{servos}</actuator>
</mujoco>"""


def replay(model: ObjectModel, prompt: str, T_world_obj: np.ndarray, T_world_grasp: np.ndarray, width: float,
           hand: Hand, grip_force: float, twin_success: bool = False, settings: GraspSettings = GraspSettings()
           ) -> Replay:
    """One trial of a grasp (world TCP pose and width) on `model` resting at `T_world_obj` (module doc)."""
    opening = min(width + settings.width_margin, hand.stroke)
    m = mujoco.MjModel.from_xml_string(scene_xml(model, T_world_obj, T_world_grasp, opening, hand, grip_force))
    d = mujoco.MjData(m)
    obj, fingers = m.body("object").id, {m.body("finger0").id, m.body("finger1").id}
    approach, grasp = T_world_grasp[:3, 2], T_world_grasp[:3, 3].copy()

    def run(seconds: float, target=None, closing=None) -> None:
        for step in range(int(round(seconds / TIME_STEP))):
            t = step * TIME_STEP
            if target is not None:
                d.mocap_pos[0] = target(t)
            if closing is not None:
                d.ctrl[:] = closing(t)
            mujoco.mj_step(m, d)

    def object_pose() -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = d.xmat[obj].reshape(3, 3), d.xpos[obj]
        return T

    back = settings.pregrasp_distance
    start = grasp - back * approach
    d.mocap_pos[0] = start
    d.qpos[7:10] = start  # the hand's free joint: at the pre-grasp, welded to the target
    mujoco.mj_forward(m, d)
    run(SETTLE_TIME)
    T_obj_start = object_pose()
    run(back / settings.approach_speed + 0.05,
        target=lambda t: start + min(t * settings.approach_speed, back) * approach)
    # the servo's target runs past the centre, so a finger stalled on the object pushes with the grip force
    limit = opening / 2 + grip_force / SERVO_KP + 0.001
    run(limit / hand.closing_speed + 0.2, closing=lambda t: np.full(2, min(t * hand.closing_speed, limit)))
    T_tcp = np.eye(4)
    T_tcp[:3, :3], T_tcp[:3, 3] = d.xmat[m.body("hand").id].reshape(3, 3), d.xpos[m.body("hand").id]
    point = np.linalg.inv(object_pose()) @ T_tcp[:, 3]  # the grasped point, object frame
    lift = settings.lift_height
    run(lift / settings.lift_speed + settings.hold_time,
        target=lambda t: grasp + np.array([0.0, 0.0, min(t * settings.lift_speed, lift)]))
    rise = float((object_pose() @ point)[2] - (T_obj_start @ point)[2])
    return Replay(rise, _on_part(m, d, model, prompt, obj, fingers, object_pose()), twin_success)


def _on_part(m, d, model: ObjectModel, prompt: str, obj: int, fingers: set[int], T_world_obj: np.ndarray
             ) -> bool | None:
    """Whether `prompt`'s part carries most of the fingertips' normal force on the object now (None: no contact)."""
    points, forces = [], []
    for k, contact in enumerate(d.contact[:d.ncon]):
        bodies = {int(m.geom_bodyid[contact.geom1]), int(m.geom_bodyid[contact.geom2])}
        if obj in bodies and bodies & fingers:
            wrench = np.zeros(6)
            mujoco.mj_contactForce(m, d, k, wrench)
            points.append(contact.pos.copy())
            forces.append(wrench[0])
    if not points:
        return None
    local = (np.asarray(points) - T_world_obj[:3, 3]) @ T_world_obj[:3, :3]
    faces, weights = touched_faces(model.mesh, local, forces)
    outcome = GraspOutcome(True, True, 0.0, touched_faces=faces, touched_weights=weights)
    return GroundTruth.of_object(model, model.prompts).touched_on_part(outcome, model.prompts.index(prompt))


def replay_run(run: Path, config: RunConfig, requests: list[tuple[str, str]], models: dict[str, ObjectModel],
               limit: int, progress=print) -> dict[tuple[str, str], list[Replay]]:
    """The first `limit` executed trials (by robot, seed and rank) of each (object, part) request of the run in
    `run` (its recorded `config`), in MuJoCo; `models` holds the requests' objects by id."""
    rows = [r for r in JsonLines(run / "trials.jsonl").read() if r["executed"]]
    results: dict[tuple[str, str], list[Replay]] = {}
    for object_id, prompt in requests:
        chosen = sorted((r for r in rows if (r["object_id"], r["prompt"]) == (object_id, prompt)),
                        key=lambda r: (robot_of(r), seed_of(r), r["rank"]))[:limit]
        model = models[object_id]
        results[(object_id, prompt)] = []
        for robot in dict.fromkeys(map(robot_of, chosen)):
            system = config.at_robot(robot)
            with SimCell([model], embodiment=system.embodiment, robot=robot, seed=0, image_size=(64, 48),
                         n_cameras=1) as cell:
                for row in (r for r in chosen if robot_of(r) == robot):
                    cell.reset(seed=row["scene_seed"], object_id=object_id)
                    _, T_world_obj = cell.object_mesh()
                    result = replay(model, prompt, T_world_obj, np.asarray(row["T_world_grasp"]), row["width"],
                                    system.hand, system.hand_grip_force, bool(row["success"]))
                    results[(object_id, prompt)].append(result)
                    progress(f"{object_id} {prompt} {robot} seed {seed_of(row)} rank {row['rank']}: twin "
                             f"{'success' if row['success'] else row['failure']}, MuJoCo "
                             f"{result.failure or 'success'} (rose {1000 * result.rise:.0f} mm)")
    return results


def report(results: dict[tuple[str, str], list[Replay]], command: str, seconds: float) -> str:
    """The markdown page: per request, the twin's and MuJoCo's successes over the same trials and where they agree."""
    lines = [
        "# The twin's trials replayed in MuJoCo", "", f"`{command}`", "",
        f"Written {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} at commit {commit()}; {seconds / 60:.1f} min.",
        "",
        "Each executed trial of the run is replayed in MuJoCo (bench/bench_mujoco_replay.py's docstring: the same "
        "object hulls, pose, grasp, grip force, closing speed, lift and hold; soft contacts, elliptic friction cones, "
        "no arm). A trial succeeds in MuJoCo when the grasped point rose at least "
        f"{100 * LIFT_SUCCESS:.0f} cm and the prompted part carried most of the squeeze.", "",
        "| object | part | trials | twin successes | MuJoCo successes | both | twin only | MuJoCo only "
        "| MuJoCo's failures |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    totals = collections.Counter()
    for (object_id, prompt), replays in results.items():
        both = sum(r.success and r.twin_success for r in replays)
        twin_only = sum(r.twin_success and not r.success for r in replays)
        mujoco_only = sum(r.success and not r.twin_success for r in replays)
        failures = collections.Counter(r.failure for r in replays if not r.success)
        named = ", ".join(f"{name} x{count}" for name, count in failures.most_common()) or "-"
        twin, mj = sum(r.twin_success for r in replays), sum(r.success for r in replays)
        lines.append(f"| {object_id} | {prompt} | {len(replays)} | {twin} | {mj} | {both} | {twin_only} | "
                     f"{mujoco_only} | {named} |")
        totals.update(trials=len(replays), twin=twin, mj=mj, both=both, twin_only=twin_only, mujoco_only=mujoco_only)
    agree = totals["trials"] - totals["twin_only"] - totals["mujoco_only"]
    lines += [f"| all | | {totals['trials']} | {totals['twin']} | {totals['mj']} | {totals['both']} | "
              f"{totals['twin_only']} | {totals['mujoco_only']} | |", "",
              f"The engines agree on {agree} of {totals['trials']} trials."]
    return "\n".join(lines) + "\n"


def parse_requests(text: str) -> list[tuple[str, str]]:
    """'OBJECT:PART,...' -> [(object, part), ...]."""
    requests = []
    for item in text.split(","):
        object_id, _, part = item.strip().partition(":")
        if not object_id or not part:
            raise ValueError(f"a request is OBJECT:PART (e.g. knife_chef:blade), got {item.strip()!r}")
        requests.append((object_id, part))
    return requests


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, required=True, help="an evaluation output folder (run.json, trials.jsonl)")
    parser.add_argument("--requests", required=True, help="comma-separated OBJECT:PART, e.g. knife_chef:blade")
    parser.add_argument("--limit", type=int, default=10, help="trials per request (by robot, seed and rank)")
    parser.add_argument("--out", type=Path, help="write the table here as markdown")
    args = parser.parse_args(argv)
    try:
        requests = parse_requests(args.requests)
        if not (args.run / "run.json").is_file() or not (args.run / "trials.jsonl").is_file():
            raise ValueError(f"{args.run} holds no evaluation run (run.json and trials.jsonl)")
        config = load_run(args.run)
        if args.limit < 1:
            raise ValueError(f"--limit must be at least 1, got {args.limit}")
        known, models = set(asset_ids()), {}
        for object_id, part in requests:
            if object_id not in known:
                raise ValueError(f"no twin object {object_id!r} (python -m assets list names them)")
            models.setdefault(object_id, load_asset(object_id))
            parts = models[object_id].prompts
            if part not in parts:
                raise ValueError(f"{object_id} has no part {part!r}; its parts: {', '.join(parts)}")
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    start = time.time()
    results = replay_run(args.run, config, requests, models, args.limit,
                         progress=lambda line: print(line, flush=True))
    empty = [f"{o}:{p}" for (o, p), replays in results.items() if not replays]
    if empty:
        print(f"error: {args.run / 'trials.jsonl'} has no executed trial of {', '.join(empty)}", file=sys.stderr)
        return 2
    publish(report(results, command_line("bench_mujoco_replay.py", argv), time.time() - start), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
