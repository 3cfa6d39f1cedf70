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
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from seggrasp.io import atomic_write_json
from sim.evaluate.config import RunConfig
from sim.evaluate.records import JsonLines
from sim.evaluate.runner import ObjectTask, Recorded, evaluate_object, make_tasks, worker_init
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


def evaluate_on_ray(config: RunConfig, out: Path, workers: int, address: str | None, on_status) -> list[dict]:
    """Evaluate every (object, seed) of the run that `out` does not hold completely as Ray tasks, appending each
    finished task's records to `out` (driver side); `on_status` sees every status, as with the local engine
    (runner.evaluate_objects). Returns the crashes."""
    import ray

    tasks, complete = make_tasks(config, out, parallel=True, collect=True)
    for status in complete:
        on_status(status)
    if not tasks:
        return []
    trace = Trace()
    with ThreadPoolExecutor(1) as packer:  # ray.init must run on the main thread
        packing = packer.submit(_pack_timed, tasks, config.decomposition_seed, trace)
        started_here = _connect(workers, address)
        trace.mark("connected")
        twins = packing.result()
    try:
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(_run_task)
        config_ref = ray.put(config)
        twin_refs = {object_id: ray.put(twin) for object_id, twin in twins.items()}
        pending = {remote.remote(config_ref, t.object_id, t.seed, t.recorded, t.out, twin_refs[t.object_id]): t
                   for t in tasks}
        crashes = []
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            task = pending.pop(ref)
            try:
                status = ray.get(ref)
            except ray.exceptions.RayError as exc:  # the worker died more often than Ray retries
                status = {"object_id": task.object_id, "seed": task.seed, "ok": False, "seconds": 0.0,
                          "error": f"{type(exc).__name__}: the Ray task failed", "traceback": str(exc)}
            if "worker" in status:  # (not when its worker died for good)
                trace.tasks.append(dict(status.pop("worker"), received=time.time()))
            for name, records in status.pop("records", {}).items():
                JsonLines(Path(task.out) / name).extend(records)
            crashes += on_status(status)
        trace.mark("done")
        return crashes
    finally:
        if started_here:  # stopping the local instance waits on its processes: the driver goes on meanwhile
            _stopping.append(threading.Thread(target=_stop, args=(trace,), name="ray-shutdown"))
            _stopping[-1].start()
        else:
            trace.write()


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
