"""One twin object as a self-contained value, for engines whose workers may run where the package's assets are not:
its manifest record, its files (mesh, part labels, collision model, URDF) and its bundled decomposition cache
entries. The Ray driver packs each object of a run once and puts it in the object store; a task unpacks it into a
node-local folder named by its content (written once per node and version, atomically, so concurrent workers agree)
and loads the object from there with the package's own loader.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from seggrasp.io import atomic_write_bytes, atomic_write_text
from seggrasp.objects import ASSETS_DIR, ObjectModel, load_asset

#: Where workers unpack shipped objects (<root>/<object>-<content digest>/): $SEGGRASP_TWIN_DIR, else a folder in
#: the node's temporary directory.
TWIN_DIR_ENV = "SEGGRASP_TWIN_DIR"


def unpack_root() -> Path:
    """The folder shipped objects are unpacked in on this node."""
    return Path(os.environ.get(TWIN_DIR_ENV) or Path(tempfile.gettempdir()) / "seggrasp-twin")


@dataclass(frozen=True)
class TwinObject:
    """A twin object's data: manifest record, files (path under the assets folder -> bytes) and decomposition
    cache entries (`<key>.npz` -> bytes)."""

    object_id: str
    record: dict
    files: dict[str, bytes]
    decompositions: dict[str, bytes]

    @property
    def digest(self) -> str:
        """Hash of the whole content: names the unpacked folder (a changed asset gets a fresh one)."""
        h = hashlib.sha256(json.dumps(self.record, sort_keys=True).encode())
        for name, data in sorted(self.files.items()) + sorted(self.decompositions.items()):
            h.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
        return h.hexdigest()[:16]

    @property
    def size(self) -> int:
        """Bytes of file content it carries."""
        return sum(map(len, self.files.values())) + sum(map(len, self.decompositions.values()))


def pack(object_id: str, decomposition_seed: int, assets_dir: Path = ASSETS_DIR) -> TwinObject:
    """Read one object of the installed twin and the bundled decomposition entries its sweep (CoACD seed
    `decomposition_seed`, the episode's configuration) can read."""
    from seggrasp.decompose import ASSET_CACHE_DIR, DecompositionConfig
    from seggrasp.decompose.sweep import sweep_cache_keys

    assets_dir = Path(assets_dir)
    records = json.loads((assets_dir / "manifest.json").read_text())["objects"]
    record = next((r for r in records if r["id"] == object_id), None)
    if record is None:
        raise ValueError(f"unknown object id {object_id!r}; the twin has {sorted(r['id'] for r in records)}")
    files = {rel: (assets_dir / rel).read_bytes() for rel in record["files"].values()}
    mesh = load_asset(object_id, assets_dir).mesh
    keys = sweep_cache_keys(mesh, DecompositionConfig(seed=decomposition_seed))
    entries = (Path(ASSET_CACHE_DIR) / f"{key}.npz" for key in keys)
    return TwinObject(object_id, record, files, {p.name: p.read_bytes() for p in entries if p.is_file()})


def unpack(twin: TwinObject, root: Path | None = None) -> tuple[ObjectModel, Path]:
    """Write `twin` under `root` (default `unpack_root()`) unless it is there already, and load it: (the object,
    the folder of its decomposition cache entries, to use as the episode's decomposition cache)."""
    folder = Path(root or unpack_root()) / f"{twin.object_id}-{twin.digest}"
    manifest = folder / "manifest.json"
    if not manifest.is_file():  # the manifest is written last: its presence means the folder is complete
        for rel, data in twin.files.items():
            atomic_write_bytes(folder / rel, data)
        for name, data in twin.decompositions.items():
            atomic_write_bytes(folder / "decompositions" / name, data)
        (folder / "decompositions").mkdir(parents=True, exist_ok=True)
        atomic_write_text(manifest, json.dumps({"objects": [twin.record]}))
    return load_asset(twin.object_id, folder), folder / "decompositions"
