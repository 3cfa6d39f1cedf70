"""The result folder of a run: append-only JSON Lines, the lock that keeps a second run out, resuming, and the
per-object cache of coarse votes."""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import sys
import time
import zipfile
from dataclasses import asdict
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from seggrasp.io import atomic_save_npz, atomic_write_json
from sim.evaluate.config import RESUME_KEYS, RunConfig

LOG = logging.getLogger("sim.evaluate")
RESULT_FILES = ("trials.jsonl", "segmentations.jsonl", "curves.jsonl")


class JsonLines:
    """An append-only JSON Lines file that several processes may append to (one flushed, fsynced line at a time)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def repair(self) -> int:
        """Cut a torn last line (no trailing newline) left by a killed writer; returns the bytes removed."""
        if not self.path.exists():
            return 0
        data = self.path.read_bytes()
        if not data or data.endswith(b"\n"):
            return 0
        keep = data.rfind(b"\n") + 1
        with open(self.path, "r+b") as handle:
            handle.truncate(keep)
            handle.flush()
            os.fsync(handle.fileno())
        LOG.warning("%s: dropped a torn last line (%d bytes)", self.path, len(data) - keep)
        return len(data) - keep

    def read(self) -> list[dict]:
        """All complete records; a torn or corrupt last line is ignored, corruption elsewhere is an error."""
        if not self.path.exists():
            return []
        lines = self.path.read_text().split("\n")
        complete, tail = lines[:-1], lines[-1]
        records = []
        for number, line in enumerate(complete, start=1):
            if not line.strip():
                continue
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise ValueError(f"{self.path}:{number}: corrupt record ({exc}); not a torn last line") from exc
        if tail.strip():
            try:  # a final line without newline is either complete JSON or torn
                records.append(json.loads(tail))
            except json.JSONDecodeError:
                LOG.warning("%s: ignoring a torn last line", self.path)
        return records

    def append(self, record: dict) -> None:
        """Append one record as one line, under an exclusive lock, flushed and fsynced before returning."""
        self.extend([record])

    def extend(self, records: Iterable[dict]) -> None:
        """Append records, one line each, in one write under an exclusive lock, flushed and fsynced before
        returning (a writer killed during it leaves at most a torn last line)."""
        data = b"".join((json.dumps(r, separators=(",", ":")) + "\n").encode("utf-8") for r in records)
        if not data:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "ab") as handle:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
            try:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            finally:
                fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def seed_of(record: dict) -> int:
    """The run seed a record belongs to (records written before they carried one: seed 0)."""
    return int(record.get("seed", 0))


def trial_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record), record["method"], record["prompt"], int(record["rank"]))


def segmentation_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record), record["method"])


def curve_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record))


def unique_records(records: Iterable[dict], key: Callable[[dict], tuple]) -> list[dict]:
    """The first record of every key, in file order; duplicates (e.g. from two runs on one folder) are dropped
    with a warning."""
    seen: set[tuple] = set()
    kept = []
    for record in records:
        k = key(record)
        if k not in seen:
            seen.add(k)
            kept.append(record)
    return kept


def read_unique(path: Path, key: Callable[[dict], tuple]) -> list[dict]:
    """`JsonLines(path).read()` without duplicate keys (warns how many were dropped)."""
    records = JsonLines(path).read()
    kept = unique_records(records, key)
    if len(kept) < len(records):
        LOG.warning("%s: %d duplicate records ignored (kept the first of each)", path, len(records) - len(kept))
    return kept


class OutputLock:
    """An exclusive lock on a result folder (`.lock`, fcntl): a second run on the same folder fails at once,
    naming the run that holds it. Released when the holder exits, however it exits."""

    def __init__(self, out: Path) -> None:
        self.path = Path(out) / ".lock"
        self._handle = None

    def acquire(self) -> "OutputLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown process"
            handle.close()
            raise ValueError(f"{self.path.parent} is in use by another run ({holder}); wait for it to finish or "
                             "choose another --out") from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                     f"{' '.join(sys.argv)}")
        handle.flush()
        self._handle = handle
        return self

    def release(self) -> None:
        if self._handle is not None:
            self._handle.close()  # closing drops the flock
            self._handle = None

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def prepare_out(out: Path, config: RunConfig, resume: bool) -> RunConfig:
    """Check `out` against the run (call under its `OutputLock`), repair torn lines and record the run; returns the
    config to run: on `--resume` its methods and objects are merged with the recorded run's."""
    run_file = out / "run.json"
    trials = out / "trials.jsonl"
    if resume:
        if not run_file.exists():
            raise ValueError(f"cannot resume {out}: no run recorded there (run.json missing); drop --resume to start")
        previous = _upgraded(json.loads(run_file.read_text()))
        changed = {k: (previous.get(k), getattr(config, k)) for k in RESUME_KEYS if previous.get(k) != getattr(config, k)}
        if changed:
            raise ValueError(f"cannot resume {out}: settings differ from the recorded run (recorded, given): {changed}")
        merged = {name: list(previous.get(name) or []) for name in ("methods", "objects", "seeds")}
        for name, values in merged.items():
            values += [v for v in getattr(config, name) if v not in values]
        config = type(config)(**dict(asdict(config), **merged))
    elif run_file.exists() and trials.exists() and trials.stat().st_size > 0:
        raise ValueError(f"{out} already holds results; pass --resume to continue them or choose another --out")
    for name in RESULT_FILES:
        JsonLines(out / name).repair()
    atomic_write_json(run_file, asdict(config))
    return config


def _upgraded(previous: dict) -> dict:
    """A run.json written before runs had several seeds (one `seed`; CoACD seeded with it), a grip force (100 N) or
    a named twin gripper model (the linkage's revolute joints)."""
    if "seeds" not in previous and "seed" in previous:
        previous = dict(previous, seeds=[previous["seed"]], decomposition_seed=previous["seed"])
    twin_gripper = "linkage" if previous.get("backend", "sim") == "sim" else ""
    return dict({"grip_force": 100.0, "twin_gripper": twin_gripper}, **previous)


class VoteCache:
    """Coarse votes per object, keyed by everything they depend on (planning mesh, prompts in order, detector and
    its seed): a resumed run reuses them only for the same inputs. A damaged entry is reported and recomputed."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)

    def _path(self, key: str) -> Path:
        return self.directory / f"coarse-{key[:24]}.npz"

    def load(self, key: str, shape: tuple[int, int]) -> np.ndarray | None:
        """The cached (F, P) votes for `key`, or None (absent, or damaged: then the file is removed)."""
        path = self._path(key)
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                stored_key, scores = str(data["key"]), np.asarray(data["scores"], dtype=np.float64)
            if stored_key != key or scores.shape != tuple(shape):
                raise ValueError(f"holds votes for another input (key {stored_key[:12]}, shape {scores.shape})")
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            LOG.warning("%s: damaged vote cache (%s: %s); discarding it and recomputing", path, type(exc).__name__, exc)
            path.unlink(missing_ok=True)
            return None
        return scores

    def save(self, key: str, scores: np.ndarray) -> None:
        """Store the votes for `key` (atomically)."""
        atomic_save_npz(self._path(key), scores=scores, key=np.array(key))

