"""`--engine ray`: the (object, seed) tasks of a run as Ray tasks, on a local Ray instance or a cluster.

Workers never touch the result files: a task returns its new records and the driver alone appends them (one
locked, fsynced write per task), so resume, torn-line repair and duplicate refusal are the local engine's. A task
whose worker process dies is retried by Ray from scratch (its records were only in the dead process's memory); one
that still fails after `MAX_RETRIES` retries is reported as a crash, like an object that raised.

The run's settings and each object of the run (its files and bundled decomposition entries, twin.py) go to the
object store once (`ray.put`) and every task gets references, so a node needs the package's code but not its
twin assets. The driver packs the objects while the local Ray instance starts (its start-up is mostly waiting on
the processes it launches), and shuts the instance down while it writes the summary.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from seggrasp.io import atomic_write_json
from sim.evaluate.config import RunConfig
from sim.evaluate.records import JsonLines, error_message
from sim.evaluate.runner import ObjectTask, Recorded, RunStopped, evaluate_object, make_tasks, worker_init
from sim.evaluate.twin import TwinObject, pack

LOG = logging.getLogger("sim.evaluate")
#: Retries of a task whose worker process died (Ray's own retry; an exception inside a task is not retried: it is
#: recorded as the object's crash, as with the local engine).
MAX_RETRIES = 3
#: Fault injection for the kill test: a path; the first task that finds it absent creates it (holding its pid) and
#: kills its own worker process after evaluating, before returning its records.
KILL_ONCE_ENV = "SEGGRASP_RAY_KILL_ONCE"
#: A JSON file to write the run's time stamps to (`python -m sim.evaluate.bench` sets it to see where Ray's time
#: goes): the driver entering the engine, Ray connected, objects packed, each task's start and end in its worker and
#: its arrival at the driver, the last task done, Ray stopped.
TRACE_ENV = "SEGGRASP_RAY_TRACE"
#: How long the driver waits for each step of a Ray connection check (TCP connect, then the head's first reply), s.
CONNECT_TIMEOUT = 10.0
#: The driver waits for finished tasks in slices of this many seconds (so a signal is handled between them).
WAIT_SLICE = 1.0
#: How long a stopped driver waits for the processes of its local instance to end before killing them, s.
TAKE_DOWN_TIMEOUT = 10.0
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
HTTP2_EMPTY_SETTINGS = bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # length 0, type SETTINGS, no flags, stream 0
HTTP2_SETTINGS = 4
_stopping: list[threading.Thread] = []  # a local instance being shut down behind the driver's back


class Trace:
    """Time stamps (time.time()) of one Ray run, written to $SEGGRASP_RAY_TRACE when that is set."""

    def __init__(self) -> None:
        self.path = os.environ.get(TRACE_ENV)
        self.stamps: dict[str, float] = {"engine": time.time()}
        self.tasks: list[dict] = []
        self.packed_bytes = 0

    def mark(self, name: str) -> None:
        self.stamps[name] = time.time()

    def write(self) -> None:
        if self.path:
            atomic_write_json(self.path, {"stamps": self.stamps, "tasks": self.tasks,
                                          "packed_bytes": self.packed_bytes})


def _run_task(config: RunConfig, object_id: str, seed: int, recorded: Recorded, out: str, twin: TwinObject) -> dict:
    """One (object, seed) in a Ray worker, on the shipped object `twin`: its status with the new records (never
    raises)."""
    started = time.time()
    worker_init(config.uses_torch)
    task = ObjectTask(object_id, seed, config, out, recorded, parallel=True, collect=True, twin=twin)
    status = evaluate_object(task)
    status["worker"] = {"pid": os.getpid(), "started": started, "finished": time.time()}
    marker = os.environ.get(KILL_ONCE_ENV)
    if marker:
        try:
            with open(marker, "x") as handle:
                handle.write(str(os.getpid()))
        except FileExistsError:
            pass
        else:
            os.kill(os.getpid(), signal.SIGKILL)
    return status


def _connect(workers: int, address: str | None) -> bool:
    """Join the cluster at `address`, or start a local instance with `workers` CPUs; True when started here."""
    import ray

    while _stopping:  # the previous run's instance first
        _stopping.pop().join()
    if ray.is_initialized():
        return False
    options = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": True}
    if address:
        _probe(address)
        try:
            ray.init(address=address, **options)
        except ConnectionError as exc:
            raise ValueError(f"cannot join the Ray cluster at {address}: {str(exc).splitlines()[0]}. A cluster of "
                             f"Ray 2.59 or later may require its token: set RAY_AUTH_MODE=token and give this "
                             f"machine the head's token (`ray get-auth-token` on the head) in ~/.ray/auth_token or "
                             f"RAY_AUTH_TOKEN (README, 'Running on a Ray cluster')") from exc
    else:
        # "local": a new instance of our own, even when a `ray start` cluster runs on this machine
        ray.init(address="local", num_cpus=workers, object_store_memory=256 * 1024**2, **options)
    return True


def _probe(address: str) -> None:
    """Refuse, within `CONNECT_TIMEOUT` s, a cluster address where no Ray head answers: ray.init retries such an
    address for many minutes in native code, deaf to SIGTERM. A head's GCS is a gRPC (HTTP/2) server: it answers
    the HTTP/2 client preface with a SETTINGS frame."""
    from ray._private.services import canonicalize_bootstrap_address

    try:  # host:port as ray.init will dial it (a Ray client address ray://host:port: that host and port)
        target = address.split("://", 1)[1] if "://" in address else canonicalize_bootstrap_address(address)
    except (ConnectionError, ValueError) as exc:  # auto: no cluster recorded on this machine; a malformed address
        raise ValueError(f"cannot join the Ray cluster at {address}: {str(exc).splitlines()[0]}") from exc
    if target is None:  # auto without a recorded cluster: ray.init says so at once
        return
    host, _, port = target.rpartition(":")
    dialled = target if target == address else f"{target} (as Ray dials {address})"
    try:
        connection = socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT)
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot join the Ray cluster at {address}: nothing answers at {dialled} "
                         f"({error_message(exc) if isinstance(exc, OSError) else exc}); is the head running "
                         "(`ray start --head`) and the address right?") from None
    reply = b""
    with connection:
        deadline = time.monotonic() + CONNECT_TIMEOUT  # one deadline, whatever trickles in
        try:
            connection.sendall(HTTP2_PREFACE + HTTP2_EMPTY_SETTINGS)
            while len(reply) < 9:
                connection.settimeout(max(deadline - time.monotonic(), 0.01))
                chunk = connection.recv(9 - len(reply))
                if not chunk:
                    break
                reply += chunk
        except OSError:  # a timeout, a reset: no reply
            pass
    if len(reply) < 9 or reply[3] != HTTP2_SETTINGS:
        raise ValueError(f"cannot join the Ray cluster at {address}: {dialled} accepts connections but does not "
                         f"answer as a Ray head (no gRPC reply within {CONNECT_TIMEOUT:g} s); check the address and "
                         "port")


class _Stopper:
    """While active (on the main thread), SIGTERM and SIGINT are noted instead of reaching Ray's native handler
    (a signal dump, exit 134) or raising inside Ray's native wait; `check` then raises `RunStopped`. The previous
    handlers come back at exit."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __enter__(self) -> "_Stopper":
        self.received: int | None = None
        self.previous = {}
        self.install()
        return self

    def install(self) -> None:
        """(Re)install the handlers (ray.init puts its own in place)."""
        if threading.current_thread() is threading.main_thread():
            self.previous = {number: signal.signal(number, self._note) for number in self.SIGNALS} | self.previous

    def _note(self, signum: int, frame) -> None:
        self.received = signum

    def check(self) -> None:
        """Raise `RunStopped` if a signal came."""
        if self.received is not None:
            raise RunStopped(f"stopped by {signal.Signals(self.received).name}", 128 + self.received)

    def __exit__(self, *exc) -> None:
        for number, previous in self.previous.items():
            signal.signal(number, previous)


