"""The transformers detectors, run for real on tiny random checkpoints built offline (tests/tiny_hf_models.py)."""

from __future__ import annotations

import matplotlib.path
import numpy as np
import pytest
import trimesh

from seggrasp.detect.base import Detections, Detector
from seggrasp.detect.grounding_dino import GroundingDino, build_caption, split_into_captions
from seggrasp.detect.hf_common import WeightsNotFoundError
from seggrasp.detect.owlv2 import OwlV2
from seggrasp.views import View
from tiny_hf_models import build_tiny_grounding_dino, build_tiny_owlv2

PROMPTS = ["Frying pan", "handle", "pan handle", "lid"]
IMAGE_SIZE = 96


@pytest.fixture(scope="session")
def tiny_weights(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("tiny_hf")
    return {
        "grounding-dino": str(build_tiny_grounding_dino(root / "grounding_dino")),
        "owlv2": str(build_tiny_owlv2(root / "owlv2")),
    }


@pytest.fixture(scope="session")
def views() -> list[View]:
    """Three views of a small pan-like mesh (a flat cylinder with a box handle), cropped to be non-square.

    Rendered with `seggrasp.render` when it is available; otherwise drawn as flat silhouettes with a pinhole camera.
    """
    pan = trimesh.creation.cylinder(radius=0.1, height=0.03, sections=24)
    handle = trimesh.creation.box(extents=(0.12, 0.025, 0.015))
    handle.apply_translation((0.15, 0.0, 0.0))
    mesh = trimesh.util.concatenate([pan, handle])
    try:
        from seggrasp.render import camera_rig, render_views
    except ImportError:
        rendered = [silhouette_view(mesh, azimuth) for azimuth in (0.0, 2.0, 4.0)]
    else:
        rendered = render_views(mesh, camera_rig(n_views=3, seed=0), image_size=IMAGE_SIZE)
    # OWLv2 pads images to a square and Grounding DINO keeps the aspect ratio: non-square images test both.
    return [View(v.rgb[:, 8:-8].copy(), v.face_ids[:, 8:-8].copy(), v.K, v.T_world_cam) for v in rendered]


def silhouette_view(mesh: trimesh.Trimesh, azimuth: float) -> View:
    """A grey-on-white silhouette of the mesh seen from 45 degrees elevation (stand-in for a rendered view)."""
    centred = mesh.copy()
    centred.apply_translation(-centred.bounds.mean(axis=0))
    direction = np.array([np.cos(azimuth), np.sin(azimuth), 1.0]) / np.sqrt(2.0)
    forward = -direction
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = np.stack([right, down, forward], axis=1)
    T_world_cam[:3, 3] = direction * 0.6
    K = np.array([[IMAGE_SIZE, 0, IMAGE_SIZE / 2], [0, IMAGE_SIZE, IMAGE_SIZE / 2], [0, 0, 1.0]])
    points = (centred.vertices - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    pixels = (points @ K.T)[:, :2] / points[:, 2:3]
    rgb = np.full((IMAGE_SIZE, IMAGE_SIZE, 3), 255, dtype=np.uint8)
    v, u = np.mgrid[:IMAGE_SIZE, :IMAGE_SIZE]
    for face in centred.faces:
        path = matplotlib.path.Path(pixels[face])
        inside = path.contains_points(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)).reshape(u.shape)
        rgb[inside] = 120
    return View(rgb, np.where(rgb[..., 0] < 255, 0, -1).astype(np.int64), K, T_world_cam)


def check_detections(results: list[Detections], views: list[View], n_prompts: int, min_score: float) -> None:
    assert len(results) == len(views)
    for detections, view in zip(results, views):
        assert isinstance(detections, Detections)
        height, width = view.rgb.shape[:2]
        boxes = detections.boxes
        assert boxes.shape == (len(detections), 4)
        assert np.all(np.isfinite(boxes))
        assert np.all(boxes[:, 0] >= 0) and np.all(boxes[:, 2] <= width)
        assert np.all(boxes[:, 1] >= 0) and np.all(boxes[:, 3] <= height)
        assert np.all(boxes[:, 0] < boxes[:, 2]) and np.all(boxes[:, 1] < boxes[:, 3])
        assert np.all((detections.scores > min_score) & (detections.scores <= 1.0))
        assert np.all((detections.prompt_index >= 0) & (detections.prompt_index < n_prompts))
        assert np.all(np.diff(detections.scores) <= 0), "detections are sorted best first"


def make(name: str, weights: str, threshold: float, **kwargs):
    if name == "grounding-dino":
        return GroundingDino(weights, box_threshold=threshold, text_threshold=threshold, **kwargs)
    return OwlV2(weights, score_threshold=threshold, **kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["grounding-dino", "owlv2"])
def test_tiny_model_loads_from_disk_and_detects(name, tiny_weights, views):
    detector = make(name, tiny_weights[name], 0.0, batch_size=2)  # 3 views: one full and one partial batch
    assert isinstance(detector, Detector) and detector.name == name
    results = detector.detect(views, PROMPTS)
    check_detections(results, views, len(PROMPTS), 0.0)
    assert sum(len(d) for d in results) > 0, "a zero threshold must let boxes through"
    again = detector.detect(views, PROMPTS)
    for first, second in zip(results, again):  # deterministic
        np.testing.assert_array_equal(first.boxes, second.boxes)
        np.testing.assert_array_equal(first.scores, second.scores)
        np.testing.assert_array_equal(first.prompt_index, second.prompt_index)
    assert detector.detect([], PROMPTS) == []


@pytest.mark.slow
@pytest.mark.parametrize("name", ["grounding-dino", "owlv2"])
def test_batching_does_not_change_results(name, tiny_weights, views):
    batched = make(name, tiny_weights[name], 0.0, batch_size=3, nms_iou=None).detect(views, PROMPTS)
    single = make(name, tiny_weights[name], 0.0, batch_size=1, nms_iou=None).detect(views, PROMPTS)
    def canonical_order(d: Detections) -> np.ndarray:
        rounded = np.round(d.boxes, 2)
        return np.lexsort((rounded[:, 3], rounded[:, 2], rounded[:, 1], rounded[:, 0], d.prompt_index))

    for a, b in zip(batched, single):
        assert len(a) == len(b)
        order_a, order_b = canonical_order(a), canonical_order(b)
        np.testing.assert_allclose(a.boxes[order_a], b.boxes[order_b], atol=1e-3)
        np.testing.assert_allclose(a.scores[order_a], b.scores[order_b], atol=1e-4)


@pytest.mark.parametrize("name", ["grounding-dino", "owlv2"])
def test_thresholds_filter(name, tiny_weights, views):
    everything = make(name, tiny_weights[name], 0.0).detect(views, PROMPTS)
    scores = np.concatenate([d.scores for d in everything])
    threshold = float(np.median(scores))
    filtered = make(name, tiny_weights[name], threshold).detect(views, PROMPTS)
    check_detections(filtered, views, len(PROMPTS), threshold)
    assert sum(len(d) for d in filtered) < len(scores)
    nothing = make(name, tiny_weights[name], 1.0).detect(views, PROMPTS)
    assert all(len(d) == 0 for d in nothing)


def test_owlv2_prompt_order_only_relabels(tiny_weights, views):
    """OWLv2 scores every prompt independently, so permuting prompts permutes the prompt indices and nothing else."""
    detector = make("owlv2", tiny_weights["owlv2"], 0.0, nms_iou=None)
    forward = detector.detect(views[:1], PROMPTS)[0]
    backward = detector.detect(views[:1], PROMPTS[::-1])[0]
    n = len(PROMPTS)
    np.testing.assert_allclose(np.sort(forward.scores), np.sort(backward.scores), atol=1e-5)
    rounded_f, rounded_b = np.round(forward.boxes, 2), np.round(backward.boxes, 2)
    order_f = np.lexsort((*rounded_f.T[::-1], forward.prompt_index))
    order_b = np.lexsort((*rounded_b.T[::-1], n - 1 - backward.prompt_index))
    np.testing.assert_array_equal(forward.prompt_index[order_f], n - 1 - backward.prompt_index[order_b])


def test_caption_tokens_map_to_their_prompts(tiny_weights):
    """Multi-token names and prompts sharing words map by position: "pan" in "frying pan" is not prompt "pan"."""
    detector = GroundingDino(tiny_weights["grounding-dino"])
    caption = build_caption(detector.tokenizer, ["frying pan", "pan", "pan handle", "handle"], [0, 1, 2, 3])
    assert caption.text == "frying pan. pan. pan handle. handle."
    tokens = detector.tokenizer.convert_ids_to_tokens(caption.input_ids)
    assert tokens == ["[CLS]", "frying", "pan", ".", "pan", ".", "pan", "handle", ".", "handle", ".", "[SEP]"]
    assert caption.token_prompt.tolist() == [-1, 0, 0, -1, 1, -1, 2, 2, -1, 3, -1, -1]


def test_long_prompt_lists_are_split_over_captions(tiny_weights):
    detector = GroundingDino(tiny_weights["grounding-dino"])
    prompts = ["frying pan", "pan", "pan handle", "handle", "lid", "knob"]
    captions = split_into_captions(detector.tokenizer, prompts, max_tokens=8)
    assert len(captions) > 1
    assert all(len(c.input_ids) <= 8 for c in captions)
    covered = np.concatenate([np.unique(c.token_prompt[c.token_prompt >= 0]) for c in captions])
    assert covered.tolist() == list(range(len(prompts)))
    with pytest.raises(ValueError, match="tokens"):
        split_into_captions(detector.tokenizer, ["a photo of the frying pan handle"], max_tokens=4)


def test_split_captions_detect_like_one_caption_per_group(tiny_weights, views):
    """With a tiny text budget, detections still carry indices into the full prompt list."""
    detector = GroundingDino(tiny_weights["grounding-dino"], box_threshold=0.0, text_threshold=0.0)
    detector.max_text_len = 6
    results = detector.detect(views[:2], PROMPTS)
    check_detections(results, views[:2], len(PROMPTS), 0.0)
    assert len(np.unique(np.concatenate([d.prompt_index for d in results]))) > 1


@pytest.mark.parametrize("cls", [GroundingDino, OwlV2])
def test_missing_weights_say_how_to_provide_them(cls, tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(WeightsNotFoundError, match="save_pretrained") as missing:
        cls(tmp_path / "no_such_folder")
    assert "does not exist" in str(missing.value)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(WeightsNotFoundError, match="config.json"):
        cls(str(empty))
    with pytest.raises(WeightsNotFoundError, match="HF_HUB_OFFLINE=1"):  # a hub id offline: no download attempted
        cls("seggrasp-tests/not-a-real-model")
    with pytest.raises(WeightsNotFoundError, match="no weights"):
        cls(None)


def test_incomplete_weights_folder_is_reported(tiny_weights, tmp_path):
    folder = tmp_path / "owl"
    folder.mkdir()
    (folder / "config.json").write_text(open(f"{tiny_weights['owlv2']}/config.json").read())
    with pytest.raises(WeightsNotFoundError, match="how to|Provide"):
        OwlV2(folder)


def test_bad_inputs_are_rejected(tiny_weights, views):
    detector = OwlV2(tiny_weights["owlv2"])
    with pytest.raises(ValueError, match="distinct"):
        detector.detect(views, ["handle", "Handle"])
    with pytest.raises(ValueError, match="empty"):
        detector.detect(views, ["handle", " "])
    with pytest.raises(ValueError, match="single string"):
        detector.detect(views, "handle")
    grey = View(views[0].rgb[..., 0], views[0].face_ids, views[0].K, views[0].T_world_cam)
    with pytest.raises(ValueError, match="rgb"):
        detector.detect([grey], ["handle"])
    with pytest.raises(ValueError, match="box_threshold"):
        GroundingDino(tiny_weights["grounding-dino"], box_threshold=1.5)
