"""``torch4dtree register A B``: register two tree files, print distances and the correspondence, write a
geodesic (SWC) and a picture or animation of it."""

from __future__ import annotations

import argparse
import dataclasses

import torch

from ..config import add_config_arguments, config_from_args
from ..trees.geodesic import geodesic
from ..trees.registration import TreeRegistration, register_trees


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``torch4dtree register A B``: register tree file A (moving) onto B (reference)."""
    parser.add_argument("moving", help="tree file A (.swc or reference .mat), registered onto B")
    parser.add_argument("reference", help="tree file B (.swc or reference .mat)")
    add_config_arguments(parser, registration=True)
    parser.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    parser.add_argument("--out", default=None, help="folder for the registered pair and a geodesic as SWC files")
    parser.add_argument("--steps", type=int, default=5, help="trees on the geodesic written with --out (default 5)")
    parser.add_argument("--image", default=None,
                        help="picture of the geodesic (.png, .jpg) or its animation (.gif, .mp4), matched branches "
                             "in one colour (needs the render extra)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files in --out / --image")


def _save_correspondence_picture(res: TreeRegistration, args: argparse.Namespace) -> object:
    """The geodesic from the registered moving tree to the reference, a branch's colour = its common slot, so
    matched branches share a colour along the path (a row of trees, or an animation for .gif / .mp4)."""
    from pathlib import Path

    from ..render import VIDEO_SUFFIXES, render_grid, save_image, save_video

    image = Path(args.image)
    if image.exists() and not args.overwrite:  # fail before rendering
        raise FileExistsError(f"{image} exists; pass --overwrite to replace it")
    steps = max(args.steps, 2)
    path = geodesic(res, steps)
    title = (f"{Path(args.moving).stem} -> {Path(args.reference).stem}: distance {float(res.distance_before):.3g} "
             f"-> {float(res.distance):.3g}")
    if image.suffix.lower() in VIDEO_SUFFIXES:
        frames = render_grid([path], video=True, n_frames=4 * steps, title=title, color="label")
        return save_video(image, frames, fps=8, overwrite=args.overwrite)
    cols = ["moving (registered)"] + [f"t = {k / (steps - 1):.2f}" for k in range(1, steps - 1)] + ["reference"]
    return save_image(image, render_grid([path], col_labels=cols, title=title, color="label"), overwrite=args.overwrite)


def run(args: argparse.Namespace) -> int:
    """Run ``torch4dtree register``; returns the exit code (files are never overwritten without --overwrite)."""
    import json
    import time
    from pathlib import Path

    from ..io import read_tree, write_swc

    cfg = config_from_args(args)
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    trees = []
    for path in (args.moving, args.reference):
        tree = read_tree(path, opts)
        if tree is None:
            raise FileNotFoundError(f"{path}: empty frame (no tree in this file)")
        trees.append(tree)
    moving, reference = trees
    t0 = time.perf_counter()
    res = register_trees(moving, reference, lambdas=cfg.lambdas, rotation=cfg.rotation,
                         neighbourhood=cfg.neighbourhood)
    seconds = time.perf_counter() - t0
    written: list[str] = []
    if args.image:
        written.append(str(_save_correspondence_picture(res, args)))
    if args.out:
        out = Path(args.out)
        names = ["moving_registered.swc", "reference.swc"] + [f"geodesic_{k:02d}.swc" for k in range(args.steps)]
        targets = [out / n for n in names]
        existing = [str(p) for p in targets if p.exists()]
        if existing and not args.overwrite:  # check all first: never leave a half-written set
            raise FileExistsError(f"{', '.join(existing)} exist(s); pass --overwrite to replace")
        pair = res.aligned.to_trees()
        path_trees = geodesic(res, args.steps).split()
        note = f"torch4dtree register {args.moving} {args.reference}; branch type = common slot index"
        for p, tree in zip(targets, pair.split() + path_trees):
            written.append(str(write_swc(p, tree, overwrite=args.overwrite, comment=note)))
    summary = {
        "distance_before": float(res.distance_before), "distance_after": float(res.distance),
        "matches": [list(m) for m in res.matches], "unmatched_moving": res.unmatched_moving,
        "unmatched_reference": res.unmatched_reference, "rotation": res.rotation.tolist(),
        "used_index_order": res.used_index_order, "seconds": seconds, "written": written,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"moving    {args.moving}: {int(moving.num_branches[0])} branches")
        print(f"reference {args.reference}: {int(reference.num_branches[0])} branches")
        print(f"distance before (index order): {summary['distance_before']:.6g}")
        print(f"distance after registration:   {summary['distance_after']:.6g}   ({seconds * 1e3:.1f} ms)")
        print("matches (moving -> reference): " + ", ".join(f"{i}->{j}" for i, j in res.matches))
        print(f"unmatched moving: {res.unmatched_moving}  unmatched reference: {res.unmatched_reference}")
        for p in written:
            print(f"wrote {p}")
    return 0
