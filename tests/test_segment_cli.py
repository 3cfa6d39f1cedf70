"""The segmentation pipeline (refine="none") and the `python -m seggrasp segment` command end to end."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from trimesh.transformations import rotation_matrix

from processes import alive, child_pids
from seggrasp.__main__ import main
from seggrasp.detect.base import Detections
from seggrasp.detect.simulated import SimulatedDetector
from seggrasp.labels import PartLabels, read_labels, write_labels
from seggrasp.mesh import prepare_mesh
from seggrasp.metrics import shape_miou
from seggrasp.labels import check_prompts
from seggrasp.segment import SegmentationConfig, segment
from seggrasp.truth import REAL_DETECTORS, SIMULATED_PRESETS, DetectorSpec, parse_detector

PARTS = ["handle", "head"]
FAST = SegmentationConfig(n_views=6, image_size=128, refine="none")


def _hammer() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and per-face labels (0 = handle, 1 = head) of a small hammer, about a thousand faces."""
    handle = trimesh.creation.cylinder(0.012, 0.25, sections=16)
    handle.apply_transform(rotation_matrix(np.pi / 2, [0, 1, 0]))
    head = trimesh.creation.box([0.03, 0.03, 0.1])
    head.apply_translation([0.14, 0, 0])
    pieces = []
    for piece in (handle, head):
        vertices, faces = trimesh.remesh.subdivide_to_size(piece.vertices, piece.faces, max_edge=0.02)
        pieces.append(trimesh.Trimesh(vertices, faces))
    mesh = trimesh.util.concatenate(pieces)
    labels = np.concatenate([np.full(len(p.faces), k) for k, p in enumerate(pieces)])
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), labels


class _WholeImageDetector:
    """Boxes the whole image for prompt 0 in every view with confidence 0.5; nothing for other prompts."""

    name = "whole-image"

    def detect(self, views, prompts):
        return [Detections(np.array([[0.0, 0.0, v.size[1], v.size[0]]]), np.array([0.5]), np.array([0]))
                for v in views]


def test_segment_coarse_result() -> None:
    vertices, faces, labels = _hammer()
    prepared = prepare_mesh(vertices, faces)
    gt = PartLabels(PARTS, labels)
    result = segment(prepared, PARTS, SimulatedDetector(gt, preset="perfect"), FAST)
    n_faces = len(faces)
    assert result.prompts == PARTS
    assert result.labels.shape == (n_faces,) and result.labels.dtype == np.int64
    assert result.scores.shape == (n_faces, 2)
    np.testing.assert_array_equal(result.scores, result.coarse_scores)  # no refinement
    np.testing.assert_array_equal(result.labels, result.coarse_labels)
    assert len(result.views) == len(result.detections) == 6
    assert result.views[0].size == (128, 128)
    assert result.detector == "simulated:perfect" and result.refine == "none" and result.partitions == []
    assert set(result.timings) == {"render", "detect", "vote"}
    assert all(seconds >= 0 for seconds in result.timings.values())
    assert shape_miou(result.labels, labels, 2, trimesh.Trimesh(vertices, faces).area_faces) > 0.6
    # Faces no box covers are unknown.
    unvoted = ~(result.scores > 0).any(axis=1)
    np.testing.assert_array_equal(result.labels[unvoted], -1)


def test_segment_reports_labels_in_input_face_order() -> None:
    """Shuffling the file's faces and adding degenerate ones permutes the labels the same way."""
    vertices, faces, labels = _hammer()
    reference = segment(prepare_mesh(vertices, faces), PARTS, _WholeImageDetector(), FAST)

    rng = np.random.default_rng(0)
    order = rng.permutation(len(faces))
    collapsed = np.array([[0, 0, 1], [5, 6, 5]])  # zero-area faces, dropped by the repair
    shuffled_faces = np.concatenate([faces[order[:10]], collapsed, faces[order[10:]]])
    prepared = prepare_mesh(vertices, shuffled_faces)
    assert prepared.n_faces == len(faces) and prepared.n_source_faces == len(faces) + 2
    result = segment(prepared, PARTS, _WholeImageDetector(), FAST)
    assert result.labels.shape == (len(faces) + 2,)
    kept = np.r_[0:10, 12:len(faces) + 2]
    np.testing.assert_array_equal(result.labels[kept], reference.labels[order])
    np.testing.assert_allclose(result.scores[kept], reference.scores[order])
    assert (result.labels == 0).sum() > 0.5 * len(faces)  # the whole-image box covers every visible face


