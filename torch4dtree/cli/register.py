"""``torch4dtree register A B``: register two tree files, print distances and the correspondence, write a
geodesic (SWC) and a picture or animation of it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config import Config
from ..settings import POSITIONS
from .options import UsageError, add_config_arguments, check_output_file, config_from_args, int_at_least

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".mp4")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``torch4dtree register A B``: register tree file A (moving) onto B (reference)."""
    parser.add_argument("moving", type=Path, help="tree file A (.swc or reference .mat), registered onto B")
    parser.add_argument("reference", type=Path, help="tree file B (.swc or reference .mat)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="write the registered pair and the geodesic as SWC files into this folder (created if "
                             "missing; its parent must exist) (default: nothing written)")
    parser.add_argument("--steps", type=int_at_least(2), default=5, metavar="N",
                        help="trees on the geodesic, both ends included, for --out and --image (default: %(default)s)")
    parser.add_argument("--image", type=Path, default=None, metavar="FILE",
                        help="picture of the geodesic (.png, .jpg) or its animation (.gif, .mp4), matched branches "
                             "in one colour; needs the render extra (default: none)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files in --out / --image")
    add_config_arguments(parser, registration=True)
    parser.add_argument("--positions", choices=POSITIONS, default=None,
                        help=f"how children's places on their parents are compared (default: {Config.positions}: "
                             "node rank along the main branch; warped: the paper's parameter after the parent's warp, "
                             "the layout's own metric; arclength: arc length from the parent's base)")


def _check_tree_file(path: Path) -> None:
    if path.is_dir():
        raise UsageError(f"{path} is a folder; register takes two tree files (.swc or .mat), e.g. two frames of a "
                         f"sequence folder")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")


def _check_outputs(args: argparse.Namespace) -> list[Path]:
    """Fail before registering if an output cannot be written; returns the SWC paths of ``--out``."""
    if args.image is not None:
        check_output_file(args.image, args.overwrite, IMAGE_SUFFIXES, "--image")
    if args.out is None:
        return []
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a folder")
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: the folder {out.parent} does not exist (create it first)")
    names = ["moving_registered.swc", "reference.swc"] + [f"geodesic_{k:02d}.swc" for k in range(args.steps)]
    targets = [out / n for n in names]
    existing = [str(p) for p in targets if p.exists()]
    if existing and not args.overwrite:  # check all first: never leave a half-written set
        raise FileExistsError(f"{', '.join(existing)} exist(s); pass --overwrite to replace")
    return targets


def _title(args: argparse.Namespace, res: Any) -> str:
    return (f"{args.moving.stem}  ->  {args.reference.stem}\n"
            f"distance {float(res.distance_before):.3g} (index order)  ->  {float(res.distance):.3g} (registered)")


def _save_correspondence_picture(res: Any, args: argparse.Namespace) -> Path:
    """The geodesic from the registered moving tree to the reference, a branch's colour = its common slot, so
    matched branches share a colour along the path (a row of trees, or an animation for .gif / .mp4)."""
    from ..render import VIDEO_SUFFIXES, fit_size, render_grid, save_image, save_video
    from ..trees.geodesic import geodesic

    image: Path = args.image
    if image.suffix.lower() in VIDEO_SUFFIXES:
        # a smooth morph: 2 s there, at 12 frames per second, whatever --steps is
        n = 24
        path = geodesic(res, n)
        labels = [f"geodesic t = {k / (n - 1):.2f}" for k in range(n)]
        frames = render_grid([path], video=True, title=_title(args, res), color="label", size=fit_size([path], 640),
                             frame_labels=labels)
        return save_video(image, frames, fps=12, overwrite=args.overwrite)
    steps = args.steps
    path = geodesic(res, steps)
    cols = ["moving (registered)"] + [f"t = {k / (steps - 1):.2f}" for k in range(1, steps - 1)] + ["reference"]
    picture = render_grid([path], col_labels=cols, title=_title(args, res), color="label", size=fit_size([path], 384))
    return save_image(image, picture, overwrite=args.overwrite)


def run(args: argparse.Namespace) -> int:
    """Run ``torch4dtree register``; returns the exit code (files are never overwritten without --overwrite)."""
    import dataclasses
    import json
    import time

    import torch

    from ..curves.dp_numba import warm_up
    from ..io import read_tree, write_swc
    from ..trees.geodesic import geodesic
    from ..trees.registration import register_trees

    for path in (args.moving, args.reference):
        _check_tree_file(path)
    targets = _check_outputs(args)
    cfg = config_from_args(args)
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    trees = []
    for path in (args.moving, args.reference):
        tree = read_tree(path, opts)
        if tree is None:
            raise UsageError(f"{path}: empty frame (no tree in this file)")
        trees.append(tree)
    moving, reference = trees
    warm_up()  # a cold compile happens here, with its notice, and stays out of the timing
    t0 = time.perf_counter()
    res = register_trees(moving, reference, lambdas=cfg.lambdas, rotation=cfg.rotation,
                         neighbourhood=cfg.neighbourhood, positions=cfg.positions)
    seconds = time.perf_counter() - t0
    written: list[str] = []
    if args.image is not None:
        written.append(str(_save_correspondence_picture(res, args)))
    if targets:
        args.out.mkdir(exist_ok=True)
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
