"""Per-face part labels: one int per face of a mesh (in the mesh file's face order) plus the part names.

File formats: JSON `{"parts": [...], "face_labels": [...]}` or NPZ with arrays `parts` and `face_labels`.
Label `k` means `parts[k]`; `-1` means unknown / no part.
"""

from __future__ import annotations

import json
import os
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from seggrasp.io import atomic_save_npz, atomic_write_text

UNKNOWN = -1


def prompt_key(name: str) -> str:
    """The form prompts and part names are compared in (the one matching rule): Unicode NFC (so a composed and a
    decomposed "café" are one name), stripped and lower-cased."""
    if not isinstance(name, str):
        raise ValueError(f"a prompt or part name must be a string, got {type(name).__name__} {name!r}")
    return unicodedata.normalize("NFC", name).strip().lower()


def same_name_groups(names: Sequence[str]) -> list[list[str]]:
    """The groups of two or more `names` that `prompt_key` makes equal (e.g. ["handle", "HANDLE"])."""
    groups: dict[str, list[str]] = {}
    for name in names:
        groups.setdefault(prompt_key(name), []).append(name)
    return [group for group in groups.values() if len(group) > 1]


def _refuse_same_names(names: Sequence[str], rule: str) -> None:
    """ValueError stating `rule` and naming the `same_name_groups` of `names`, if any."""
    groups = same_name_groups(names)
    if groups:
        # names that differ only in Unicode composition print alike: show their code points
        shown = [[ascii(n) if len({unicodedata.normalize("NFC", m) for m in group}) < len(group) else repr(n)
                  for n in group] for group in groups]
        listed = "; ".join(" and ".join(group) for group in shown)
        raise ValueError(f"{rule}, but {listed} name the same part (names are compared case-insensitively, after "
                         "Unicode NFC normalisation)")


def check_prompts(prompts: Sequence[str]) -> list[str]:
    """Stripped prompts in Unicode NFC; ValueError if there are none, one is empty, or two are the same under
    `prompt_key` (case-insensitively)."""
    if isinstance(prompts, str):
        raise ValueError(f"prompts must be a list of part names, got the single string {prompts!r}")
    given = [str(p).strip() for p in prompts]
    if not given:
        raise ValueError("give at least one prompt (a part name such as 'handle')")
    if any(not p for p in given):
        raise ValueError(f"prompts must not be empty: {list(prompts)}")
    _refuse_same_names(given, "prompts must be distinct")
    return [unicodedata.normalize("NFC", p) for p in given]


def find_prompt(names: Sequence[str], name: str) -> int | None:
    """Index of `name` among `names` under `prompt_key`, or None when absent."""
    keys = [prompt_key(n) for n in names]
    key = prompt_key(name)
    return keys.index(key) if key in keys else None


def prompt_index(names: Sequence[str], name: str, what: str = "prompts") -> int:
    """Index of `name` among `names` under `prompt_key`; ValueError naming the known ones if absent."""
    index = find_prompt(names, name)
    if index is None:
        raise ValueError(f"{name!r} is not among the {what} {list(names)}")
    return index


@dataclass
class PartLabels:
    """Part names (distinct under `prompt_key`: "handle" and "HANDLE" are refused) and one label per face
    (-1 = unknown)."""

    parts: list[str]
    face_labels: np.ndarray

    def __post_init__(self) -> None:
        if isinstance(self.parts, (str, bytes)) or not all(isinstance(p, str) for p in self.parts):
            raise ValueError(f"parts must be a list of part names (strings), got {self.parts!r}")
        self.parts = [str(p) for p in self.parts]
        labels = np.asarray(self.face_labels)
        if labels.dtype == object or labels.dtype.kind in "USb":
            raise ValueError(f"face_labels must be integers, got values of type {labels.dtype}")
        if labels.ndim != 1:
            raise ValueError(f"face_labels must be a 1-D array, got shape {labels.shape}")
        if labels.size and not np.issubdtype(labels.dtype, np.integer):
            if not np.all(np.equal(np.mod(labels, 1), 0)):
                raise ValueError("face_labels must be integers")
        self.face_labels = labels.astype(np.int64)
        _refuse_same_names(self.parts, "part names must be unique")
        bad = (self.face_labels < UNKNOWN) | (self.face_labels >= len(self.parts))
        if bad.any():
            raise ValueError(
                f"face_labels has {int(bad.sum())} values outside -1..{len(self.parts) - 1} "
                f"(first bad value {int(self.face_labels[bad][0])}) for parts {self.parts}"
            )

    @property
    def n_faces(self) -> int:
        return int(self.face_labels.shape[0])

    def check_faces(self, n_faces: int, what: str = "mesh") -> None:
        """Raise ValueError unless there is exactly one label per face of a mesh with `n_faces` faces."""
        if self.n_faces != n_faces:
            raise ValueError(f"label file has {self.n_faces} face labels but the {what} has {n_faces} faces")

    def part_index(self, name: str) -> int:
        """Index of a part by name (case-insensitive); ValueError naming the known parts if absent."""
        index = find_prompt(self.parts, name)
        if index is None:
            raise ValueError(f"no part named {name!r}; parts are {self.parts}")
        return index

    def remap_to(self, prompts: list[str]) -> np.ndarray:
        """Face labels expressed as prompt indices: a part matches a prompt by name; others become -1."""
        found = [find_prompt(prompts, part) for part in self.parts]
        table = np.array([UNKNOWN if i is None else i for i in found] + [UNKNOWN], dtype=np.int64)
        return table[self.face_labels]  # index -1 picks the trailing UNKNOWN

    def to_json(self) -> dict:
        return {"parts": list(self.parts), "face_labels": self.face_labels.tolist()}


def read_labels(path: str | os.PathLike) -> PartLabels:
    """Read a label file (.json or .npz); errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"label file not found: {path}")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or "parts" not in data or "face_labels" not in data:
                raise ValueError('expected a JSON object with keys "parts" and "face_labels"')
            return PartLabels(data["parts"], data["face_labels"])
        if path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as data:
                return PartLabels([str(p) for p in data["parts"]], data["face_labels"])
    except (ValueError, TypeError, KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f"bad label file {path}: {exc}") from exc
    raise ValueError(f"unsupported label file type {path.suffix!r} (use .json or .npz): {path}")


def write_labels(path: str | os.PathLike, labels: PartLabels) -> None:
    """Write a label file (.json or .npz) atomically."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        atomic_write_text(path, json.dumps(labels.to_json()) + "\n")
    elif path.suffix.lower() == ".npz":
        atomic_save_npz(path, parts=np.array(labels.parts), face_labels=labels.face_labels)
    else:
        raise ValueError(f"unsupported label file type {path.suffix!r} (use .json or .npz): {path}")
