"""Which perceived instance is the requested object: detector boxes on the camera images, voted onto instances.

`find_target` runs a `Detector` on the cameras' RGB images (`camera_views`) with the object's name as the prompt
and scores each instance (`seggrasp.perception.split_instances`) by the sum over frames and boxes of the box's
confidence times its IoU with the box around the instance's points visible in that frame (`visible_pixels`: in the
image, in front of the camera and not behind the depth measured at their pixel by more than `depth_tolerance`; a
pixel without a reading hides nothing). The boxes' IoU, not the share of an instance's points inside a box, so
that a small object standing inside a frying pan's box does not win the pan's request. The best-scoring instance
is the target; when none scores above zero, the target is not found.

Objects that touch (a pile) are one instance. So the chosen instance is cut by the boxes that chose it: a point
that a frame sees outside its box there, grown by `BOX_MARGIN` of the box's size on each side (the boxes are not
tight), is another object's, and those points become an instance of their own (`TargetSearch.instances`), an
obstacle like the others. The cut is only made when it leaves at least `MIN_KEPT` of the instance's points.

In the twin, frames say which body each pixel shows (`Frame.instance_ids`); `true_bodies` and `instance_iou`
score an instance against that truth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from seggrasp.cell import Frame
from seggrasp.cloud import project
from seggrasp.detect.base import Detector, box_iou
from seggrasp.views import View

if TYPE_CHECKING:
    from seggrasp.perception import OrientedCloud

#: A point more than this (m) behind the depth measured at its pixel is hidden there (depth noise at 1 m is about
#: 3.6 mm, voxel centroids move points by up to a voxel).
DEPTH_TOLERANCE = 0.01

#: The chosen box in a frame is grown by this fraction of its width and height on each side before cutting the
#: target's instance by it (the simulated `typical` detector jitters a box's centre by 8 % and its sides by 15 %).
BOX_MARGIN = 0.2

#: The cut by the boxes is made only when it keeps at least this fraction of the instance's points (less: the boxes
#: name a small part of it, or are wrong, and cutting would throw the object away).
MIN_KEPT = 0.25


@dataclass(frozen=True)
class TargetSearch:
    """The outcome of `find_target`: each instance's score, the chosen one (`index` into `instances`, None when not
    found) and the instances with the target's points outside its boxes split off (the last one, when cut)."""

    scores: tuple[float, ...]
    index: int | None
    instances: list[OrientedCloud]

    @property
    def found(self) -> bool:
        return self.index is not None


def object_name(category: str) -> str:
    """The prompt that names an object of a category ("frying_pan" -> "frying pan")."""
    return category.replace("_", " ").strip()


def camera_views(frames: Sequence[Frame]) -> list[View]:
    """The frames' RGB images as detector views; no mesh is rendered in them, so the face ids are the twin's body
    per pixel (`Frame.instance_ids`) where the frame has them, else all -1."""
    return [
        View(frame.rgb, np.full(frame.depth.shape, -1, dtype=np.int64) if frame.instance_ids is None
             else np.asarray(frame.instance_ids, dtype=np.int64), np.asarray(frame.K, dtype=float),
             np.asarray(frame.T_world_cam, dtype=float))
        for frame in frames
    ]


