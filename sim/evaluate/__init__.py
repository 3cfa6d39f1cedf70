"""`python -m sim.evaluate`: the benchmark on the bundled twin (or a real cell) — segmentation, part selection and
grasp success per method, as the paper's Tables I-III.

For each (object, seed) the runner (runner.py) hands the cell, the detector and the ground truth to one
`seggrasp.episode.Episode`: segment once per method (coarse votes and decompositions shared), sample grasps once,
and for each prompt execute the method's top-k grasps on the selected part, each from a fresh reset of the same
scene. The seed redraws the detector's errors, the scene and the grasps (CoACD keeps config.DECOMPOSITION_SEED).
Tasks run in local processes or as Ray tasks (ray_engine.py, whose driver alone writes the records and ships each
object once through the object store, twin.py). Outputs in `--out` (records.py; the folder is locked while a run
writes it):

- `trials.jsonl`       one JSON line per trial (appended, flushed and fsynced; a torn last line left by a killed run
                       is dropped on `--resume`, trials already recorded are skipped, duplicates ignored);
- `segmentations.jsonl` one line per (object, seed, method): mIoU (area and face count) and per-part IoU;
- `curves.jsonl`       one line per (object, seed): GeoSpreading vs GeoFusion mIoU over the decomposition thresholds;
- `cache/`             coarse votes per object, keyed by mesh, prompts and detector (a resumed run reuses them);
- `summary.json`, `summary.md`, `plots/*.png` (report.py with the intervals of stats.py, plots.py).

A failed grasp is data; an exception while evaluating an object is a crash: the other tasks go on, the summary
is written, and the exit code is 1. Options: cli.py. `python -m sim.evaluate.bench` times the engines (bench.py).
"""

from sim.evaluate.cli import build_config, main, parse_args, run
from sim.evaluate.config import RunConfig, scene_seed_of
from sim.evaluate.records import JsonLines, OutputLock, VoteCache
from sim.evaluate.report import markdown_report, summarise, write_summary
from sim.evaluate.runner import run_object, subject_of

__all__ = [
    "JsonLines", "OutputLock", "RunConfig", "VoteCache", "build_config", "main", "markdown_report", "parse_args",
    "run", "run_object", "scene_seed_of", "subject_of", "summarise", "write_summary",
]
