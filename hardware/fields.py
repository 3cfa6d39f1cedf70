"""Reading the hardware bridge's YAML files: one strict YAML reader and a field reader whose errors name the field.

`read_yaml` is the only YAML reader of the cell config, the calibration file and the calibration poses file. Unlike
`yaml.safe_load` it refuses what YAML would otherwise resolve silently: a key given twice in one mapping (plain
YAML keeps the last one, so ``max_tool_speed: 0.25`` followed by ``max_tool_speed: 0.9`` would be "valid"),
integers written with a leading zero and numbers written with colons, which YAML 1.1 reads as octal or base 60 (a
camera serial ``01234567`` would become 342391, ``hold_time: 1:30.0`` 90 s). Its mappings and lists remember the
line of each entry (`LineMap`, `LineList`), so errors name the line.

`FieldReader` pulls typed, checked values out of the parsed mappings and raises `ConfigError` with messages like
``cell.yaml:58: limits.max_tool_speed: must be a positive number, got -1``.
"""

from __future__ import annotations

import math
import re
import reprlib
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation


#: The largest YAML file read (bytes): a cell config is a few kB; anything this big is not one.
MAX_YAML_BYTES = 1_000_000
#: The farthest (m, per axis) a transform of the cell may reach: a tool offset, a camera, a calibration pose.
MAX_TRANSLATION = 10.0


class ConfigError(ValueError):
    """The cell configuration is invalid; the message names the file, the line and the field."""


class LineMap(dict):
    """A mapping read by `read_yaml`: `line` is where it starts, `lines[key]` where each key is (1-based)."""

    line: int = 0
    lines: dict[Any, int]


class LineList(list):
    """A list read by `read_yaml`: `line` is where it starts, `lines[i]` where item i is (1-based)."""

    line: int = 0
    lines: list[int]


class _Refused(yaml.constructor.ConstructorError):
    """Valid YAML that the strict reader refuses (a duplicated key, an octal or base-60 number)."""


class _StrictLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses duplicate mapping keys and numbers YAML 1.1 would read as octal/base 60, and
    builds `LineMap` / `LineList` containers."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        first_line: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *anchor` overrides on purpose
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                seen = key in first_line
            except TypeError:  # an unhashable key: the base class reports it
                continue
            if seen:
                raise _Refused(
                    None, None, f"duplicate key {key!r}: first at line {first_line[key]}, again at line "
                    f"{key_node.start_mark.line + 1} (YAML would silently keep the last one)", key_node.start_mark)
            first_line[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)

    def construct_located_map(self, node: yaml.MappingNode):
        data = LineMap()
        data.line = node.start_mark.line + 1
        yield data
        data.update(self.construct_mapping(node))
        data.lines = {}
        for key_node, _ in node.value:  # after construct_mapping: merged (<<) entries are in node.value now
            try:
                data.lines.setdefault(self.construct_object(key_node), key_node.start_mark.line + 1)
            except TypeError:
                pass

    def construct_located_seq(self, node: yaml.SequenceNode):
        data = LineList()
        data.line = node.start_mark.line + 1
        yield data
        data.extend(self.construct_sequence(node))
        data.lines = [child.start_mark.line + 1 for child in node.value]

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        text = str(node.value).lstrip("+-").replace("_", "")
        if ":" in text or (len(text) > 1 and text.startswith("0") and text[1].isdigit()):
            raise _Refused(
                None, None, f"{node.value!r} is read by YAML as a base-8/base-60 number, not as written; quote it "
                "(a serial: \"...\") or drop the leading zero", node.start_mark)
        return super().construct_yaml_int(node)

    def construct_yaml_float(self, node: yaml.ScalarNode) -> float:
        if ":" in str(node.value):
            raise _Refused(None, None, f"{node.value!r} is read by YAML 1.1 as a base-60 number "
                           f"({super().construct_yaml_float(node)!r}), not as written; write the plain number",
                           node.start_mark)
        return super().construct_yaml_float(node)


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)
_StrictLoader.add_constructor("tag:yaml.org,2002:float", _StrictLoader.construct_yaml_float)
_StrictLoader.add_constructor("tag:yaml.org,2002:map", _StrictLoader.construct_located_map)
_StrictLoader.add_constructor("tag:yaml.org,2002:seq", _StrictLoader.construct_located_seq)


