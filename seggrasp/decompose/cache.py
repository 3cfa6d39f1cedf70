"""On-disk cache of CoACD runs: one compressed `<key>.npz` per run holding the face -> part array.

The writable cache is `$SEGGRASP_CACHE/decompositions` (default `~/.cache/seggrasp/decompositions`); the bundled
twin caches in assets/decompositions/ are searched read-only. Entries are written atomically (a temporary file and a
rename), so a killed run leaves no partial entry. An entry that cannot be read anyway (truncated or emptied by a
full disk, a copy or a hand) or holds no valid partition (one integer part id per face, numbered 0, 1, ... in order
of first appearance, so below the face count) is logged with its path: discarded from the writable cache, so the
run is recomputed, and skipped in a read-only one.
"""

from __future__ import annotations

import logging
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from seggrasp.decompose.mapping import canonical_parts
from seggrasp.io import atomic_save_npz, cache_root

logger = logging.getLogger(__name__)

#: What numpy raises on a damaged .npz (empty: EOFError / BadZipFile, truncated member: zlib.error / ValueError).
DAMAGED_ENTRY_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error)


def default_cache_dir() -> Path:
    """Writable cache: `$SEGGRASP_CACHE/decompositions` or `~/.cache/seggrasp/decompositions`."""
    return cache_root() / "decompositions"


def _read_entry(path: Path, n_faces: int) -> tuple[np.ndarray | None, str]:
    """The part array of one entry, or None and what is wrong with it."""
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = np.asarray(data["part_of_face"])
    except DAMAGED_ENTRY_ERRORS as exc:
        return None, f"unreadable ({type(exc).__name__}: {exc})"
    if not np.issubdtype(stored.dtype, np.integer):
        return None, f"part ids of type {stored.dtype}, expected integers"
    if stored.shape != (n_faces,):
        return None, f"{stored.size} face labels, expected {n_faces}"
    parts = stored.astype(np.int64)
    if parts.size and parts.min() < 0:
        return None, "negative part ids"
    if parts.size and parts.max() >= n_faces:
        return None, f"part id {int(parts.max())} beyond the {n_faces} faces (every part owns a face)"
    if not np.array_equal(canonical_parts(parts), parts):
        return None, "part ids not numbered 0, 1, ... in order of first appearance, as every run writes them"
    return parts, ""


def load_cached(key: str, n_faces: int, writable: Path, search: Sequence[Path]) -> np.ndarray | None:
    """The cached part array of run `key` from the first folder of `search` that holds a valid entry, else None.

    A damaged entry in `writable` is deleted (so the run is recomputed and re-cached); elsewhere it is skipped.
    """
    for folder in search:
        path = folder / f"{key}.npz"
        if not path.is_file():
            continue
        parts, problem = _read_entry(path, n_faces)
        if parts is not None:
            return parts
        if Path(folder) == Path(writable):
            logger.warning("damaged decomposition cache entry %s: %s; discarded, the run is recomputed", path, problem)
            path.unlink(missing_ok=True)
        else:
            logger.warning("damaged read-only decomposition cache entry %s: %s; skipped", path, problem)
    return None


def save_cached(writable: Path, key: str, parts: np.ndarray, threshold: float) -> None:
    """Store one run's part array atomically under `key`."""
    atomic_save_npz(Path(writable) / f"{key}.npz", part_of_face=_compact(parts), threshold=np.float64(threshold))


def _compact(parts: np.ndarray) -> np.ndarray:
    return parts.astype(np.uint8 if parts.max(initial=0) < 256 else np.uint16 if parts.max() < 65536 else np.int32)