def evaluate_on_ray(config: RunConfig, out: Path, workers: int, address: str | None, on_status) -> list[dict]:
    """Evaluate every (object, seed) of the run that `out` does not hold completely as Ray tasks, appending each
    finished task's records to `out` (driver side); `on_status` sees every status, as with the local engine
    (runner.evaluate_objects). Returns the crashes."""
    # Ray's native failure handler (read when ray is imported) turns a SIGTERM during ray.init into a signal dump
    # and an abort (exit 134); without it the signal reaches Python's handler (_Stopper). Ray still reports a
    # worker's crash.
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    import ray

    tasks, complete = make_tasks(config, out, parallel=True, collect=True)
    for status in complete:
        on_status(status)
    if not tasks:
        return []
    trace = Trace()
    with _Stopper() as stopper:
        with ThreadPoolExecutor(1) as packer:  # ray.init must run on the main thread
            packing = packer.submit(_pack_timed, tasks, config.decomposition_seed, trace)
            try:
                started_here = _connect(workers, address)
            except SystemExit:  # the SIGTERM handlers ray.init puts in place (until ours is back) exit
                _take_down(ray.shutdown)  # what ray.init had started
                raise RunStopped("stopped by SIGTERM", 128 + signal.SIGTERM) from None
            stopper.install()
            trace.mark("connected")
            twins = packing.result()
        return _run_tasks(tasks, twins, config, started_here, trace, stopper, on_status)