def read_yaml(path: Path, what: str, error: type[ValueError] = ValueError) -> Any:
    """Parse a YAML file strictly (see the module docstring); a missing, unreadable or oversized file or bad YAML
    raises `error` with one sentence naming `what`, the path and, where there is one, the line."""
    path = Path(path)
    try:
        if not path.exists():
            raise error(f"{what} {path} not found")
        if path.is_dir():
            raise error(f"{what} {path} is a folder, not a file")
        if not path.is_file():
            raise error(f"{what} {path} is not a regular file (a device, FIFO or socket)")
        with path.open("rb") as stream:
            raw = stream.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if len(raw) > MAX_YAML_BYTES:
        raise error(f"{what} {path} is larger than {MAX_YAML_BYTES // 1000} kB: not a cell configuration file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text (byte {exc.start})") from None
    try:
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        if isinstance(exc, _Refused):
            raise error(f"{where}: {exc.problem}") from None
        problem = " ".join(part for part in (exc.context, exc.problem) if part)
        raise error(f"{where}: {what} is not valid YAML: {problem}") from None
    except yaml.YAMLError as exc:
        raise error(f"{what} {path} is not valid YAML: {exc}") from None
    except RecursionError:
        raise error(f"{what} {path} is nested too deeply to be a cell configuration file") from None


_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlist = _REPR.maxtuple = 8
_REPR.maxlevel = 2
_REPR.maxlong = 40


def shown(value: Any) -> str:
    """`repr(value)` cut short, so a message quoting a huge or deeply nested value stays one short sentence."""
    return _REPR.repr(value)


