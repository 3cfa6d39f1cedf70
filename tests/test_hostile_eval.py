"""Regression tests of issue 34's hostile pass on `python -m sim.evaluate`: nothing silent or counted twice, nothing
unbounded, one sentence (file and line where there is one) and a non-zero exit for bad input, `--help` that tells
the truth."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from processes import alive, descendants
from sim.evaluate import JsonLines, main
from sim.evaluate.records import trial_key

REPO = Path(__file__).resolve().parents[1]
ORACLE = ["--objects", "mug_classic", "--methods", "oracle", "--embodiment", "floating", "--top-k", "1",
          "--detector", "perfect"]
SMALL = [*ORACLE[:2], "--methods", "oracle,coarse", *ORACLE[4:]]
AS_ROOT = pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("unshare"),
                             reason="needs root and unshare for a private mount namespace")


def _env() -> dict:
    return dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))


def _evaluate(*args: str, timeout: float = 60, prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    return subprocess.run([*prefix, sys.executable, "-m", "sim.evaluate", *args], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=timeout)


def _error(err: str) -> str:
    """The one `error:` line of a run's stderr (and no traceback)."""
    assert "Traceback" not in err, err
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    """A finished run (mug, oracle + coarse, top-1, perfect detector, strips), copied by the tests that change it."""
    out = tmp_path_factory.mktemp("hostile") / "run"
    assert main([*SMALL, "--record", "1", "--out", str(out)]) == 0
    return out


def _copy(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "run"))


def _trials(out: Path) -> list[dict]:
    return JsonLines(out / "trials.jsonl").read()


def _counts(out: Path) -> tuple[int, int]:
    run = json.loads((out / "summary.json").read_text())["run"]
    return run["recorded_trials"], run["expected_trials"]


# ------------------------------------------------------------------------------------- silent or duplicated


@pytest.mark.parametrize("option, value", [("--objects", "mug_classic,mug_classic"), ("--methods", "oracle,oracle"),
                                           ("--prompts", "handle,handle"), ("--categories", "mug,mug")])
def test_an_item_given_twice_is_refused(option, value, tmp_path, capsys) -> None:
    args = [*ORACLE[2:], option, value] if option in ("--objects", "--categories") else [*ORACLE, option, value]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert f"{option} lists {value.split(',')[0]} more than once" in _error(capsys.readouterr().err)
    assert not (tmp_path / "out" / "trials.jsonl").exists()


@pytest.mark.slow
def test_resume_alone_keeps_the_recorded_objects_methods_and_settings(small_run, tmp_path, capsys) -> None:
    out = _copy(small_run, tmp_path)
    recorded = json.loads((out / "run.json").read_text())
    assert main(["--resume", "--out", str(out)]) == 0
    kept = json.loads((out / "run.json").read_text())
    assert {k: v for k, v in kept.items() if k != "record"} == {k: v for k, v in recorded.items() if k != "record"}
    assert len(_trials(out)) == 4 and _counts(out) == (4, 4)
    capsys.readouterr()
    assert main(["--resume", "--top-k", "2", "--out", str(out)]) == 2
    assert "--top-k 2 contradicts the recorded run's top_k 1" in _error(capsys.readouterr().err)


@pytest.mark.slow
def test_a_fresh_run_refuses_a_folder_holding_a_killed_run_s_segmentation(small_run, tmp_path, capsys) -> None:
    """Killed after it wrote its votes and segmentation, before any trial: a fresh run with the prompts reordered
    would have reused the segmentation of the other order."""
    out = _copy(small_run, tmp_path)
    (out / "trials.jsonl").write_text("")
    assert main([*SMALL, "--prompts", "body,handle", "--out", str(out)]) == 2
    assert "already holds records of a run (segmentations.jsonl" in _error(capsys.readouterr().err)


def test_records_without_run_json_are_not_reused_by_another_run(small_run, tmp_path, capsys) -> None:
    out = _copy(small_run, tmp_path)
    (out / "run.json").unlink()
    assert main([*SMALL[:-1], "typical", "--out", str(out)]) == 2
    assert "but no run.json saying which run made them" in _error(capsys.readouterr().err)


