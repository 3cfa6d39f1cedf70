"""`python -m assets list|generate|gallery|decompose`: the SegGraspSet twin's command line."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

from assets.generate import ASSETS_DIR, generate_set
from seggrasp.arguments import bounded_int
from seggrasp.decompose.config import MAX_SEED
from seggrasp.objects import asset_ids, load_asset, load_asset_set

GALLERY_PATH = ASSETS_DIR / "gallery.png"


def _list(args: argparse.Namespace) -> int:
    models = [load_asset(i) for i in asset_ids(args.category)]
    print(f"{'id':24s} {'category':12s} {'prompts':22s} {'mass kg':>8s} {'mu':>5s} {'size mm':>18s} "
          f"{'faces':>6s} {'hulls':>5s}")
    for m in models:
        size = "x".join(f"{d * 1000:.0f}" for d in m.mesh.extents)
        print(f"{m.object_id:24s} {m.category:12s} {','.join(m.prompts):22s} {m.mass:8.3f} {m.friction:5.2f} "
              f"{size:>18s} {len(m.mesh.faces):6d} {len(m.collision_hulls):5d}")
    print(f"{len(models)} objects in {len({m.category for m in models})} categories")
    return 0


def _generate(args: argparse.Namespace) -> int:
    manifest = generate_set(seed=args.seed, object_ids=args.only or None, root=args.root,
                            collision=not args.no_collision)
    count = len(args.only) if args.only else len(manifest["objects"])
    print(f"generated {count} objects (seed {args.seed}); {args.root / 'manifest.json'} lists {len(manifest['objects'])}")
    return 0


def _gallery(args: argparse.Namespace) -> int:
    from assets.gallery import gallery_png

    path = gallery_png(load_asset_set(args.category), args.out, columns=args.columns)
    print(f"wrote {path}")
    return 0


def precompute_decompositions(mode: str = "fast", seed: int = 0, workers: int | None = None,
                              only: list[str] | None = None, force: bool = False) -> list[str]:
    """Fill assets/decompositions/ with the decomposition sweeps of the twin's objects (the bundled warm cache);
    one line per object. Each object's mesh is decomposed as the benchmark reads it (the file's faces) and, where
    repairing it changes it (degenerate or duplicate faces), as `python -m seggrasp segment` reads it (the working
    mesh of `seggrasp.mesh.prepare_mesh`). Runs already there are kept, unless `force`: then every run is recomputed
    (into a temporary folder, so an interrupted run leaves the old entries) and replaces the object's entries for
    `mode` and `seed`."""
    from seggrasp.decompose import ASSET_CACHE_DIR, DecompositionConfig, decompose_sweep, mesh_hash
    from seggrasp.decompose.sweep import sweep_cache_keys
    from seggrasp.mesh import prepare_mesh

    config = DecompositionConfig(mode=mode, seed=seed)
    done = []
    for model in load_asset_set() if not only else [load_asset(i) for i in only]:
        started = time.perf_counter()
        working = prepare_mesh(model.mesh.vertices, model.mesh.faces, name=model.object_id).mesh
        meshes = [model.mesh] + ([working] if mesh_hash(working) != mesh_hash(model.mesh) else [])
        for mesh in meshes:
            if force:
                with tempfile.TemporaryDirectory(prefix="decompose-", dir=ASSET_CACHE_DIR) as fresh:
                    partitions = decompose_sweep(mesh, config, cache_dir=fresh, workers=workers, bundled=False)
                    for key in sweep_cache_keys(mesh, config):
                        (ASSET_CACHE_DIR / f"{key}.npz").unlink(missing_ok=True)
                    for entry in Path(fresh).glob("*.npz"):
                        os.replace(entry, ASSET_CACHE_DIR / entry.name)
            else:
                partitions = decompose_sweep(mesh, config, cache_dir=ASSET_CACHE_DIR, workers=workers)
            done.append(f"{model.object_id}{'' if mesh is model.mesh else ' (working mesh)'}: {len(mesh.faces)} "
                        f"faces, {len(partitions)} distinct partitions, {time.perf_counter() - started:.1f} s")
    return done


def _decompose(args: argparse.Namespace) -> int:
    logging.getLogger("seggrasp").setLevel(logging.INFO)  # progress of the sweeps
    for line in precompute_decompositions(args.mode, args.seed, args.workers, args.only, args.force):
        print(line, flush=True)
    return 0


#: Columns of the gallery picture.
MAX_COLUMNS = 36


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    parser = argparse.ArgumentParser(prog="python -m assets", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_list = sub.add_parser("list", help="list the objects of the twin")
    p_list.add_argument("--category", action="append", help="only this category (repeatable)")
    p_gen = sub.add_parser("generate", help="regenerate meshes, labels, collision models, URDFs and the manifest")
    p_gen.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0,
                       help="shape jitter seed (0 = the committed set)")
    p_gen.add_argument("--only", action="append", metavar="ID", help="regenerate only this object (repeatable)")
    p_gen.add_argument("--no-collision", action="store_true", help="keep the existing collision.obj (skip CoACD)")
    p_gen.add_argument("--root", type=Path, default=ASSETS_DIR, help="output folder (default: the committed set)")
    p_gal = sub.add_parser("gallery", help="render all objects coloured by part into a PNG")
    p_gal.add_argument("--out", type=Path, default=GALLERY_PATH)
    p_gal.add_argument("--columns", type=bounded_int(1, MAX_COLUMNS), default=6,
                       help=f"objects per row, 1..{MAX_COLUMNS} (default 6)")
    p_gal.add_argument("--category", action="append", help="only this category (repeatable)")
    p_dec = sub.add_parser("decompose", help="precompute the decomposition sweeps of the twin into "
                                             "assets/decompositions/ (the bundled warm cache)")
    p_dec.add_argument("--mode", choices=("fast", "reference"), default="fast", help="sweep mode (default fast)")
    p_dec.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0,
                       help="CoACD seed (default 0, the default seed of `python -m seggrasp segment`, which reads "
                            "these entries)")
    p_dec.add_argument("--workers", type=bounded_int(1, 256),
                       help="parallel CoACD processes (default: the CPU count)")
    p_dec.add_argument("--only", action="append", metavar="ID", help="only this object (repeatable)")
    p_dec.add_argument("--force", action="store_true",
                       help="recompute every run and replace the object's entries (without it, runs already in "
                            "assets/decompositions/ are kept and the command only adds missing ones)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    handlers = {"list": _list, "generate": _generate, "gallery": _gallery, "decompose": _decompose}
    try:
        return handlers[args.command](args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
