"""The result folder of a run: append-only JSON Lines, the lock that keeps a second run out, resuming, and the
per-object cache of coarse votes."""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import socket
import sys
import time
import zipfile
from contextlib import contextmanager
from dataclasses import asdict, fields
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from seggrasp.io import atomic_save_npz, atomic_write_bytes, atomic_write_json
from sim.evaluate.config import DEFAULT_ROBOT, RESUME_KEYS, RunConfig

LOG = logging.getLogger("sim.evaluate")
#: Errors of the file system rather than of one object: a task that meets one stops the run (the other tasks would
#: meet it too), with what `error_message` says of it.
STORAGE_ERRORS = {errno.ENOSPC: "the disk is full: free space, then --resume continues the run",
                  errno.EDQUOT: "the disk quota is used up: free space, then --resume continues the run",
                  errno.EROFS: "a read-only file system: choose another --out",
                  errno.EACCES: "no permission: choose another --out", errno.EPERM: "not permitted: choose another --out",
                  errno.ENAMETOOLONG: "a name or path too long for the file system: choose a shorter one",
                  errno.ENOTDIR: "a file where a folder belongs: move it away or choose another --out",
                  errno.EISDIR: "a folder where a file belongs: move it away or choose another --out",
                  errno.EEXIST: "a file where a folder belongs: move it away or choose another --out",
                  errno.EIO: "an input/output error of the disk"}


class JsonLines:
    """An append-only JSON Lines file that several processes may append to (one flushed, fsynced line at a time)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def exists(self) -> bool:
        """Whether the file is there; a folder or a device in its place is an error."""
        if not self.path.exists():
            return False
        if not self.path.is_file():
            raise ValueError(f"{self.path} is not a regular file (a folder or a device is in its place); move it "
                             "away or choose another --out")
        return True

    def holds_records(self) -> bool:
        """Whether the file is there and not empty."""
        return self.exists() and self.path.stat().st_size > 0

    def _data(self) -> bytes | None:
        """The file's bytes (None when there is no file)."""
        return self.path.read_bytes() if self.exists() else None

    def repair(self) -> int:
        """Cut a torn last line (no trailing newline) left by a killed writer; returns the bytes removed."""
        data = self._data()
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
        """All complete records; a torn last line is ignored, anything else that is not a record is an error."""
        return [record for _, record in self.read_numbered()]

    def read_numbered(self) -> list[tuple[int, dict]]:
        """(line number, record) of every complete record; a torn last line (a killed writer's) is ignored, a line
        elsewhere that is not UTF-8 JSON of an object is an error naming the file and line."""
        data = self._data()
        if not data:
            return []
        lines = data.split(b"\n")
        records = [(number, self._parse(line, number)) for number, line in enumerate(lines[:-1], start=1)
                   if line.strip()]
        tail = lines[-1]
        if tail.strip():  # a final line without newline is either a complete record or torn
            try:
                text = tail.decode("utf-8")
                value = json.loads(text)
            except (UnicodeDecodeError, json.JSONDecodeError):
                LOG.warning("%s: ignoring a torn last line", self.path)
            else:
                records.append((len(lines), self._record(value, len(lines))))
        return records

    def _parse(self, line: bytes, number: int) -> dict:
        try:
            text = line.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.path}:{number}: not UTF-8 text (byte 0x{line[exc.start]:02x} at column "
                             f"{exc.start + 1}); re-save the line as UTF-8 or delete it") from None
        try:
            value = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.path}:{number}: corrupt record ({exc.msg} at column {exc.colno}); not a torn "
                             "last line") from None
        return self._record(value, number)

    def _record(self, value, number: int) -> dict:
        if not isinstance(value, dict):
            raise ValueError(f"{self.path}:{number}: not a record: a JSON {_json_kind(value)} where an object "
                             "{...} belongs")
        return value

    def append(self, record: dict) -> None:
        """Append one record as one line, under an exclusive lock, flushed and fsynced before returning."""
        self.extend([record])

    @staticmethod
    def encode(records: Iterable[dict]) -> bytes:
        """Records as the file's lines: one compact JSON object each."""
        return b"".join((json.dumps(r, separators=(",", ":")) + "\n").encode("utf-8") for r in records)

    def extend(self, records: Iterable[dict]) -> None:
        """Append records, one line each, in one write under an exclusive lock, flushed and fsynced before
        returning (a writer killed during it leaves at most a torn last line)."""
        data = self.encode(records)
        if not data:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with writing(self.path), open(self.path, "ab") as handle:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
            try:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            finally:
                fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


