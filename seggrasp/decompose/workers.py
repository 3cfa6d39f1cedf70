"""CoACD runs in child processes: the working mesh they see, one run per process, time budget, progress.

CoACD aborts the whole interpreter on some inputs (failed C++ assertions), so no run shares a process with the
caller or with another run. Children die with their parent: on Linux each child asks the kernel for SIGKILL when
its parent dies (prctl PR_SET_PDEATHSIG), and the parent kills the children it still runs when it leaves
`run_jobs` early (an exception, SIGINT, or SIGTERM turned into SystemExit by the command line).
"""

from __future__ import annotations

import ctypes
import faulthandler
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh

from seggrasp.decompose.config import COACD_LOG_LEVELS
from seggrasp.decompose.mapping import canonical_parts, map_faces_to_hulls

logger = logging.getLogger(__name__)

#: Simplification of a mesh over the CoACD face limit may coarsen up to this fraction of its diagonal.
MAX_SIMPLIFY_TOLERANCE = 0.008
#: A CoACD run that takes longer than this logs "still running" at this interval (seconds).
HEARTBEAT_S = 10.0
#: How often (seconds) the CPU time of running CoACD processes is compared with the budget.
BUDGET_POLL_S = 0.5
_PR_SET_PDEATHSIG = 1


def set_coacd_log_level(level: str) -> None:
    """Validate `level` and pass it to CoACD (an invalid string would abort the interpreter inside CoACD)."""
    if level not in COACD_LOG_LEVELS:
        raise ValueError(f"invalid CoACD log level {level!r}; use one of {COACD_LOG_LEVELS}")
    import coacd

    coacd.set_log_level(level)


def run_coacd_hulls(vertices: np.ndarray, faces: np.ndarray, threshold: float, params: dict) -> list[np.ndarray]:
    """Run CoACD once; returns the vertex array of every hull."""
    import coacd

    result = coacd.run_coacd(coacd.Mesh(vertices, faces), threshold=float(threshold), **params)
    return [np.asarray(hull_vertices, dtype=np.float64) for hull_vertices, _ in result]


def _solid(vertices: np.ndarray, faces: np.ndarray):
    """The manifold3d solid of a mesh (check `.status()`: NoError = a closed manifold)."""
    import manifold3d

    # Fresh writable C-ordered copies: manifold3d refuses read-only views.
    return manifold3d.Manifold(manifold3d.Mesh64(np.array(vertices, dtype=np.float64, order="C"),
                                                 np.array(faces, dtype=np.uint64, order="C")))


def _is_closed(solid) -> bool:
    import manifold3d

    return solid.status() == manifold3d.Error.NoError and not solid.is_empty()