@pytest.mark.slow
def test_records_of_another_run_are_set_aside_never_counted(small_run, tmp_path, capsys) -> None:
    out = _copy(small_run, tmp_path)
    trials = _trials(out)
    coarse = next(r for r in trials if r["method"] == "coarse" and r["prompt"] == "handle")
    kept = [r for r in trials if r is not coarse]
    pasted = [dict(coarse, detector="simulated:hard"),  # in place of the run's own: the slot must run again
              dict(coarse, rank=5), dict(coarse, prompt="spout"), dict(coarse, object_id="mug_tall")]
    (out / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in kept + pasted))
    assert main([*SMALL, "--resume", "--out", str(out)]) == 0
    assert _counts(out) == (4, 4)
    redone = _trials(out)
    assert len(redone) == 4 and {r["detector"] for r in redone if r["method"] == "coarse"} == {"simulated:perfect"}
    aside = JsonLines(out / "set-aside.jsonl").read()
    reasons = [a["reason"] for a in aside]
    assert len(aside) == 4 and [a["record"] for a in aside] == pasted
    assert "detector simulated:hard" in reasons[0] and "rank 5" in reasons[1] and "'spout'" in reasons[2]
    assert "'mug_tall'" in reasons[3]


def test_record_films_slots_with_reused_outcomes_and_captions_the_trial_s_verdict(small_run) -> None:
    from PIL import Image

    trials = {(r["method"], r["prompt"]): r for r in _trials(small_run) if r["rank"] == 0}
    assert trials["coarse", "handle"]["reused_outcome"]  # the oracle's grasp: the cell did not move for it
    for method in ("oracle", "coarse"):
        path = small_run / "strips" / f"{method}-mug_classic-handle-0.png"
        with Image.open(path) as image:
            caption = image.text["caption"]
        record = trials[method, "handle"]
        verdict = "success" if record["success"] else f"failed: {record['failure']}"
        assert caption.startswith(f"{method} mug_classic 'handle' #0: {verdict}")


def test_a_strip_of_a_lifted_wrong_part_grasp_says_failed() -> None:
    from seggrasp.episode import TrialRecord
    from sim.evaluate.strips import strip_caption

    record = TrialRecord(object_id="mug_classic", category="mug", method="coarse", detector="simulated:typical",
                         prompt="handle", prompt_index=0, rank=0, seed=0, scene_seed=0, n_candidates=5,
                         executed=True, lifted=True, success=False, failure="wrong_part", message="lifted")
    assert strip_caption(record).startswith("coarse mug_classic 'handle' #0: failed: wrong_part (cell: lifted")


# ------------------------------------------------------------------------------------- hangs, unbounded work


@pytest.mark.parametrize("args, message", [
    (["--seeds", "0-200000"], "gives more than 1000 seeds"),
    (["--top-k", "100000"], "--top-k must be 1-100"),
])
@pytest.mark.slow
def test_seeds_and_top_k_are_bounded_at_once(args, message, tmp_path) -> None:
    started = time.monotonic()
    result = _evaluate(*ORACLE[:4], *args, "--out", str(tmp_path / "out"))
    assert result.returncode == 2 and message in _error(result.stderr)
    assert time.monotonic() - started < 30 and not (tmp_path / "out").exists()


def test_the_seed_bound_is_exact() -> None:
    from sim.evaluate.cli import parse_seeds
    from sim.evaluate.config import MAX_SEEDS

    assert parse_seeds(f"0-{MAX_SEEDS - 1}") == list(range(MAX_SEEDS))
    with pytest.raises(ValueError, match=f"more than {MAX_SEEDS} seeds"):
        parse_seeds(f"5,0-{MAX_SEEDS - 1}")


@pytest.mark.slow
def test_a_ray_address_with_nothing_there_ends_in_one_sentence(tmp_path) -> None:
    started = time.monotonic()
    result = _evaluate(*ORACLE, "--engine", "ray", "--address", "127.0.0.1:1", "--out", str(tmp_path / "out"))
    assert result.returncode == 2 and time.monotonic() - started < 60
    assert "cannot join the Ray cluster at 127.0.0.1:1: nothing answers" in _error(result.stderr)


def test_a_ray_address_that_accepts_and_never_answers_is_refused_within_the_deadline(monkeypatch) -> None:
    from sim.evaluate import ray_engine

    monkeypatch.setattr(ray_engine, "CONNECT_TIMEOUT", 0.5)
    with socket.create_server(("0.0.0.0", 0)) as silent:
        port = silent.getsockname()[1]
        started = time.monotonic()
        with pytest.raises(ValueError, match="accepts connections but does not answer as a Ray head"):
            ray_engine._probe(f"127.0.0.1:{port}")
    assert time.monotonic() - started < 5