def _is_number(value: Any) -> bool:
    """An int or float (not a bool) that converts to a finite float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond the float range
        return False


def _interval(low: float | None, high: float | None) -> str:
    """"in [low, high]", "at least low" or "at most high"."""
    if low is not None and high is not None:
        return f"in [{low:g}, {high:g}]"
    return f"at least {low:g}" if low is not None else f"at most {high:g}"


_PATH_PART = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def line_of(root: Any, field_name: str) -> int | None:
    """The line (1-based) of a dotted field such as ``cameras[0].fps`` in data read by `read_yaml`: the line of the
    deepest part of the path that exists (the section, for a missing key); None when none does (a missing section)
    or for data without lines."""
    line, node = None, root
    for key, index in _PATH_PART.findall(field_name):
        if isinstance(node, LineMap):
            match = next((k for k in node if str(k) == key), None) if key else None
            if match is None:
                break
            line, node = node.lines.get(match, line), node[match]
        elif isinstance(node, LineList) and index and int(index) < len(node):
            line, node = node.lines[int(index)], node[int(index)]
        else:
            break
    return line


class FieldReader:
    """Reads fields out of nested mappings and raises `ConfigError` naming the file, the line and the field.

    `root` is the whole document as `read_yaml` returned it; errors look up their field's line in it."""

    def __init__(self, source: str, root: Any = None) -> None:
        self.source = source
        self.root = root

    def error(self, field_name: str, problem: str) -> ConfigError:
        """The error for `field_name` (dotted, e.g. ``limits.max_tool_speed``)."""
        line = line_of(self.root, field_name)
        return ConfigError(f"{self.source}{f':{line}' if line else ''}: {field_name}: {problem}")

    def section(self, data: dict, key: str, prefix: str, allowed: set[str], required: bool = True) -> dict:
        """The mapping under `key` (empty if absent and not `required`), with only `allowed` keys."""
        name = f"{prefix}{key}"
        if key not in data:
            if required:
                raise self.error(name, "missing section")
            return {}
        value = data[key]
        if not isinstance(value, dict):
            raise self.error(name, f"must be a mapping, got {type(value).__name__}")
        self.check_keys(value, f"{name}.", allowed)
        return value

    def check_keys(self, data: dict, prefix: str, allowed: set[str]) -> None:
        """Refuse keys outside `allowed` (a typo must not drop a field silently)."""
        unknown = sorted(set(map(str, data)) - allowed)
        if unknown:
            raise self.error(f"{prefix}{unknown[0]}", f"unknown key (allowed: {', '.join(sorted(allowed))})")

    def _given(self, data: dict, key: str, name: str, default: Any) -> bool:
        """Whether `key` is in `data`; raises when it is missing and has no `default`."""
        if key in data:
            return True
        if default is None:
            raise self.error(name, "missing")
        return False

    def number(self, data: dict, key: str, prefix: str, default: float | None = None, *, positive: bool = False,
               non_negative: bool = False, low: float | None = None, high: float | None = None) -> float:
        """A finite number (optionally > 0, >= 0 or within [low, high]); `default` when absent (None: required)."""
        name = f"{prefix}{key}"
        if not self._given(data, key, name, default):
            return float(default)
        value = data[key]
        if isinstance(value, str) and re.fullmatch(r"\s*[-+]?\d+(\.\d*)?[eE][-+]?\d+\s*", value):
            raise self.error(name, f"YAML reads {shown(value)} as text: write a plain decimal or a point and a signed "
                             f"exponent (e.g. {float(value):.1e})")
        if not _is_number(value):
            raise self.error(name, f"must be a finite number, got {shown(value)}")
        if positive and value <= 0:
            raise self.error(name, f"must be a positive number, got {shown(value)}")
        if non_negative and value < 0:
            raise self.error(name, f"must be >= 0, got {shown(value)}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.error(name, f"must be {_interval(low, high)}, got {shown(value)}")
        return float(value)

    def integer(self, data: dict, key: str, prefix: str, default: int | None = None, *, low: int | None = None,
                high: int | None = None) -> int:
        """An integer within [low, high]; `default` when absent (None: required)."""
        name = f"{prefix}{key}"
        if not self._given(data, key, name, default):
            return int(default)
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"must be an integer, got {shown(value)}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.error(name, f"must be {_interval(low, high)}, got {shown(value)}")
        return int(value)

    def string(self, data: dict, key: str, prefix: str, default: str | None = None) -> str:
        """A non-empty string (an integer is taken as its digits: unquoted serials); `default` when absent."""
        name = f"{prefix}{key}"
        if not self._given(data, key, name, default):
            return default
        value = data[key]
        if isinstance(value, int) and not isinstance(value, bool):
            value = str(value)  # camera serials are often written without quotes
        if not isinstance(value, str) or not value.strip():
            raise self.error(name, f"must be a non-empty string, got {shown(value)}")
        return value.strip()

    def boolean(self, data: dict, key: str, prefix: str, default: bool) -> bool:
        """true or false; `default` when absent."""
        if key not in data:
            return default
        value = data[key]
        if not isinstance(value, bool):
            raise self.error(f"{prefix}{key}", f"must be true or false, got {shown(value)}")
        return value

    def vector(self, value: Any, name: str, length: int) -> np.ndarray:
        """A list of `length` finite numbers."""
        if not isinstance(value, (list, tuple)) or len(value) != length or not all(map(_is_number, value)):
            raise self.error(name, f"must be a list of {length} finite numbers, got {shown(value)}")
        return np.asarray(value, dtype=np.float64)

    def transform(self, value: Any, name: str) -> np.ndarray:
        """A rigid transform written as a 4x4 matrix or as {xyz: [..], rpy: [..]} (metres, radians, extrinsic XYZ);
        the translation within `MAX_TRANSLATION` and the angles within a turn either way."""
        if isinstance(value, dict):
            self.check_keys(value, f"{name}.", {"xyz", "rpy"})
            rpy = self.vector(value.get("rpy", [0.0, 0.0, 0.0]), f"{name}.rpy", 3)
            if np.any(np.abs(rpy) > 2 * np.pi):
                raise self.error(f"{name}.rpy", f"angles must be radians within [-2 pi, 2 pi], got {rpy.tolist()}")
            T = np.eye(4)
            T[:3, 3] = self.vector(value.get("xyz", [0.0, 0.0, 0.0]), f"{name}.xyz", 3)
            T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
        elif not (isinstance(value, (list, tuple)) and len(value) == 4 and all(
                isinstance(row, (list, tuple)) and len(row) == 4 and all(map(_is_number, row)) for row in value)):
            raise self.error(name, f"must be a 4x4 matrix of finite numbers or {{xyz: [...], rpy: [...]}}, got "
                             f"{shown(value)}")
        else:
            T = np.asarray(value, dtype=np.float64)
            if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
                raise self.error(name, "last row must be [0, 0, 0, 1]")
            R = T[:3, :3]
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0.999:
                raise self.error(name, "rotation part is not a proper rotation matrix (orthonormal, det +1)")
        if np.any(np.abs(T[:3, 3]) > MAX_TRANSLATION):
            raise self.error(name, f"translation {shown(T[:3, 3].tolist())} m reaches beyond {MAX_TRANSLATION:g} m: "
                             "metres are expected, and a cell is a few metres across")
        return T
