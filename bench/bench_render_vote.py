"""Time rendering 10 views (RGB + face ids) and voting on a 10k-face mesh; the detector is excluded.

Usage: python bench/bench_render_vote.py [--faces-per-ring 100] [--views 10] [--image-size 512] [--repeats 5]
Target (issue 2): under 1 s for render + vote on a 2-core machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from seggrasp.detect.base import Detections  # noqa: E402
from seggrasp.render import camera_rig, render_views  # noqa: E402
from seggrasp.vote import vote  # noqa: E402


def synthetic_detections(views, n_prompts: int, boxes_per_prompt: int, seed: int) -> list[Detections]:
    """Random boxes inside each view's object bounding box: a stand-in for the detector, which is not timed."""
    rng = np.random.default_rng(seed)
    detections = []
    for view in views:
        rows, cols = np.nonzero(view.face_ids >= 0)
        low, high = np.array([cols.min(), rows.min()]), np.array([cols.max(), rows.max()]) + 1
        n_boxes = n_prompts * boxes_per_prompt
        corners = low + rng.random((n_boxes, 2, 2)) * (high - low)
        boxes = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)
        detections.append(Detections(boxes, rng.random(n_boxes), np.repeat(np.arange(n_prompts), boxes_per_prompt)))
    return detections


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", type=int, default=100, help="torus sections; faces = 2 x sections x sections/2")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--image-size", type=int, default=512)
    parser.add_argument("--prompts", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    mesh = trimesh.creation.torus(0.08, 0.03, major_sections=args.sections, minor_sections=args.sections // 2)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 0, 0]))
    poses = camera_rig(args.views)

    start = time.perf_counter()
    views = render_views(mesh, poses, image_size=args.image_size)
    first = time.perf_counter() - start
    detections = synthetic_detections(views, args.prompts, boxes_per_prompt=2, seed=0)

    render_times, vote_times = [], []
    for _ in range(args.repeats):
        start = time.perf_counter()
        views = render_views(mesh, poses, image_size=args.image_size)
        render_times.append(time.perf_counter() - start)
        start = time.perf_counter()
        vote(views, detections, len(mesh.faces), args.prompts)
        vote_times.append(time.perf_counter() - start)

    render_s, vote_s = float(np.median(render_times)), float(np.median(vote_times))
    print(f"mesh: {len(mesh.faces)} faces; {args.views} views at {args.image_size} px; {args.prompts} prompts x 2 boxes")
    print(f"first call (creates the GL context): {first:.3f} s")
    print(f"render {args.views} views (RGB + face ids): {render_s:.3f} s  (median of {args.repeats})")
    print(f"vote: {vote_s:.3f} s")
    print(f"render + vote: {render_s + vote_s:.3f} s  (target < 1 s)")


if __name__ == "__main__":
    main()
