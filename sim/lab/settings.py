"""The emulated controller's settings: its generation (CB3 3.x, e-Series 5.x), PolyScope version, serial number
and timings (`python -m sim.lab serve --controller cb3|e-series --polyscope X.Y.Z`)."""

from __future__ import annotations

from dataclasses import dataclass

GENERATIONS = {"cb3": 3, "e-series": 5}
DEFAULT_POLYSCOPE = {"cb3": "3.15.7", "e-series": "5.11.1"}


def parse_polyscope(text: str, generation: str) -> tuple[int, int, int, int]:
    """'5.11.1' or '5.11.1.108318' -> (major, minor, bugfix, build), checked against the controller generation."""
    parts = text.strip().split(".")
    if not 3 <= len(parts) <= 4 or not all(p.isdigit() for p in parts):
        raise ValueError(f"PolyScope version {text!r} is not of the form X.Y.Z (or X.Y.Z.build)")
    version = tuple(int(p) for p in parts) + (0,) * (4 - len(parts))
    if version[0] != GENERATIONS[generation]:
        raise ValueError(f"PolyScope {text} does not run on a {generation} controller (it runs "
                         f"{GENERATIONS[generation]}.x)")
    return version  # type: ignore[return-value]


@dataclass(frozen=True)
class ControllerSettings:
    """Controller generation ("cb3" 125 Hz, "e-series" 500 Hz), PolyScope version, serial number and timings."""

    generation: str = "e-series"
    polyscope: tuple[int, int, int, int] = (5, 11, 1, 0)
    serial: str = "20235500001"
    unlock_delay: float = 5.0  # s after a protective stop before the dashboard may unlock it (UR's rule)
    program_start_delay: float = 0.1  # s from a complete script to its program running

    @property
    def frequency(self) -> float:
        """The RTDE rate (Hz) of this generation."""
        return 500.0 if self.generation == "e-series" else 125.0

    @property
    def remote_control_exists(self) -> bool:
        """Whether this PolyScope has the local/remote control switch (ur_rtde checks it on 5.6 and later)."""
        return self.polyscope[0] == 5 and self.polyscope[1] > 5
