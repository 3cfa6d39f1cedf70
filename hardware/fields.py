"""Reading the hardware bridge's YAML files: one strict YAML reader and a field reader whose errors name the field.

`read_yaml` is the only YAML reader of the cell config, the calibration file and the calibration poses file. Unlike
`yaml.safe_load` it refuses what YAML would otherwise resolve silently: a key given twice in one mapping (plain
YAML keeps the last one, so ``max_tool_speed: 0.25`` followed by ``max_tool_speed: 0.9`` would be "valid") and
integers written with a leading zero or with colons, which YAML 1.1 reads as octal or base 60 (a camera serial
``01234567`` would become 342391).

`FieldReader` pulls typed, checked values out of the parsed mappings and raises `ConfigError` with messages like
``cell.yaml: limits.max_tool_speed: must be a positive number, got -1``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation


class ConfigError(ValueError):
    """The cell configuration is invalid; the message names the file and the field."""


class _StrictLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses duplicate mapping keys and integers YAML 1.1 would read as octal/base 60."""

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
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}: first at line {first_line[key]}, again at line "
                    f"{key_node.start_mark.line + 1} (YAML would silently keep the last one)", key_node.start_mark)
            first_line[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        text = str(node.value).lstrip("+-").replace("_", "")
        if ":" in text or (len(text) > 1 and text.startswith("0") and text[1].isdigit()):
            raise yaml.constructor.ConstructorError(
                None, None, f"{node.value!r} is read by YAML as a base-8/base-60 number, not as written; quote it "
                "(a serial: \"...\") or drop the leading zero", node.start_mark)
        return super().construct_yaml_int(node)


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)


def read_yaml(path: Path, what: str, error: type[ValueError] = ValueError) -> Any:
    """Parse a YAML file strictly (see the module docstring); a missing file or bad YAML raises `error` naming
    `what` and the path."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} {path} {'is a folder, not a file' if path.is_dir() else 'not found'}")
    try:
        return yaml.load(path.read_text(), Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise error(f"{what} {path} is not valid YAML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text: {exc}") from None


class FieldReader:
    """Reads fields out of nested mappings and raises `ConfigError` naming the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, field_name: str, problem: str) -> ConfigError:
        """The error for `field_name` (dotted, e.g. ``limits.max_tool_speed``)."""
        return ConfigError(f"{self.source}: {field_name}: {problem}")

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
            raise self.error(name, f"YAML reads {value!r} as text: write a plain decimal or a point and a signed "
                             f"exponent (e.g. {float(value):.1e})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(name, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.error(name, f"must be a positive number, got {value!r}")
        if non_negative and value < 0:
            raise self.error(name, f"must be >= 0, got {value!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.error(name, f"must be in [{low}, {high}], got {value!r}")
        return float(value)

    def integer(self, data: dict, key: str, prefix: str, default: int | None = None, *, low: int | None = None,
                high: int | None = None) -> int:
        """An integer within [low, high]; `default` when absent (None: required)."""
        name = f"{prefix}{key}"
        if not self._given(data, key, name, default):
            return int(default)
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"must be an integer, got {value!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.error(name, f"must be in [{low}, {high}], got {value}")
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
            raise self.error(name, f"must be a non-empty string, got {value!r}")
        return value.strip()

    def boolean(self, data: dict, key: str, prefix: str, default: bool) -> bool:
        """true or false; `default` when absent."""
        if key not in data:
            return default
        value = data[key]
        if not isinstance(value, bool):
            raise self.error(f"{prefix}{key}", f"must be true or false, got {value!r}")
        return value

    def vector(self, value: Any, name: str, length: int) -> np.ndarray:
        """A list of `length` finite numbers."""
        if isinstance(value, (list, tuple)) and any(isinstance(v, bool) for v in value):
            raise self.error(name, f"must be a list of {length} numbers, got {value!r}")
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(name, f"must be a list of {length} numbers, got {value!r}") from None
        if array.shape != (length,) or not np.all(np.isfinite(array)):
            raise self.error(name, f"must be a list of {length} finite numbers, got {value!r}")
        return array

    def transform(self, value: Any, name: str) -> np.ndarray:
        """A rigid transform written as a 4x4 matrix or as {xyz: [..], rpy: [..]} (metres, radians, extrinsic XYZ)."""
        if isinstance(value, dict):
            self.check_keys(value, f"{name}.", {"xyz", "rpy"})
            T = np.eye(4)
            T[:3, 3] = self.vector(value.get("xyz", [0.0, 0.0, 0.0]), f"{name}.xyz", 3)
            T[:3, :3] = Rotation.from_euler("xyz", self.vector(value.get("rpy", [0.0, 0.0, 0.0]), f"{name}.rpy", 3)
                                            ).as_matrix()
            return T
        try:
            T = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(name, "must be a 4x4 matrix or {xyz: [...], rpy: [...]}") from None
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise self.error(name, f"must be a 4x4 matrix of finite numbers, got shape {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
            raise self.error(name, "last row must be [0, 0, 0, 1]")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0.999:
            raise self.error(name, "rotation part is not a proper rotation matrix (orthonormal, det +1)")
        return T


def transform_from_config(value: Any, name: str, source: str = "calibration") -> np.ndarray:
    """Validate one transform written as in the config (4x4 or {xyz, rpy}); raises `ConfigError` naming `name`."""
    return FieldReader(source).transform(value, name)