def test_segment_is_deterministic() -> None:
    vertices, faces, labels = _hammer()
    prepared = prepare_mesh(vertices, faces)
    gt = PartLabels(PARTS, labels)
    first = segment(prepared, PARTS, SimulatedDetector(gt, seed=4), FAST)
    second = segment(prepared, PARTS, SimulatedDetector(gt, seed=4), FAST)
    np.testing.assert_array_equal(first.scores, second.scores)


def test_prompt_and_config_checks() -> None:
    assert check_prompts([" handle ", "head"]) == ["handle", "head"]
    for bad, message in (([], "at least one"), (["handle", ""], "empty"), (["a", "A"], "distinct"),
                         ("handle", "single string")):
        with pytest.raises(ValueError, match=message):
            check_prompts(bad)
    with pytest.raises(ValueError, match="n_views"):
        SegmentationConfig(n_views=0)
    with pytest.raises(ValueError, match="image_size"):
        SegmentationConfig(image_size=4)


@pytest.fixture(scope="module")
def hammer_files(tmp_path_factory) -> tuple[Path, Path, np.ndarray]:
    folder = tmp_path_factory.mktemp("hammer")
    vertices, faces, labels = _hammer()
    mesh_path, labels_path = folder / "hammer.obj", folder / "hammer_gt.json"
    trimesh.Trimesh(vertices, faces, process=False).export(mesh_path)
    write_labels(labels_path, PartLabels(PARTS, labels))
    return mesh_path, labels_path, labels


def test_cli_end_to_end(hammer_files, tmp_path: Path, capsys) -> None:
    mesh_path, labels_path, labels = hammer_files
    out = tmp_path / "result"
    code = main(["segment", str(mesh_path), "--prompt", "head", "--prompt", "handle", "--labels", str(labels_path),
                 "--detector", "perfect", "--views", "6", "--image-size", "128", "--refine", "none", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "simulated:perfect" in printed and "mIoU" in printed and "head" in printed

    written = read_labels(out / "labels.json")
    assert written.parts == ["head", "handle"]  # parts are the prompts, in order
    assert written.n_faces == len(labels)
    scores = np.load(out / "scores.npy")
    assert scores.shape == (len(labels), 2)
    np.testing.assert_array_equal(written.face_labels[scores.max(axis=1) > 0], scores.argmax(axis=1)[scores.max(axis=1) > 0])
    # Ground truth is matched to prompts by name: prompt 0 is "head" = gt part 1.
    truth = np.where(labels == 1, 0, 1)
    agreement = (written.face_labels == truth)[written.face_labels >= 0].mean()
    assert agreement > 0.75

    coloured = trimesh.load(out / "segmented.ply", process=False)
    assert len(coloured.faces) == len(labels)
    for picture in ("views.png", "labels.png"):
        assert (out / picture).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / "partitions.png").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["detector"] == "simulated:perfect" and summary["refine"] == "none"
    assert set(summary["evaluation"]["final_area"]["part_iou"]) == {"head", "handle"}
    assert 0.0 <= summary["evaluation"]["final_area"]["miou"] <= 1.0


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--labels", "{missing}"], "label file not found"),
        (["--labels", "{short}"], "face labels but the mesh"),
        ([], "needs ground-truth part labels"),
        (["--labels", "{labels}", "--detector", "owlv2"], "weights"),
        (["--labels", "{labels}", "--detector", "simulated-typical"], "unknown detector"),
        (["--labels", "{labels}", "--weights", "w"], "takes no weights"),
        (["--labels", "{labels}", "--workers", "0"], "workers"),
        (["--labels", "{labels}", "--prompt", "lid", "--prompt", "HANDLE"], "distinct"),
    ],
)
def test_cli_bad_input_exits_2(hammer_files, tmp_path: Path, capsys, extra: list[str], message: str) -> None:
    mesh_path, labels_path, labels = hammer_files
    short = tmp_path / "short.json"
    write_labels(short, PartLabels(PARTS, labels[:5]))
    paths = {"missing": tmp_path / "nope.json", "short": short, "labels": labels_path}
    extra = [arg.format(**paths) for arg in extra]
    code = main(["segment", str(mesh_path), "--prompt", "handle", "--views", "2", "--image-size", "32",
                 "--refine", "none", "--out", str(tmp_path / "out"), *extra])
    assert code == 2
    assert message in capsys.readouterr().err