@pytest.mark.slow
def test_a_ray_head_passes_the_probe() -> None:
    import ray

    from sim.evaluate.ray_engine import _probe

    ray.init(num_cpus=1, include_dashboard=False, logging_level="WARNING")
    try:
        _probe(ray.get_runtime_context().gcs_address)  # a real head's GCS answers the gRPC preface
    finally:
        ray.shutdown()


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0.0, 3.0])  # while ray.init starts the instance; once the tasks run
def test_sigterm_stops_a_ray_driver_cleanly(delay, tmp_path) -> None:
    out = tmp_path / "out"
    driver = subprocess.Popen([sys.executable, "-m", "sim.evaluate", *SMALL, "--engine", "ray", "--out", str(out)],
                              cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    ray_processes: dict[int, str] = {}
    while not ray_processes and time.monotonic() < deadline and driver.poll() is None:
        time.sleep(0.5)
        ray_processes = {pid: c for pid, c in descendants(driver.pid).items() if "raylet" in c}
    assert ray_processes, "the driver never started its Ray instance"
    ray_processes = descendants(driver.pid)
    time.sleep(delay)
    driver.send_signal(signal.SIGTERM)
    _, err = driver.communicate(timeout=60)
    assert driver.returncode == 128 + signal.SIGTERM, err
    assert "SIGTERM received" not in err and "stopped by SIGTERM; the records written so far are kept" in _error(err)
    deadline = time.monotonic() + 30
    while any(alive(pid) for pid in ray_processes) and time.monotonic() < deadline:
        time.sleep(0.5)
    left = [command for pid, command in ray_processes.items() if alive(pid)]
    assert not left, f"processes left running: {left}"


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])  # in process; a pool of worker processes
def test_ctrl_c_stops_a_run_in_one_sentence_and_it_resumes(workers, tmp_path) -> None:
    out = tmp_path / "out"
    args = [sys.executable, "-m", "sim.evaluate", *SMALL, "--seeds", "0-1", "--workers", str(workers),
            "--out", str(out)]
    # a session of its own, so that the SIGINT reaches the whole group as a terminal's Ctrl-C does
    driver = subprocess.Popen(args, cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    trials = out / "trials.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and driver.poll() is None and not (trials.exists() and trials.stat().st_size):
        time.sleep(0.05)
    assert driver.poll() is None, "the run ended before it could be stopped"
    group = descendants(driver.pid)
    os.killpg(driver.pid, signal.SIGINT)
    _, err = driver.communicate(timeout=60)
    assert driver.returncode == 128 + signal.SIGINT, err
    assert f"stopped by SIGINT; the records written so far are kept (--resume --out {out}" in _error(err)
    deadline = time.monotonic() + 30
    while any(alive(pid) for pid in group) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [command for pid, command in group.items() if alive(pid)]
    assert main([*SMALL, "--seeds", "0-1", "--out", str(out), "--resume"]) == 0
    keys = [trial_key(r) for r in _trials(out)]  # nothing lost, nothing twice
    assert len(keys) == len(set(keys)) == json.loads((out / "summary.json").read_text())["run"]["expected_trials"]


# ------------------------------------------------------------------------- storage: one sentence, nothing lost


def _storage_case(case: str, tmp_path: Path) -> tuple[list[str], str]:
    """A bad output place of kind `case`: (the arguments, what the error must name)."""
    out = tmp_path / "out"
    if case == "out is a file":
        out.write_text("")
        return ORACLE, f"--out {out} is a file"
    if case == "out under a file":
        (tmp_path / "file").write_text("")
        return ORACLE, f"{tmp_path / 'file'}"
    if case == "name too long":
        out = tmp_path / ("a" * 300)
        return ORACLE, "a name or path too long"
    out.mkdir()
    if case == ".lock is a folder":
        (out / ".lock").mkdir()
        return ORACLE, f"{out / '.lock'}: Is a directory"
    if case == "trials.jsonl is a folder":
        (out / "trials.jsonl").mkdir()
        return ORACLE, f"{out / 'trials.jsonl'} is not a regular file"
    (out / "cache").write_text("")  # the vote cache's folder
    return [*ORACLE[:2], "--methods", "coarse", *ORACLE[4:]], f"{out / 'cache'}"


@pytest.mark.parametrize("case", ["out is a file", "out under a file", "name too long", ".lock is a folder",
                                  "trials.jsonl is a folder", "cache is a file"])
def test_a_bad_output_place_is_one_sentence(case, tmp_path, capsys) -> None:
    args, named = _storage_case(case, tmp_path)
    out = tmp_path / ("a" * 300) if case == "name too long" else tmp_path / "out"
    if case == "out under a file":
        out = tmp_path / "file" / "out"
    assert main([*args, "--out", str(out)]) == 2
    assert named in _error(capsys.readouterr().err)


def _in_a_mount(tmp_path: Path, mount: str, script: str) -> subprocess.CompletedProcess:
    """Run `script` (sh) in a private mount namespace after `mount` (sh); $E is the evaluation command."""
    command = f"set -e; {mount}; set +e; {script}"
    evaluate = f"{sys.executable} -m sim.evaluate"
    return subprocess.run(["unshare", "-m", "sh", "-c", command], cwd=REPO, env=dict(_env(), E=evaluate),
                          capture_output=True, text=True, timeout=120)


@pytest.mark.slow
@AS_ROOT
def test_a_full_disk_stops_the_run_in_one_sentence_and_resume_completes_it(tmp_path) -> None:
    disk, kept = tmp_path / "disk", tmp_path / "kept"
    disk.mkdir()
    args = " ".join(ORACLE)
    result = _in_a_mount(tmp_path, f"mount -t tmpfs -o size=12k tmpfs {disk}",
                         f"$E {args} --out {disk}/run; code=$?; cp -a {disk}/run {kept}; exit $code")
    assert result.returncode == 2
    assert "No space left on device (the disk is full: free space, then --resume continues" in _error(result.stderr)
    written = _trials(kept)
    assert main([*ORACLE, "--resume", "--out", str(kept)]) == 0
    trials = _trials(kept)
    assert trials[:len(written)] == written and len({trial_key(r) for r in trials}) == len(trials) == 2


@pytest.mark.slow
@AS_ROOT
@pytest.mark.parametrize("read_only", ["the folder", "trials.jsonl"])
def test_a_read_only_output_is_one_sentence(read_only, small_run, tmp_path) -> None:
    out = _copy(small_run, tmp_path)
    lines = (out / "trials.jsonl").read_text().splitlines(keepends=True)
    (out / "trials.jsonl").write_text("".join(lines[:-1]))  # one trial to redo: the run must append
    target = out if read_only == "the folder" else out / "trials.jsonl"
    result = _in_a_mount(tmp_path, f"mount --bind {target} {target}; mount -o remount,bind,ro {target}",
                         f"$E {' '.join(SMALL)} --resume --out {out}")
    assert result.returncode == 2
    assert "Read-only file system (a read-only file system: choose another --out)" in _error(result.stderr)


# ------------------------------------------------------------------------- hand-edited records: file and line


@pytest.mark.parametrize("line, message", [
    (b"[1,2,3]", ":2: not a record: a JSON array"),
    (b'"hello"', ":2: not a record: a JSON string"),
    (b"without rank", ":2: not a record of trials.jsonl: 'rank' is missing"),
    (b"latin-1", ":2: not UTF-8 text (byte 0xe9"),
])
def test_a_hand_edited_trials_line_is_named_by_file_and_line(line, message, small_run, tmp_path, capsys) -> None:
    out = _copy(small_run, tmp_path)
    lines = (out / "trials.jsonl").read_bytes().splitlines(keepends=True)
    if line == b"without rank":
        line = json.dumps({k: v for k, v in json.loads(lines[1]).items() if k != "rank"}).encode()
    elif line == b"latin-1":
        line = lines[1].rstrip(b"\n").replace(b'"mug"', b'"mug\xe9"')
    (out / "trials.jsonl").write_bytes(lines[0] + line + b"\n" + b"".join(lines[1:]))
    assert main([*SMALL, "--resume", "--out", str(out)]) == 2
    assert f"{out / 'trials.jsonl'}{message}" in _error(capsys.readouterr().err)


@pytest.mark.parametrize("content, message", [
    (b"[1,2,3]\n", ":1: not a run record: a JSON array"),
    (b'"hello"\n', ":1: not a run record: a JSON string"),
    (b'{"methods": ["oracle"],\n "objects": ["caf\xe9"]}\n', ":2: not UTF-8 text (byte 0xe9"),
    (b'{"methods": ["oracle"], "objects": ["mug_classic"], "seeds": [0], "top_k": "one"}\n', ": 'top_k' is \"one\""),
])
def test_a_hand_edited_run_json_is_named_by_file_and_line(content, message, small_run, tmp_path, capsys) -> None:
    out = _copy(small_run, tmp_path)
    (out / "run.json").write_bytes(content)
    assert main([*SMALL, "--resume", "--out", str(out)]) == 2
    assert f"{out / 'run.json'}{message}" in _error(capsys.readouterr().err)


# ------------------------------------------------------------------------------------ a worker process dies


@pytest.mark.slow
def test_killing_one_of_two_workers_loses_no_finished_work(tmp_path) -> None:
    out = tmp_path / "out"
    args = ["--objects", "mug_classic,mug_tapered", "--methods", "oracle", "--embodiment", "floating",
            "--top-k", "2", "--prompts", "handle", "--detector", "perfect", "--workers", "2", "--out", str(out)]
    driver = subprocess.Popen([sys.executable, "-m", "sim.evaluate", *args], cwd=REPO, env=_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and driver.poll() is None and not _trials(out):
        time.sleep(0.2)
    written = _trials(out)
    workers = [pid for pid, command in descendants(driver.pid).items() if "spawn_main" in command]
    assert written and len(workers) == 2, "the run finished before a worker could be killed"
    os.kill(workers[0], signal.SIGKILL)
    _, err = driver.communicate(timeout=240)
    assert driver.returncode == 0, err
    assert "a worker process died" in err
    trials = _trials(out)
    assert all(record in trials for record in written)  # nothing finished was lost ...
    assert len({trial_key(r) for r in trials}) == len(trials) == 2 * 2  # ... or recorded twice
    assert _counts(out) == (4, 4)


# -------------------------------------------------------------------------------------------- --help's truth


def test_help_gives_every_option_a_text_and_the_true_defaults(capsys) -> None:
    from seggrasp.grasp.select import TOP_K
    from sim.evaluate.cli import parse_args

    with pytest.raises(SystemExit):
        parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--embodiment {arm,floating} twin only", "--backend {sim,real} sim, the PyBullet twin",
                   "-v, --verbose log every step", "(default: typical)", "(default: arm; --quick: floating)",
                   f"(default: {TOP_K}; --quick 3)", "default: 1)", "default: local)", "(default: sim)",
                   "With --resume, a setting not given is the recorded run's and one given must match it"):
        assert option in text, option
    defaults = parse_args([])
    assert defaults.embodiment is None and defaults.detector is None  # filled from the run (fresh or recorded)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_stopped_local_run_leaves_no_worker_behind_and_resumes_whole(sig, tmp_path) -> None:
    """Before, a SIGTERM or SIGKILL took the driver down alone: its two spawned workers ran on, orphaned, and kept
    appending records to --out."""
    out = tmp_path / "out"
    argv = ["--objects", "mug_classic,knife_chef,hammer_claw,bottle_water", *ORACLE[2:], "--workers", "2",
            "--out", str(out)]
    driver = subprocess.Popen([sys.executable, "-m", "sim.evaluate", *argv], cwd=REPO, env=_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, workers = time.monotonic() + 60, {}
    while len(workers) < 2 and time.monotonic() < deadline and driver.poll() is None:
        time.sleep(0.2)
        workers = {pid: c for pid, c in descendants(driver.pid).items() if "multiprocessing.spawn" in c}
    assert len(workers) == 2, "the driver never started its two workers"
    time.sleep(2.0)
    driver.send_signal(sig)
    _, err = driver.communicate(timeout=60)
    assert driver.returncode == (128 + sig if sig == signal.SIGTERM else -sig), err
    if sig == signal.SIGTERM:
        assert "stopped by SIGTERM; the records written so far are kept" in _error(err)
    deadline = time.monotonic() + 30
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [command for pid, command in workers.items() if alive(pid)], "workers left running"
    assert main(["--resume", "--out", str(out)]) == 0
    keys = [trial_key(t) for t in _trials(out)]
    assert len(keys) == len(set(keys)) == 4 * 2  # four objects, two prompts each, top-1: each trial once