def visible_pixels(
    points: np.ndarray, frame: Frame, depth_tolerance: float = DEPTH_TOLERANCE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(column, row, visible) of world points (N, 3) in a frame: their pixel (rounded; valid where visible) and
    whether they are in the image, in front of the camera and not behind the measured depth by more than
    `depth_tolerance`."""
    if not depth_tolerance > 0:
        raise ValueError(f"depth_tolerance must be positive, got {depth_tolerance}")
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    K = np.asarray(frame.K, dtype=float)
    u, v, z, visible = project(points, np.linalg.inv(frame.T_world_cam), K, frame.depth.shape)
    measured = np.zeros(len(z))
    measured[visible] = frame.depth[v[visible], u[visible]]
    visible &= (measured <= 0) | (z <= measured + depth_tolerance)
    return u, v, visible


def find_target(
    instances: Sequence[OrientedCloud], detector: Detector, prompt: str, depth_tolerance: float = DEPTH_TOLERANCE
) -> TargetSearch:
    """The instance the detector's boxes for `prompt` cover most, cut by the boxes that chose it (module docstring);
    the instances' frames (the registered ones, shared by all instances of one `split_instances`) are the images it
    looks at."""
    if not prompt.strip():
        raise ValueError("the target's prompt is empty; give the object's name, e.g. 'mug'")
    if not instances:
        raise ValueError("no instances to choose the target from")
    frames = instances[0].frames
    if any(instance.frames is not frames for instance in instances):
        raise ValueError("the instances come from different captures; give the instances of one split_instances")
    detections = detector.detect(camera_views(frames), [prompt])
    if len(detections) != len(frames):
        raise ValueError(f"detector {detector.name} returned {len(detections)} results for {len(frames)} images")
    votes = np.zeros((len(instances), len(frames)))  # best box's vote per instance and frame
    chosen_box = np.zeros((len(instances), len(frames)), dtype=np.int64)
    scores = np.zeros(len(instances))
    for f, (frame, found) in enumerate(zip(frames, detections)):
        if not len(found):
            continue
        for k, instance in enumerate(instances):
            u, v, visible = visible_pixels(instance.points, frame, depth_tolerance)
            if visible.any():
                seen = np.array([u[visible].min(), v[visible].min(), u[visible].max() + 1, v[visible].max() + 1])
                vote = found.scores * box_iou(seen.astype(float), np.asarray(found.boxes, float))
                scores[k] += float(vote.sum())
                votes[k, f], chosen_box[k, f] = vote.max(), int(np.argmax(vote))
    best = int(np.argmax(scores))
    if not scores[best] > 0:
        return TargetSearch(tuple(float(s) for s in scores), None, list(instances))
    boxes = [found.boxes[chosen_box[best, f]] if votes[best, f] > 0 else None for f, found in enumerate(detections)]
    return TargetSearch(tuple(float(s) for s in scores), best, cut_by_boxes(instances, best, boxes, depth_tolerance))


def cut_by_boxes(
    instances: Sequence[OrientedCloud], index: int, boxes: Sequence[np.ndarray | None],
    depth_tolerance: float = DEPTH_TOLERANCE,
) -> list[OrientedCloud]:
    """The instances with instance `index`'s points that some frame sees outside its box (one per frame, None: the
    frame does not judge), grown by `BOX_MARGIN`, split off into a last instance; unchanged when nothing is outside
    or the cut would keep less than `MIN_KEPT` of the points (module docstring)."""
    target = instances[index]
    outside = np.zeros(len(target.points), dtype=bool)
    for frame, box in zip(target.frames, boxes):
        if box is None:
            continue
        x0, y0, x1, y1 = np.asarray(box, dtype=float)
        grow_x, grow_y = BOX_MARGIN * (x1 - x0), BOX_MARGIN * (y1 - y0)
        u, v, visible = visible_pixels(target.points, frame, depth_tolerance)
        outside |= visible & ((u < x0 - grow_x) | (u >= x1 + grow_x) | (v < y0 - grow_y) | (v >= y1 + grow_y))
    if not outside.any() or (~outside).sum() < MIN_KEPT * len(outside):
        return list(instances)
    kept, cut = (replace(target, points=target.points[m], normals=target.normals[m]) for m in (~outside, outside))
    return [kept if k == index else instance for k, instance in enumerate(instances)] + [cut]


def true_bodies(points: np.ndarray, frames: Sequence[Frame], depth_tolerance: float = DEPTH_TOLERANCE) -> np.ndarray:
    """The twin's body of each point (N,): the body most frames in which it is visible show at its pixel
    (`Frame.instance_ids`), -1 where no frame sees it (ties go to the smaller body id)."""
    if any(frame.instance_ids is None for frame in frames):
        raise ValueError("the frames carry no instance ids: the truth of which body a pixel shows is the twin's")
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    seen = [np.full(len(points), -1, dtype=np.int64) for _ in frames]
    for body, frame in zip(seen, frames):
        u, v, visible = visible_pixels(points, frame, depth_tolerance)
        body[visible] = np.asarray(frame.instance_ids)[v[visible], u[visible]]
    seen = np.stack(seen, axis=1)
    bodies = np.unique(seen[seen >= 0])
    if len(bodies) == 0:
        return np.full(len(points), -1, dtype=np.int64)
    votes = (seen[:, :, None] == bodies[None, None, :]).sum(axis=1)
    return np.where(votes.max(axis=1) > 0, bodies[np.argmax(votes, axis=1)], -1)


def instance_iou(instances: Sequence[OrientedCloud], index: int, body: int,
                 depth_tolerance: float = DEPTH_TOLERANCE) -> float:
    """IoU of instance `index`'s points and the points of all instances that the twin's masks assign to `body`
    (`true_bodies`); 0 when neither has a point."""
    if not 0 <= index < len(instances):
        raise ValueError(f"instance index {index} is out of range for {len(instances)} instances")
    points = np.concatenate([instance.points for instance in instances])
    owner = np.repeat(np.arange(len(instances)), [len(instance.points) for instance in instances])
    of_body = true_bodies(points, instances[0].frames, depth_tolerance) == body
    chosen = owner == index
    union = int((chosen | of_body).sum())
    return float((chosen & of_body).sum() / union) if union else 0.0