def test_cli_subprocess_bad_mesh_has_no_traceback(tmp_path: Path) -> None:
    broken = tmp_path / "broken.ply"
    broken.write_text("not a mesh at all")
    completed = subprocess.run(
        [sys.executable, "-m", "seggrasp", "segment", str(broken), "--prompt", "handle", "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=120,
    )
    assert completed.returncode == 2
    assert "error:" in completed.stderr and "broken.ply" in completed.stderr
    assert "Traceback" not in completed.stderr


def test_cli_ground_truth_must_name_a_prompt(hammer_files, tmp_path: Path, capsys) -> None:
    mesh_path, labels_path, _ = hammer_files
    out = tmp_path / "out"
    code = main(["segment", str(mesh_path), "--prompt", "lid", "--labels", str(labels_path), "--views", "2",
                 "--image-size", "32", "--refine", "none", "--out", str(out)])
    assert code == 2
    assert "names a part of the ground truth" in capsys.readouterr().err
    assert not out.exists()  # checked before anything is computed or written


@pytest.mark.parametrize("option", ["--out", "--cache-dir"])
@pytest.mark.parametrize("kind", ["file", "inside_a_file", "unwritable", "name_too_long"])
def test_cli_unusable_out_is_refused_before_any_work(hammer_files, tmp_path: Path, capsys, monkeypatch, kind,
                                                     option) -> None:
    mesh_path, labels_path, _ = hammer_files
    a_file = tmp_path / "taken"
    a_file.write_text("x")
    folder = {"file": a_file, "inside_a_file": a_file / "sub", "unwritable": tmp_path / "ro" / "out",
              "name_too_long": tmp_path / ("x" * 300) / "sub"}[kind]
    if kind == "unwritable":
        (tmp_path / "ro").mkdir()

        make_temporary = tempfile.TemporaryDirectory

        def refuse(*args, **kwargs):
            if Path(kwargs["dir"]) == tmp_path / "ro":
                raise PermissionError(13, "Permission denied", str(tmp_path / "ro"))
            return make_temporary(*args, **kwargs)

        monkeypatch.setattr("tempfile.TemporaryDirectory", refuse)  # root may write anywhere: simulate the refusal
    monkeypatch.setattr("seggrasp.__main__.load_mesh", lambda *a: pytest.fail("work started before it was checked"))
    places = {"--out": str(tmp_path / "out"), "--cache-dir": str(tmp_path / "cache")} | {option: str(folder)}
    code = main(["segment", str(mesh_path), "--prompt", "handle", "--labels", str(labels_path), "--views", "2",
                 "--image-size", "32", "--refine", "none", "--out", places["--out"], "--cache-dir",
                 places["--cache-dir"]])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {option} {str(folder)[:120]}") and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("extra, message", [
    (["--views", "1000"], "--views must be between 1 and 64"),
    (["--image-size", "10000"], "--image-size must be between 8 and 2048"),
    (["--views", "64", "--image-size", "2048"], "limit is 32 Mpx"),
    (["--coacd-timeout", "0"], "--coacd-timeout"),
])
@pytest.mark.slow
def test_cli_absurd_work_sizes_are_refused(hammer_files, tmp_path: Path, capsys, extra, message) -> None:
    mesh_path, labels_path, _ = hammer_files
    with pytest.raises(SystemExit) as exited:
        main(["segment", str(mesh_path), "--prompt", "handle", "--labels", str(labels_path), "--out",
              str(tmp_path / "o"), *extra])
    assert exited.value.code == 2
    assert message in capsys.readouterr().err
    assert "--views" in subprocess.run([sys.executable, "-m", "seggrasp", "segment", "--help"], capture_output=True,
                                       text=True, timeout=60).stdout.split("Limits:")[1]


