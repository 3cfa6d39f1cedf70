"""Generate the SegGraspSet twin: exact part-labelled meshes, physical properties, collision models, URDFs, manifest.

Parts are joined by manifold3d boolean union; manifold3d records for every output triangle the original solid it
came from (`run_original_id`), which gives exact per-face part labels on a single closed 2-manifold surface.
Everything except the CoACD collision model is cheap and reproducible from (spec, seed): vertices are written with
fixed decimals and mass properties rounded well above floating-point noise (`stable_mass_properties`), so the files
come out the same on CPUs and BLAS builds that sum in another order (a value within that noise of a rounding step
could still differ in its last written digit; tests compare numbers with a tolerance). The collision model is also
seeded but slow, so `generate_object(..., collision=False)` skips it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import zlib
from dataclasses import dataclass
from pathlib import Path

import manifold3d as mf
import numpy as np
import trimesh
from tqdm import tqdm

from assets.catalog import BUILDERS, CATEGORY_PARTS, MATERIALS, OBJECT_SPECS, ObjectSpec
from seggrasp.io import atomic_write_json, atomic_write_text
from seggrasp.labels import PartLabels
from seggrasp.mesh import mesh_hash
from seggrasp.object_physics import (
    CollisionConfig,
    MassProperties,
    combine_mass_properties,
    convex_decomposition,
    mass_properties,
    obj_group_names,
    obj_text,
    urdf_text,
    write_collision_obj,
)

log = logging.getLogger(__name__)

GENERATOR_VERSION = "1.0.0"
ASSETS_DIR = Path(__file__).resolve().parent
OBJECTS_DIR = ASSETS_DIR / "objects"
MANIFEST_PATH = ASSETS_DIR / "manifest.json"
#: Relative jitter applied to every numeric parameter (uniform in [-JITTER, +JITTER]); seed 0 is the committed set.
JITTER = 0.03
#: Decimal places of vertex coordinates in the written OBJ files (1e-8 m).
VERTEX_DECIMALS = 8
#: CoACD settings for the twin's collision models, applied to each part's solid separately (so no hull straddles
#: a part boundary and a contact with hull k touches part `hull_parts[k]`): moderate concavity threshold, at most
#: `max_hulls` hulls per part. The meshes are clean 2-manifolds, so CoACD's remeshing pre-process is off.
TWIN_COLLISION = CollisionConfig(threshold=0.06, max_hulls=16, resolution=2000, mcts_iterations=100, preprocess="off", seed=0)
#: Significant digits kept of the mass properties, each relative to its own scale: the mass itself, the object's
#: size for the centre of mass, the largest component for the inertia tensor. Finer digits are floating-point noise
#: that differs between CPUs and BLAS builds (summation order): e.g. products of inertia of 1e-21 kg m^2 or a centre
#: of mass 1e-17 m off the symmetry plane; rounded to this resolution they are exactly 0 on every machine.
MASS_DIGITS = 8
INERTIA_DIGITS = 7
#: Friction model for PyBullet: small spinning/rolling friction so round objects come to rest.
SPINNING_FRICTION = 0.002
ROLLING_FRICTION = 0.0002


@dataclass
class GeneratedMesh:
    """An object's labelled surface in its resting frame (footprint centred at the origin, lowest point at z = 0)."""

    spec: ObjectSpec
    seed: int
    params: dict
    mesh: trimesh.Trimesh
    labels: PartLabels
    part_volumes: list[trimesh.Trimesh]  # disjoint solids whose union is the object, one per part (mass split)
    keep_open: np.ndarray  # (K, 3) points the collision model must leave empty


def jittered_params(spec: ObjectSpec, seed: int) -> dict:
    """The spec's parameters with every float scaled by 1 + U(-JITTER, JITTER), seeded by (seed, object id)."""
    rng = np.random.default_rng([seed, zlib.crc32(spec.object_id.encode())])
    params = {}
    for key in sorted(spec.params):
        value = spec.params[key]
        if isinstance(value, float):
            value = float(value * (1.0 + rng.uniform(-JITTER, JITTER)))
        params[key] = value
    return params


def _quantise(vertices: np.ndarray) -> np.ndarray:
    """Vertex coordinates exactly as they read back from the OBJ text (fixed decimals)."""
    return np.array([[float(f"{c:.{VERTEX_DECIMALS}f}") for c in row] for row in vertices], dtype=np.float64)