@contextmanager
def writing(path: Path) -> Iterator[None]:
    """Name `path` in an OSError raised while writing it that names no file, or only a temporary file beside it
    (a write, flush or fsync that fails, e.g. on a full disk, says only what went wrong)."""
    try:
        yield
    except OSError as exc:
        if exc.strerror and (exc.filename is None or Path(exc.filename).parent == Path(path).parent):
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise


def error_message(exc: BaseException) -> str:
    """One sentence for an error that stops a run: what an OSError says of which file (with what to do about the
    file system's errors, `STORAGE_ERRORS`), else the error's own text."""
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
        hint = STORAGE_ERRORS.get(exc.errno)
        return f"{str(where) + ': ' if where is not None else ''}{exc.strerror}{f' ({hint})' if hint else ''}"
    return str(exc)


def seed_of(record: dict) -> int:
    """The run seed a record belongs to (records written before they carried one: seed 0)."""
    return int(record.get("seed", 0))


def robot_of(record: dict) -> str:
    """The robot system a record belongs to (records written before runs had several: the UR5)."""
    return str(record.get("robot", DEFAULT_ROBOT))


def trial_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record), robot_of(record), record["method"], record["prompt"],
            int(record["rank"]))


def segmentation_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record), robot_of(record), record["method"])


def curve_key(record: dict) -> tuple:
    return (record["object_id"], seed_of(record), robot_of(record))


#: The run's result files, each with the key that makes a record unique in it (`read_unique` keeps the first).
RESULT_KEYS = {"trials.jsonl": trial_key, "segmentations.jsonl": segmentation_key, "curves.jsonl": curve_key}
RESULT_FILES = tuple(RESULT_KEYS)


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


def _json_kind(value) -> str:
    return {list: "array", str: "string", bool: "boolean", type(None): "null", dict: "object"}.get(
        type(value), "number")


#: What a value of each field kind must be (`?`: or null).
_KINDS: dict[str, tuple[str, Callable[[object], bool]]] = {
    "str": ("a string", lambda v: isinstance(v, str)),
    "count": ("a non-negative integer", lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0),
    "number": ("a number", lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)),
    "bool": ("true or false", lambda v: isinstance(v, bool)),
    "bool?": ("true, false or null", lambda v: v is None or isinstance(v, bool)),
    "list": ("an array", lambda v: isinstance(v, list)),
    "dict": ("an object", lambda v: isinstance(v, dict)),
}
#: The fields the harness reads from each result file's records, and their kinds (`seed` and `robot`: absent in
#: records written before runs had seeds or robots, read as 0 and the UR5).
RECORD_FIELDS: dict[str, dict[str, str]] = {
    "trials.jsonl": {"object_id": "str", "category": "str", "method": "str", "detector": "str", "prompt": "str",
                     "rank": "count", "executed": "bool", "reachable": "bool", "contacts_on_part": "bool?",
                     "success": "bool?"},
    "segmentations.jsonl": {"object_id": "str", "category": "str", "method": "str", "detector": "str",
                            "miou": "number", "miou_faces": "number"},
    "curves.jsonl": {"object_id": "str", "category": "str", "detector": "str", "thresholds": "list",
                     "spread": "list", "full": "list"},
}
#: What an executed trial adds (its grasp and the outcome a resumed run may reuse).
EXECUTED_FIELDS = {"T_world_grasp": "list", "width": "number", "outcome": "dict"}
SET_ASIDE = "set-aside.jsonl"