def test_cli_refuses_a_mesh_over_the_face_limit(hammer_files, tmp_path: Path, capsys, monkeypatch) -> None:
    mesh_path, labels_path, labels = hammer_files
    monkeypatch.setattr("seggrasp.__main__.MAX_SEGMENT_FACES", len(labels) - 1)
    code = main(["segment", str(mesh_path), "--prompt", "handle", "--labels", str(labels_path), "--views", "2",
                 "--image-size", "32", "--out", str(tmp_path / "o")])
    assert code == 2
    assert f"segment takes at most {len(labels) - 1:,}" in capsys.readouterr().err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("signum", ["SIGTERM", "SIGINT", "SIGKILL"])
def test_killing_segment_kills_its_coacd_processes(tmp_path: Path, signum: str) -> None:
    """A cold reference sweep of a torus (CoACD at 0.01 takes minutes); the CLI is killed once a CoACD child runs."""
    import signal
    import time

    mesh = trimesh.creation.torus(0.05, 0.015, major_sections=48, minor_sections=24)
    mesh_path, labels_path = tmp_path / "torus.obj", tmp_path / "torus.json"
    mesh.export(mesh_path)
    write_labels(labels_path, PartLabels(["body"], np.zeros(len(mesh.faces), dtype=int)))
    cli = subprocess.Popen(
        [sys.executable, "-m", "seggrasp", "segment", str(mesh_path), "--prompt", "body", "--labels", str(labels_path),
         "--views", "2", "--image-size", "32", "--decomposition", "reference", "--cache-dir", str(tmp_path / "cache"),
         "--out", str(tmp_path / "out")],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # a background launcher may ignore SIGINT
    try:
        deadline = time.monotonic() + 90
        children: set[int] = set()
        while not children and time.monotonic() < deadline and cli.poll() is None:
            time.sleep(0.2)
            children = child_pids(cli.pid)
        assert children, "no CoACD child appeared"
        time.sleep(0.5)
        cli.send_signal(getattr(signal, signum))
        cli.wait(timeout=30)
        time.sleep(3)
        survivors = [pid for pid in children if alive(pid)]
        assert survivors == [], f"CoACD processes {survivors} outlived the killed CLI"
        assert b"Traceback" not in cli.stderr.read()
    finally:
        for pid in child_pids(cli.pid) | (children if "children" in locals() else set()):
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        if cli.poll() is None:
            cli.kill()


@pytest.mark.parametrize("preset", SIMULATED_PRESETS)
def test_every_spelling_of_a_simulated_detector_reads_as_its_record_label(preset: str) -> None:
    spec = DetectorSpec("simulated", preset=preset, seed=4)
    for text in (preset, f"simulated:{preset}", spec.label):
        assert parse_detector(text, seed=4) == spec
    assert parse_detector("simulated") == DetectorSpec()  # the default preset
    assert SimulatedDetector(PartLabels(PARTS, np.zeros(1, dtype=np.int64)), preset=preset).name == spec.label


@pytest.mark.parametrize("name", REAL_DETECTORS)
def test_a_real_detector_needs_weights(name: str) -> None:
    assert parse_detector(name, "weights/dir", seed=2) == DetectorSpec(name, weights="weights/dir", seed=2)
    with pytest.raises(ValueError, match="needs weights"):
        parse_detector(name)
    with pytest.raises(ValueError, match="unknown detector"):
        parse_detector(f"{name}:typical", "w")


@pytest.mark.parametrize("text", ["", "simulated:", "simulated:flawless", "typical:hard", "owl"])
def test_unknown_detectors_are_refused_with_the_known_names(text: str) -> None:
    with pytest.raises(ValueError, match="simulated:typical"):
        parse_detector(text)
