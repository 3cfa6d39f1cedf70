"""seggrasp.gl: OSMesa is chosen unless another platform is set; a missing GL library is one sentence, not a
traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from seggrasp import gl

REPO = Path(__file__).resolve().parents[1]

#: Imported at start-up of a child Python (sitecustomize): dlopen of the named libraries fails as on a machine
#: without them. `{names}` is a tuple of file names; a name ending in "*" matches every file name starting with it.
HIDE_LIBRARIES = """
import ctypes
_hidden = {names!r}
_load = ctypes.CDLL.__init__

def _init(self, name, *args, **kwargs):
    base = str(name).rsplit("/", 1)[-1]
    if any(base == h or (h.endswith("*") and base.startswith(h[:-1])) for h in _hidden):
        raise OSError(f"{{name}}: cannot open shared object file: No such file or directory")
    _load(self, name, *args, **kwargs)

ctypes.CDLL.__init__ = _init
"""


def _run_headless(tmp_path: Path, hidden: tuple[str, ...], *args: str) -> subprocess.CompletedProcess:
    """Run `python *args` with no display, no PYOPENGL_PLATFORM and the `hidden` libraries failing to load."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(HIDE_LIBRARIES.format(names=hidden))
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    env.update(PYTHONPATH=f"{REPO}{os.pathsep}{site}", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(
    ("environment", "expected"),
    [({}, "osmesa"), ({"DISPLAY": ":0"}, "osmesa"), ({"WAYLAND_DISPLAY": "wayland-0"}, "osmesa"),
     ({"PYOPENGL_PLATFORM": ""}, "osmesa"), ({"PYOPENGL_PLATFORM": "egl"}, "egl"),
     ({"DISPLAY": ":0", "PYOPENGL_PLATFORM": "glx"}, "glx")],
)
def test_osmesa_is_chosen_unless_another_platform_is_set(
    monkeypatch: pytest.MonkeyPatch, environment: dict[str, str], expected: str
) -> None:
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM"):
        monkeypatch.delenv(name, raising=False)
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    assert gl.select_platform() == expected
    assert os.environ.get("PYOPENGL_PLATFORM") == expected


def test_missing_library_raises_one_sentence_naming_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    from OpenGL import platform

    monkeypatch.setattr(platform.PLATFORM, "GL", None)  # what PyOpenGL holds when dlopen failed
    monkeypatch.setattr(sys, "excepthook", sys.excepthook)
    monkeypatch.setenv("PYOPENGL_PLATFORM", "osmesa")
    with pytest.raises(gl.GLUnavailableError, match=r"libOSMesa\.so .*install the system package libosmesa6"):
        gl.import_pyrender()
    assert gl.missing_library_message("egl").endswith("install the system package libegl1 (`apt-get install libegl1`)")
    assert "\n" not in gl.missing_library_message("osmesa")


@pytest.mark.parametrize(
    "command",
    [("-m", "sim.evaluate", "--quick", "--out", "out"),
     ("-m", "seggrasp", "segment", str(REPO / "assets/objects/mug_classic/mesh.obj"), "--prompt", "handle",
      "--labels", str(REPO / "assets/objects/mug_classic/labels.json"), "--refine", "none", "--out", "out")],
    ids=["evaluate", "segment"],
)
def test_clis_without_osmesa_print_one_sentence_and_fail(tmp_path: Path, command: tuple[str, ...]) -> None:
    """Regression: without libOSMesa, `import pyrender` died with "'NoneType' object has no attribute 'glGetError'"."""
    result = _run_headless(tmp_path, ("libOSMesa*",), *command)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and "glGetError" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [f"error: {gl.missing_library_message('osmesa')}"]
    assert not (tmp_path / "out" / "trials.jsonl").exists()


@pytest.mark.slow
def test_the_runtime_package_is_enough_without_the_unversioned_dev_link(tmp_path: Path) -> None:
    """install.sh installs libosmesa6 only: PyOpenGL must find libOSMesa.so.8 when libOSMesa.so (-dev) is absent."""
    script = ("from seggrasp.render import camera_rig, render_views\nimport trimesh\n"
              "views = render_views(trimesh.creation.box(), camera_rig(1), image_size=32)\n"
              "print((views[0].face_ids >= 0).sum())")
    result = _run_headless(tmp_path, ("libOSMesa.so",), "-c", script)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout.split()[-1]) > 50