def malformed(name: str, record: dict) -> str:
    """What is wrong with the shape of a record of result file `name` ("" when nothing)."""
    fields = dict(RECORD_FIELDS[name], **{optional: kind for optional, kind in (("seed", "count"), ("robot", "str"))
                                          if optional in record})
    if name == "trials.jsonl" and record.get("executed") is True:
        fields.update(EXECUTED_FIELDS)
    for field_name, kind in fields.items():
        if field_name not in record:
            return f"not a record of {name}: {field_name!r} is missing"
        description, valid = _KINDS[kind]
        if not valid(record[field_name]):
            return f"{field_name!r} is {json.dumps(record[field_name])[:40]}, not {description}"
    return ""


def foreign(name: str, record: dict, config: RunConfig) -> str:
    """Why a well-formed record of result file `name` does not belong to the run `config` ("" when it does)."""
    from seggrasp.method import ORACLE
    from sim.evaluate.config import prompts_of

    object_id, method = record["object_id"], record.get("method")
    if object_id not in config.objects:
        return f"object {object_id!r} is not one of the run's"
    if seed_of(record) not in config.seeds:
        return f"seed {seed_of(record)} is not one of the run's seeds"
    if robot_of(record) not in config.robots:
        return f"robot {robot_of(record)!r} is not one of the run's ({', '.join(config.robots)})"
    if method is not None and method not in config.methods:
        return f"method {method!r} is not one of the run's"
    if method != ORACLE and record["detector"] != config.detector_label:  # the oracle's labels are the truth's
        return f"detector {record['detector']} is not the run's {config.detector_label}"
    prompts = prompts_of(config, object_id)
    if "prompts" in record and record["prompts"] != prompts:
        return f"prompts {record['prompts']} are not the run's {prompts} (in this order)"
    if name != "trials.jsonl":
        return ""
    if record["prompt"] not in prompts:
        return f"prompt {record['prompt']!r} is not one the run asks of {object_id} ({', '.join(prompts)})"
    if record["rank"] >= config.top_k:
        return f"rank {record['rank']} is beyond the run's top-k {config.top_k}"
    extra = record.get("extra") if isinstance(record.get("extra"), dict) else {}
    for key in ("embodiment", "backend", "perceive", "decomposition_seed"):
        if key in extra and extra[key] != getattr(config, key):
            return f"{key} {extra[key]!r} is not the run's {getattr(config, key)!r}"
    return ""


