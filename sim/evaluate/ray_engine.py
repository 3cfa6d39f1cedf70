"""`--engine ray`: the (object, seed) tasks of a run as Ray tasks, on a local Ray instance or a cluster.

Workers never touch the result files: a task returns its new records and the driver alone appends them (one
locked, fsynced write per task), so resume, torn-line repair and duplicate refusal are the local engine's. A task
whose worker process dies is retried by Ray from scratch (its records were only in the dead process's memory); one
that still fails after `MAX_RETRIES` retries is reported as a crash, like an object that raised.

The run's settings go to the object store once (`ray.put`) and every task gets a reference. The twin's objects and
the bundled decompositions are not shipped: every Ray node runs the installed package, which holds them, and reads
one object (a few MB at most) in a fraction of a second, against tens of seconds of simulation per task.
"""

from __future__ import annotations

import logging
import os
import signal
from pathlib import Path

from sim.evaluate.config import RunConfig
from sim.evaluate.records import JsonLines
from sim.evaluate.runner import ObjectTask, Recorded, evaluate_object, make_tasks, worker_init

LOG = logging.getLogger("sim.evaluate")
#: Retries of a task whose worker process died (Ray's own retry; an exception inside a task is not retried: it is
#: recorded as the object's crash, as with the local engine).
MAX_RETRIES = 3
#: Fault injection for the kill test: a path; the first task that finds it absent creates it (holding its pid) and
#: kills its own worker process after evaluating, before returning its records.
KILL_ONCE_ENV = "SEGGRASP_RAY_KILL_ONCE"


def _run_task(config: RunConfig, object_id: str, seed: int, recorded: Recorded, out: str) -> dict:
    """One (object, seed) in a Ray worker: its status with the new records (never raises)."""
    worker_init()
    status = evaluate_object(ObjectTask(object_id, seed, config, out, recorded, parallel=True, collect=True))
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

    if ray.is_initialized():
        return False
    options = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": True}
    if address:
        ray.init(address=address, **options)
    else:
        ray.init(num_cpus=workers, object_store_memory=256 * 1024**2, **options)
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
    started_here = _connect(workers, address)
    try:
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(_run_task)
        config_ref = ray.put(config)
        pending = {remote.remote(config_ref, t.object_id, t.seed, t.recorded, t.out): t for t in tasks}
        crashes = []
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            task = pending.pop(ref)
            try:
                status = ray.get(ref)
            except ray.exceptions.RayError as exc:  # the worker died more often than Ray retries
                status = {"object_id": task.object_id, "seed": task.seed, "ok": False, "seconds": 0.0,
                          "error": f"{type(exc).__name__}: the Ray task failed", "traceback": str(exc)}
            for name, records in status.pop("records", {}).items():
                JsonLines(Path(task.out) / name).extend(records)
            crashes += on_status(status)
        return crashes
    finally:
        if started_here:
            ray.shutdown()