def is_closed_manifold(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether manifold3d accepts the mesh as a closed manifold."""
    return _is_closed(_solid(vertices, faces))


def simplify(mesh: trimesh.Trimesh, tolerance: float, max_faces: int | None = None, passes: int = 1
             ) -> tuple[np.ndarray, np.ndarray, bool]:
    """Vertices and faces of `mesh` simplified with manifold3d within `tolerance` x its bounding-box diagonal, and
    whether the result is a closed manifold verified by manifold3d.

    manifold3d's edge collapses keep a closed manifold closed, so CoACD (which aborts on some non-manifold input)
    gets a valid mesh. With `max_faces`, the tolerance is doubled (up to MAX_SIMPLIFY_TOLERANCE) while the result has
    more faces. With `passes` > 1 the simplified solid is simplified again at the same tolerance, up to that many
    passes in all, while a pass removes at least a tenth of the faces (manifold3d leaves many collapsible edges after
    one pass of a dense mesh: 9976 faces after one pass of a 2.9M-face knife, 2624 after two). A mesh that is not a
    closed manifold, or a tolerance of 0, is returned unchanged and unverified (False: CoACD then needs its own
    preprocessing).
    """
    vertices = np.array(mesh.vertices, dtype=np.float64, order="C")
    faces = np.array(mesh.faces, dtype=np.int64, order="C")
    if tolerance <= 0:
        return vertices, faces, False
    solid = _solid(vertices, faces)
    if not _is_closed(solid):
        logger.info("mesh is not a closed manifold (%s): decomposing it without simplification", solid.status())
        return vertices, faces, False
    diagonal = float(np.linalg.norm(mesh.extents))
    solid = solid.simplify(tolerance * diagonal)
    for _ in range(passes - 1):
        again = solid.simplify(tolerance * diagonal)
        if again.is_empty() or again.num_tri() > 0.9 * solid.num_tri():
            break
        solid = again
    while max_faces is not None and solid.num_tri() > max_faces and tolerance < MAX_SIMPLIFY_TOLERANCE:
        tolerance = min(2.0 * tolerance, MAX_SIMPLIFY_TOLERANCE)
        solid = solid.simplify(tolerance * diagonal)
    simplified = solid.to_mesh64()
    return (np.asarray(simplified.vert_properties[:, :3], dtype=np.float64),
            np.asarray(simplified.tri_verts, np.int64), True)


def limit_faces(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """(vertices, faces, closed): the mesh quadric-decimated (fast-simplification) to at most about `max_faces`
    faces when it has more, and whether manifold3d verifies the result as a closed manifold; unchanged (and
    unverified) when it is small enough."""
    if len(faces) <= max_faces:
        return vertices, faces, False
    import fast_simplification

    reduction = 1.0 - max_faces / len(faces)
    points, triangles = fast_simplification.simplify(np.ascontiguousarray(vertices, np.float32),
                                                     np.ascontiguousarray(faces, np.int32), reduction)
    points, triangles = np.asarray(points, np.float64), np.asarray(triangles, np.int64)
    closed = is_closed_manifold(points, triangles)
    logger.info("decomposing a %d-face decimation (%s) of the %d-face working mesh (CoACD limit %d faces)",
                len(triangles), "a closed manifold" if closed else "not closed", len(faces), max_faces)
    return points, triangles, closed


def params_for(params: dict, closed_manifold: bool) -> dict:
    """CoACD arguments for one input mesh: preprocessing "off" becomes "auto" unless the mesh is a verified closed
    manifold (CoACD may abort on other input without its preprocessing)."""
    if params["preprocess_mode"] == "off" and not closed_manifold:
        return dict(params, preprocess_mode="auto")
    return params


class Job(NamedTuple):
    """One CoACD run: its input mesh, the centroids of the faces to map, the mesh scale and the run's settings."""

    vertices: np.ndarray
    faces: np.ndarray
    centroids: np.ndarray
    scale: float
    threshold: float
    params: dict
    log_level: str


@dataclass
class RunOutcome:
    """What became of one job: status "ok" (with `part_of_face`), "crashed" or "timeout"; wall-clock seconds."""

    threshold: float
    status: str
    seconds: float
    part_of_face: np.ndarray | None = None


def decompose_once(job: Job) -> np.ndarray:
    """One CoACD run and its face mapping (runs in a child process): the canonical part of every face."""
    set_coacd_log_level(job.log_level)
    hulls = run_coacd_hulls(job.vertices, job.faces, job.threshold, job.params)
    return canonical_parts(map_faces_to_hulls(job.centroids, hulls, job.scale))


def _die_with_parent(parent: int) -> None:
    """Ask Linux to SIGKILL this process when its parent dies; leave at once if the parent is already gone."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no libc prctl: the parent's clean-up still applies
            pass
    if os.getppid() != parent:
        os._exit(1)


def _job_process(conn, job: Job, parent: int) -> None:
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent cleans up
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    faulthandler.disable()  # a CoACD abort is reported by the parent; no interpreter dump from the child
    conn.send(decompose_once(job))
    conn.close()


def run_jobs(jobs: list[Job], workers: int, timeout: float | None = None,
             heartbeat: float = HEARTBEAT_S) -> list[RunOutcome]:
    """Run every job in its own child process, at most `workers` at a time, each within `timeout` CPU seconds.

    A run whose process dies is "crashed"; one that uses more than `timeout` seconds of CPU is killed and "timeout"
    (CPU time rather than wall-clock time, so that a run's fate does not depend on how busy the machine is; where
    /proc is missing, wall-clock time). Every finished run is logged with its threshold and time, and runs that
    take long log a heartbeat every `heartbeat` seconds.
    """
    context = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    outcomes: list[RunOutcome | None] = [None] * len(jobs)
    pending = list(range(len(jobs)))
    running: dict[int, tuple] = {}  # index -> (process, receiver, start time)
    last_beat = time.monotonic()
    try:
        while pending or running:
            while pending and len(running) < workers:
                index = pending.pop(0)
                receive, send = context.Pipe(duplex=False)
                process = context.Process(target=_job_process, args=(send, jobs[index], os.getpid()), daemon=True)
                process.start()
                send.close()
                running[index] = (process, receive, time.monotonic())
            wait = max(0.05, min(heartbeat - (time.monotonic() - last_beat), BUDGET_POLL_S if timeout else heartbeat))
            ready = multiprocessing.connection.wait([receive for _, receive, _ in running.values()], timeout=wait)
            for index in list(running):
                outcome = _collect(running, index, jobs[index].threshold, ready, timeout)
                if outcome is not None:
                    outcomes[index] = outcome
            if time.monotonic() - last_beat >= heartbeat:
                last_beat = time.monotonic()
                long_runs = [f"threshold {jobs[i].threshold:.2f} for {last_beat - started:.0f} s"
                             for i, (_, _, started) in sorted(running.items()) if last_beat - started >= heartbeat]
                if long_runs:
                    logger.info("CoACD still running: %s", ", ".join(long_runs))
    finally:
        for process, receive, _ in running.values():  # left early (exception, interrupt): no orphans
            process.kill()
            process.join()
            receive.close()
    return outcomes  # type: ignore[return-value]


def cpu_seconds(pid: int, fallback: float) -> float:
    """CPU seconds (user + system) process `pid` has used (Linux /proc), else `fallback`."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return fallback


def _collect(running: dict, index: int, threshold: float, ready: list, timeout: float | None) -> RunOutcome | None:
    """The outcome of running job `index` if it finished (or ran out of time), removing it from `running`."""
    process, receive, started = running[index]
    elapsed = time.monotonic() - started
    if receive in ready:
        try:
            outcome = RunOutcome(threshold, "ok", elapsed, receive.recv())
            logger.info("CoACD at threshold %.2f: %d parts in %.1f s", threshold, outcome.part_of_face.max() + 1,
                        elapsed)
        except EOFError:  # the child died (CoACD abort) before sending
            outcome = RunOutcome(threshold, "crashed", elapsed)
    elif timeout is not None and cpu_seconds(process.pid, elapsed) > timeout:
        process.kill()
        outcome = RunOutcome(threshold, "timeout", elapsed)
        logger.warning("CoACD at threshold %.2f exceeded its time budget of %.0f CPU s: killed; the sweep goes on "
                       "without it", threshold, timeout)
    else:
        return None
    process.join()
    receive.close()
    del running[index]
    return outcome
