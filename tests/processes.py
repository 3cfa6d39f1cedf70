"""The tests' view of running processes (Linux /proc), independent of the code under test: which processes a
command started and whether they still run."""

from __future__ import annotations

from pathlib import Path


def _stat_fields(pid: int | str) -> list[str]:
    """The fields of /proc/PID/stat after the command name (state first, then the parent pid)."""
    return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()


def process_table() -> dict[int, tuple[int, str]]:
    """{pid: (parent pid, command line)} of every process."""
    table = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            parent = int(_stat_fields(entry.name)[1])
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError):
            continue
        table[int(entry.name)] = (parent, command)
    return table


def child_pids(pid: int) -> set[int]:
    """The processes whose parent is `pid`."""
    return {child for child, (parent, _) in process_table().items() if parent == pid}


def descendants(pid: int) -> dict[int, str]:
    """{pid: command line} of the processes descending from `pid`."""
    table, found, frontier = process_table(), {}, [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, command) in table.items():
            if ppid == parent and child not in found:
                found[child] = command
                frontier.append(child)
    return found


def alive(pid: int) -> bool:
    """Whether `pid` runs (exists and is not a zombie)."""
    try:
        return _stat_fields(pid)[0] != "Z"
    except OSError:
        return False