def _run_tasks(tasks: list[ObjectTask], twins: dict[str, TwinObject], config: RunConfig, started_here: bool,
               trace: Trace, stopper: _Stopper, on_status) -> list[dict]:
    """Submit the tasks to the connected Ray instance and receive them as they finish; returns the crashes."""
    import ray

    stopped = False
    try:
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(_run_task)
        config_ref = ray.put(config)
        twin_refs = {object_id: ray.put(twin) for object_id, twin in twins.items()}
        pending = {remote.remote(config_ref, t.object_id, t.seed, t.recorded, t.out, twin_refs[t.object_id]): t
                   for t in tasks}
        crashes = []
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_SLICE)
            stopper.check()
            if ready:
                crashes += _receive(ready[0], pending.pop(ready[0]), trace, on_status)
        trace.mark("done")
        return crashes
    except RunStopped:
        stopped = True
        raise
    finally:
        if started_here and not stopped:  # stopping the local instance waits on its processes: the driver goes on
            _stopping.append(threading.Thread(target=_stop, args=(trace,), name="ray-shutdown"))
            _stopping[-1].start()
        elif started_here:  # stopped from outside: take the instance down before exiting
            _take_down(lambda: _stop(trace))
        else:
            trace.write()


def _receive(ref, task: ObjectTask, trace: Trace, on_status) -> list[dict]:
    """Write a finished Ray task's records (driver side) and report its status; returns it as a crash or not."""
    import ray

    try:
        status = ray.get(ref)
    except ray.exceptions.RayError as exc:  # the worker died more often than Ray retries
        status = {"object_id": task.object_id, "seed": task.seed, "ok": False, "seconds": 0.0,
                  "error": f"{type(exc).__name__}: the Ray task failed", "traceback": str(exc)}
    if "worker" in status:  # (not when its worker died for good)
        trace.tasks.append(dict(status.pop("worker"), received=time.time()))
    for name, records in status.pop("records", {}).items():
        JsonLines(Path(task.out) / name).extend(records)
    return on_status(status)


def _take_down(shutdown) -> None:
    """Call `shutdown` (of the local instance), then end the processes this driver started that outlive it for
    `TAKE_DOWN_TIMEOUT` s (a node's agents, orphaned when the run is stopped mid-task, wait for nothing)."""
    started = _descendants(os.getpid())
    shutdown()
    deadline = time.monotonic() + TAKE_DOWN_TIMEOUT
    while _running(started) and time.monotonic() < deadline:
        time.sleep(0.2)
    for pid in _running(started):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:  # ended meanwhile
            pass


def _descendants(pid: int) -> dict[int, str]:
    """{pid: start time} of the processes descending from `pid` (from /proc; empty where there is none)."""
    parents = {}
    for entry in Path("/proc").glob("[0-9]*"):
        fields = _stat_fields(entry)
        if fields is not None:
            parents[int(entry.name)] = (int(fields[1]), fields[19])
    found, frontier = {}, [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, start) in parents.items():
            if ppid == parent and child not in found:
                found[child] = start
                frontier.append(child)
    return found


def _running(processes: dict[int, str]) -> list[int]:
    """Those of `processes` ({pid: start time}) still running (the same process: same start time, not a zombie)."""
    running = []
    for pid, start in processes.items():
        fields = _stat_fields(Path(f"/proc/{pid}"))
        if fields is not None and fields[19] == start and fields[0] != "Z":
            running.append(pid)
    return running


def _stat_fields(entry: Path) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state first), None when the process is gone."""
    try:
        return (entry / "stat").read_text().rpartition(")")[2].split()
    except OSError:
        return None


def _stop(trace: Trace) -> None:
    """Shut the local Ray instance down and write the trace."""
    import ray

    ray.shutdown()
    trace.mark("stopped")
    trace.write()


def _pack_timed(tasks: list[ObjectTask], decomposition_seed: int, trace: Trace) -> dict[str, TwinObject]:
    twins = pack_objects(tasks, decomposition_seed)
    trace.mark("packed")
    trace.packed_bytes = sum(t.size for t in twins.values())
    return twins


def pack_objects(tasks: list[ObjectTask], decomposition_seed: int) -> dict[str, TwinObject]:
    """Each object of `tasks` packed once (whatever its number of seeds), in task order."""
    return {object_id: pack(object_id, decomposition_seed) for object_id in dict.fromkeys(t.object_id for t in tasks)}