def check_records(out: Path, config: RunConfig) -> None:
    """Refuse a malformed record of `out`'s result files (ValueError naming file and line) and set aside those that
    belong to another run's settings: moved to `SET_ASIDE` with the reason, a warning, never counted."""
    for name in RESULT_FILES:
        path = out / name
        numbered = JsonLines(path).read_numbered()
        aside = {}
        for number, record in numbered:
            problem = malformed(name, record)
            if problem:
                raise ValueError(f"{path}:{number}: {problem}; fix or delete the line")
            reason = foreign(name, record, config)
            if reason:
                aside[number] = {"file": name, "line": number, "reason": reason, "record": record}
        if aside:
            lines = path.read_bytes().split(b"\n")
            JsonLines(out / SET_ASIDE).extend(aside.values())
            with writing(path):
                atomic_write_bytes(path, b"\n".join(line for number, line in enumerate(lines, start=1)
                                                    if number not in aside))
            first = next(iter(aside.values()))
            LOG.warning("%s: %d record(s) of another run set aside to %s, not counted (line %d: %s)", path,
                        len(aside), out / SET_ASIDE, first["line"], first["reason"])


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
        try:
            with writing(self.path):
                self._stamp(handle)
        except OSError:
            handle.close()
            raise
        self._handle = handle
        return self

    @staticmethod
    def _stamp(handle) -> None:
        """Say in the lock file who holds it."""
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                     f"{' '.join(sys.argv)}")
        handle.flush()

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
    config to run: on `--resume` its methods, objects and seeds are merged with the recorded run's, and records of
    other settings are set aside (`check_records`)."""
    if resume:
        previous = asdict(load_run(out))
        changed = {k: (previous.get(k), getattr(config, k)) for k in RESUME_KEYS if previous.get(k) != getattr(config, k)}
        if changed:
            raise ValueError(f"cannot resume {out}: settings differ from the recorded run (recorded, given): {changed}")
        merged = {name: list(previous.get(name) or []) for name in ("methods", "objects", "seeds", "robots")}
        for name, values in merged.items():
            values += [v for v in getattr(config, name) if v not in values]
        config = type(config)(**dict(asdict(config), **merged))
    else:
        held = [name for name in RESULT_FILES if JsonLines(out / name).holds_records()]
        if held and (out / "run.json").exists():
            raise ValueError(f"{out} already holds records of a run ({', '.join(held)}); pass --resume to continue "
                             "it or choose another --out")
        if held:
            raise ValueError(f"{out} holds records ({', '.join(held)}) but no run.json saying which run made them; "
                             "choose another --out, or move those files away to start over here")
    for name in RESULT_FILES:
        JsonLines(out / name).repair()
    if resume:
        check_records(out, config)
    with writing(out / "run.json"):
        atomic_write_json(out / "run.json", asdict(config))
    return config


def load_run(out: Path) -> RunConfig:
    """The run recorded in `out`/run.json (ValueError naming the file, and the line where there is one, when it
    cannot be read as a run)."""
    path = out / "run.json"
    if not out.is_dir():
        raise ValueError(f"cannot resume {out}: no such folder")
    if not path.is_file():
        raise ValueError(f"cannot resume {out}: no run recorded there (run.json missing); drop --resume to start")
    data = path.read_bytes()
    try:
        previous = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x}); re-save it as UTF-8") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg} at column {exc.colno})") from None
    if not isinstance(previous, dict):
        raise ValueError(f"{path}:1: not a run record: a JSON {_json_kind(previous)} where an object {{...}} belongs")
    previous = _upgraded(previous)
    kinds = {f.name: f.type for f in fields(RunConfig)}
    missing = [name for name in ("methods", "objects", "seeds") if name not in previous]
    if missing:
        raise ValueError(f"{path}: not a run record: {', '.join(map(repr, missing))} missing")
    for name, value in previous.items():
        if name in kinds and not _of_type(value, kinds[name]):
            raise ValueError(f"{path}: {name!r} is {json.dumps(value)[:40]}, not {kinds[name]}")
    return RunConfig(**{name: value for name, value in previous.items() if name in kinds})


def _of_type(value, annotation: str) -> bool:
    """Whether a JSON value fits a RunConfig field's annotation (`list[str]`, `int`, `str | None`, ...)."""
    def one(kind: str) -> bool:
        if kind == "None":
            return value is None
        if kind.startswith("list["):
            item = kind[5:-1]
            return isinstance(value, list) and all(
                isinstance(v, str) if item == "str" else isinstance(v, int) and not isinstance(v, bool) and v >= 0
                for v in value)
        if kind == "bool":
            return isinstance(value, bool)
        if kind == "int":
            return isinstance(value, int) and not isinstance(value, bool)
        if kind == "float":
            return isinstance(value, (int, float)) and not isinstance(value, bool)
        return isinstance(value, str)
    return any(one(kind.strip()) for kind in annotation.split("|"))


def _upgraded(previous: dict) -> dict:
    """A run.json written before runs had several seeds (one `seed`; CoACD seeded with it), a grip force (100 N) or
    a named twin gripper model (the linkage's revolute joints)."""
    if "seeds" not in previous and "seed" in previous:
        previous = dict(previous, seeds=[previous["seed"]], decomposition_seed=previous["seed"])
    twin_gripper = "linkage" if previous.get("backend", "sim") == "sim" else ""
    return dict({"grip_force": 100.0, "twin_gripper": twin_gripper, "dry_run": False}, **previous)


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
        with writing(self._path(key)):
            atomic_save_npz(self._path(key), scores=scores, key=np.array(key))

