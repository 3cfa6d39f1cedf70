"""Test-wide settings: headless OSMesa rendering, one torch thread, no network for model hubs."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

try:
    import torch  # noqa: E402

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover - torch is a hard dependency, but keep collection readable
    pass

@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """The YCB scans (`$SEGGRASP_YCB_DIR`, else shared/data/ycb beside the repository: `seggrasp.datasets`); tests
    that need them skip when the folder is absent."""
    from seggrasp.datasets import ycb_data_dir

    folder = ycb_data_dir()
    if not folder.is_dir():
        pytest.skip(f"YCB scans not found at {folder} (set SEGGRASP_YCB_DIR; see assets/ycb/README.md)")
    return folder


@pytest.fixture(scope="session")
def twin_knife():
    """The twin's chef knife (`seggrasp.objects.ObjectModel`); tests that need it skip when the twin is absent."""
    from seggrasp.objects import load_asset

    try:
        return load_asset("knife_chef")
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"twin not available: {exc}")


@pytest.fixture(scope="session")
def two_tier():
    """A 30 mm wide block 10 mm tall under a 20 mm wide block (trimesh), and which faces are the lower block's."""
    import numpy as np
    import trimesh

    low = trimesh.creation.box((0.040, 0.030, 0.010))
    low.apply_translation([0.0, 0.0, 0.005])
    high = trimesh.creation.box((0.040, 0.020, 0.030))
    high.apply_translation([0.0, 0.0, 0.025])
    return trimesh.util.concatenate([low, high]), np.r_[np.ones(len(low.faces), bool), np.zeros(len(high.faces), bool)]


@pytest.fixture(scope="session")
def box_with_knob():
    """A 60 mm box standing on z = 0 with a 16 mm knob on its top, and its face labels (0 body, 1 knob): the knob
    is 3 % of the surface."""
    import numpy as np
    import trimesh

    body = trimesh.creation.box((0.06, 0.06, 0.10))
    body.apply_translation([0.0, 0.0, 0.05])
    knob = trimesh.creation.cylinder(radius=0.008, height=0.02, sections=24)
    knob.apply_translation([0.0, 0.0, 0.11])
    return trimesh.util.concatenate([body, knob]), np.r_[np.zeros(len(body.faces), int), np.ones(len(knob.faces), int)]
