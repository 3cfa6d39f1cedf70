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

YCB_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ycb"


@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """The shared YCB scans; tests that need them skip when the folder is absent."""
    if not YCB_DIR.is_dir():
        pytest.skip(f"YCB scans not found at {YCB_DIR}")
    return YCB_DIR


@pytest.fixture(scope="session")
def twin_knife():
    """The twin's chef knife (`seggrasp.objects.ObjectModel`); tests that need it skip when the twin is absent."""
    from seggrasp.objects import load_asset

    try:
        return load_asset("knife_chef")
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"twin not available: {exc}")