def build_mesh(spec: ObjectSpec, seed: int = 0) -> GeneratedMesh:
    """Build one object's labelled mesh (no files written). Deterministic in (spec, seed)."""
    params = jittered_params(spec, seed)
    parts, keep_open = BUILDERS[spec.category](params)
    names = [name for name, _ in parts]
    if tuple(names) != CATEGORY_PARTS[spec.category]:
        raise ValueError(f"{spec.object_id}: builder returned parts {names}, expected {CATEGORY_PARTS[spec.category]}")
    originals = [solid.as_original() for _, solid in parts]
    part_of_id = {solid.original_id(): k for k, solid in enumerate(originals)}
    union = mf.Manifold.batch_boolean(originals, mf.OpType.Add)
    if union.status() != mf.Error.NoError or union.is_empty():
        raise ValueError(f"{spec.object_id}: boolean union failed ({union.status()})")
    if len(union.decompose()) != 1:
        raise ValueError(f"{spec.object_id}: parts do not touch: the union has {len(union.decompose())} pieces")
    out = union.to_mesh64()
    vertices = np.asarray(out.vert_properties)[:, :3]
    faces = np.asarray(out.tri_verts).astype(np.int64)
    run_index = np.asarray(out.run_index).astype(np.int64) // 3
    face_labels = np.full(len(faces), -1, dtype=np.int64)
    for start, stop, original in zip(run_index[:-1], run_index[1:], np.asarray(out.run_original_id)):
        if int(original) not in part_of_id:
            raise ValueError(f"{spec.object_id}: output triangles from unknown solid {int(original)}")
        face_labels[start:stop] = part_of_id[int(original)]

    lower, upper = vertices.min(axis=0), vertices.max(axis=0)
    shift = np.array([-(lower[0] + upper[0]) / 2, -(lower[1] + upper[1]) / 2, -lower[2]])
    vertices = _quantise(vertices + shift)
    mesh = trimesh.Trimesh(vertices, faces, process=False)

    pieces = []
    for k, solid in enumerate(originals):
        piece = solid - mf.Manifold.batch_boolean(originals[:k], mf.OpType.Add) if k else solid
        piece_mesh = piece.to_mesh64()
        pieces.append(trimesh.Trimesh(np.asarray(piece_mesh.vert_properties)[:, :3] + shift,
                                      np.asarray(piece_mesh.tri_verts).astype(np.int64), process=False))
    keep = np.asarray(keep_open, dtype=np.float64).reshape(-1, 3) + shift
    return GeneratedMesh(spec, seed, params, mesh, PartLabels(names, face_labels), pieces, keep)


def round_to_scale(values: np.ndarray | float, scale: float, digits: int) -> np.ndarray:
    """`values` rounded to `digits` significant digits of `scale` (a fixed absolute step, correctly rounded in
    decimal): components below that step become exactly 0.0 (never -0.0)."""
    array = np.asarray(values, dtype=np.float64)
    if scale <= 0 or not math.isfinite(scale):
        raise ValueError(f"rounding scale must be positive and finite, got {scale}")
    decimals = digits - 1 - math.floor(math.log10(scale))
    return np.array([round(float(v), decimals) + 0.0 for v in array.ravel()]).reshape(array.shape)


def stable_mass_properties(props: MassProperties, size: float) -> MassProperties:
    """`props` rounded to what is not floating-point noise (`MASS_DIGITS`, `INERTIA_DIGITS`); `size` is the
    object's largest extent, the scale of its centre of mass. The same solid gives the same numbers on any machine."""
    inertia = round_to_scale(props.inertia, float(np.abs(props.inertia).max()), INERTIA_DIGITS)
    return MassProperties(
        mass=float(round_to_scale(props.mass, props.mass, MASS_DIGITS)),
        center_of_mass=round_to_scale(props.center_of_mass, size, MASS_DIGITS),
        inertia=inertia,  # still exactly symmetric: equal components round alike
    )


def physical_properties(generated: GeneratedMesh) -> tuple[MassProperties, float, list[float]]:
    """Mass properties from per-part densities (rounded: `stable_mass_properties`), object friction
    (surface-area-weighted) and per-part masses."""
    spec = generated.spec
    per_part = [mass_properties(piece, MATERIALS[material].density)
                for piece, material in zip(generated.part_volumes, spec.materials)]
    areas = generated.mesh.area_faces
    labels = generated.labels.face_labels
    part_area = np.array([areas[labels == k].sum() for k in range(len(spec.materials))])
    frictions = np.array([MATERIALS[m].friction for m in spec.materials])
    friction = float(np.round((part_area * frictions).sum() / part_area.sum(), 3))
    props = stable_mass_properties(combine_mass_properties(per_part), float(generated.mesh.extents.max()))
    return props, friction, [round(p.mass, 6) for p in per_part]


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def label_hash(face_labels: np.ndarray) -> str:
    """Hash of a face-label array (int64 bytes)."""
    return _sha256(np.asarray(face_labels, dtype=np.int64).tobytes())[:32]


