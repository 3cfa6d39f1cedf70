"""A run carried in pieces: the (object, seed) tasks a `python -m sim.evaluate` run has finished, packed into xz
archives in a folder that travels (a repository, another machine), and unpacked into a fresh run folder that
`--resume` continues. A run longer than one sitting of its machine is finished this way, piece by piece.

    python -m sim.evaluate.pieces pack RUN PIECES     # add RUN's finished tasks that PIECES lacks, as one piece
    python -m sim.evaluate.pieces unpack PIECES RUN   # write every piece's records into a new RUN

A piece holds only whole tasks (every robot, method, prompt and slot of an (object, seed), its segmentations and
threshold curves), so a task is never split over two pieces nor counted twice. PIECES/run.json is the run's
settings; packing a run of other settings into it is refused. The records are those of the code that wrote them:
resume only with a checkout whose planning, physics and assets are that code's."""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import shutil
import sys
import tarfile
from pathlib import Path

from sim.evaluate.records import RESULT_FILES, RESULT_KEYS, JsonLines, load_run, read_unique, seed_of
from sim.evaluate.runner import is_complete, recorded_index

PIECE = re.compile(r"^piece-(\d{3})\.tar\.xz$")


def pieces_of(folder: Path) -> list[Path]:
    """The folder's pieces, in the order they were packed."""
    return sorted(path for path in folder.glob("piece-*.tar.xz") if PIECE.match(path.name))


def _members(piece: Path) -> dict[str, bytes]:
    """A piece's result files by name (ValueError naming the piece when it cannot be read)."""
    try:
        with tarfile.open(piece, "r:xz") as archive:
            return {member.name: archive.extractfile(member).read() for member in archive.getmembers()
                    if member.name in RESULT_FILES and member.isfile()}
    except (tarfile.TarError, EOFError, OSError) as exc:
        raise ValueError(f"{piece}: not a readable piece ({exc})") from None


def _tasks_of(trials: bytes) -> set[tuple[str, int]]:
    """The (object, seed) tasks of a piece's trials.jsonl."""
    return {(record["object_id"], seed_of(record)) for record in map(json.loads, trials.splitlines())}


def packed_tasks(folder: Path) -> set[tuple[str, int]]:
    """The (object, seed) tasks the folder's pieces hold."""
    return set().union(*(_tasks_of(_members(piece).get("trials.jsonl", b"")) for piece in pieces_of(folder)))


def pack(run: Path, folder: Path) -> Path | None:
    """Add the tasks `run` holds completely that `folder`'s pieces lack, as one new piece; returns its path, or None
    when there is none to add."""
    if not (run / "run.json").is_file():
        raise ValueError(f"{run} holds no run.json: not a run folder of `python -m sim.evaluate`")
    config = load_run(run)
    folder.mkdir(parents=True, exist_ok=True)
    kept = folder / "run.json"
    if kept.exists() and load_run(folder) != config:
        raise ValueError(f"{kept} records another run than {run / 'run.json'}: pack each run into its own folder")
    recorded = recorded_index(run)
    done = packed_tasks(folder)
    new = {(object_id, seed) for seed in config.seeds for object_id in config.objects
           if (object_id, seed) not in done and is_complete(recorded(object_id, seed), object_id, config.at_seed(seed))}
    if not new:
        return None
    numbers = [int(PIECE.match(path.name).group(1)) for path in pieces_of(folder)]
    piece = folder / f"piece-{max(numbers, default=-1) + 1:03d}.tar.xz"
    partial = piece.with_name(piece.name + ".partial")
    with tarfile.open(partial, "w:xz", preset=9) as archive:
        for name, key in RESULT_KEYS.items():
            data = JsonLines.encode(record for record in read_unique(run / name, key)
                                    if (record["object_id"], seed_of(record)) in new)
            member = tarfile.TarInfo(name)
            member.size = len(data)
            archive.addfile(member, io.BytesIO(data))
    os.replace(partial, piece)
    if not kept.exists():
        shutil.copyfile(run / "run.json", kept)
    return piece


def unpack(folder: Path, run: Path) -> int:
    """Write every piece of `folder` into the new run folder `run`; returns the number of tasks written."""
    if not (folder / "run.json").is_file():
        raise ValueError(f"{folder} holds no run.json: not a folder of pieces")
    held = [name for name in ("run.json", *RESULT_FILES) if (run / name).exists()]
    if held:
        raise ValueError(f"{run} already holds {', '.join(held)}: unpack into a new folder")
    run.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(folder / "run.json", run / "run.json")
    tasks = set()
    for piece in pieces_of(folder):
        members = _members(piece)
        tasks |= _tasks_of(members.get("trials.jsonl", b""))
        for name, data in members.items():
            with open(run / name, "ab") as out:
                out.write(data)
    return len(tasks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate.pieces", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    packing = sub.add_parser("pack", help="add RUN's finished tasks that PIECES lacks, as one piece")
    packing.add_argument("run", type=Path)
    packing.add_argument("pieces", type=Path)
    unpacking = sub.add_parser("unpack", help="write every piece's records into the new run folder RUN")
    unpacking.add_argument("pieces", type=Path)
    unpacking.add_argument("run", type=Path)
    args = parser.parse_args(argv)
    try:
        if args.command == "pack":
            piece = pack(args.run, args.pieces)
            print(f"{piece}: {len(_tasks_of(_members(piece)['trials.jsonl']))} tasks added" if piece else
                  f"{args.run} holds no finished task that {args.pieces} lacks: nothing packed")
        else:
            tasks = unpack(args.pieces, args.run)
            print(f"{args.run}: {tasks} tasks unpacked; continue with "
                  f"`python -m sim.evaluate --out {args.run} --resume`")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