def generate_object(spec: ObjectSpec, out_dir: Path, seed: int = 0, collision: bool = True) -> dict:
    """Write mesh.obj, labels.json, collision.obj (if `collision`, else reuse an existing one) and object.urdf into
    `out_dir`; return the object's manifest record (file paths as they lie under `assets/`: objects/<id>/...)."""
    generated = build_mesh(spec, seed)
    props, friction, part_masses = physical_properties(generated)
    out_dir.mkdir(parents=True, exist_ok=True)
    mesh_bytes = obj_text(generated.mesh.vertices, generated.mesh.faces, VERTEX_DECIMALS).encode()
    atomic_write_text(out_dir / "mesh.obj", mesh_bytes.decode())
    labels_text = json.dumps(generated.labels.to_json()) + "\n"
    atomic_write_text(out_dir / "labels.json", labels_text)
    collision_path = out_dir / "collision.obj"
    if collision:
        hulls, names = [], []
        for part, piece in zip(generated.labels.parts, generated.part_volumes):
            part_hulls = convex_decomposition(piece, TWIN_COLLISION)
            names += [f"{part}_{len(hulls) + k}" for k in range(len(part_hulls))]
            hulls += part_hulls
        write_collision_obj(collision_path, hulls, VERTEX_DECIMALS, names)
    elif not collision_path.is_file():
        raise ValueError(
            f"{spec.object_id}: no collision model at {collision_path} to keep; generate it with CoACD first"
        )
    hull_parts = [generated.labels.parts.index(name.rsplit("_", 1)[0]) for name in obj_group_names(collision_path)]
    urdf = urdf_text(spec.object_id, "mesh.obj", "collision.obj", props, friction,
                     spinning_friction=SPINNING_FRICTION, rolling_friction=ROLLING_FRICTION)
    atomic_write_text(out_dir / "object.urdf", urdf)
    mesh = generated.mesh
    rel = f"objects/{spec.object_id}"
    return {
        "id": spec.object_id,
        "category": spec.category,
        "parts": generated.labels.parts,
        "prompts": generated.labels.parts,
        "materials": list(spec.materials),
        "part_masses": part_masses,
        "mass": props.mass,  # rounded: exactly the URDF's values
        "friction": friction,
        "center_of_mass": props.center_of_mass.tolist(),
        "inertia": props.inertia.tolist(),
        "dimensions": [round(float(d), 6) for d in mesh.extents],
        "n_vertices": int(len(mesh.vertices)),
        "n_faces": int(len(mesh.faces)),
        "n_hulls": len(hull_parts),
        "hull_parts": hull_parts,
        "keep_open": [[round(float(c), 6) for c in point] for point in generated.keep_open],
        "files": {
            "mesh": f"{rel}/mesh.obj",
            "labels": f"{rel}/labels.json",
            "collision": f"{rel}/collision.obj",
            "urdf": f"{rel}/object.urdf",
        },
        "sha256": {
            "mesh": _sha256(mesh_bytes),
            "labels": _sha256(labels_text.encode()),
            "collision": _sha256(collision_path.read_bytes()),
            "urdf": _sha256(urdf.encode()),
        },
        "mesh_hash": mesh_hash(mesh),
        "label_hash": label_hash(generated.labels.face_labels),
        "seed": seed,
        "params": generated.params,
    }


def _manifest(records: dict[str, dict], seed: int) -> dict:
    order = [s.object_id for s in OBJECT_SPECS if s.object_id in records]
    return {
        "name": "SegGraspSet twin",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "collision": {
            "method": "coacd",
            "threshold": TWIN_COLLISION.threshold,
            "max_hulls": TWIN_COLLISION.max_hulls,
            "resolution": TWIN_COLLISION.resolution,
            "mcts_iterations": TWIN_COLLISION.mcts_iterations,
            "preprocess": TWIN_COLLISION.preprocess,
            "seed": TWIN_COLLISION.seed,
        },
        "frame": "resting pose, z up; footprint (bounding-box x/y) centre at the origin, lowest point at z = 0",
        "objects": [records[i] for i in order],
    }


def generate_set(
    seed: int = 0, object_ids: list[str] | None = None, root: Path = ASSETS_DIR, collision: bool = True
) -> dict:
    """Generate objects (all by default) under `root`/objects and (re)write `root`/manifest.json.

    Records of objects not regenerated are kept from an existing manifest, so the set can be extended in steps.
    """
    specs = [s for s in OBJECT_SPECS if object_ids is None or s.object_id in object_ids]
    if object_ids is not None:
        missing = set(object_ids) - {s.object_id for s in specs}
        if missing:
            raise ValueError(f"unknown object ids {sorted(missing)}; known: {[s.object_id for s in OBJECT_SPECS]}")
    manifest_path = root / "manifest.json"
    previous = {}
    if manifest_path.is_file():
        existing = json.loads(manifest_path.read_text())
        if existing.get("seed") == seed:  # records of another seed are not kept
            previous = {r["id"]: r for r in existing["objects"]}
    if not specs:
        raise ValueError("no objects to generate")
    manifest = {}
    for spec in tqdm(specs, desc="objects", unit="obj"):
        previous[spec.object_id] = generate_object(spec, root / "objects" / spec.object_id, seed, collision)
        manifest = _manifest(previous, seed)
        atomic_write_json(manifest_path, manifest)  # after every object: readers never see stale hashes for long
    return manifest
