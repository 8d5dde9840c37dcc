"""``torch4dtree register4d SEQ_A SEQ_B``: register two 4D trees (sequence folders) in space and time.

Prints the 4D distance before registration, after the spatial and after the temporal registration, and the
time warp; writes the registered 4D trees and the 4D geodesic as sequence folders (``--out``) and a grid picture
or video of the geodesic (``--image``: rows = steps along the geodesic, columns = time).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from .options import (
    UsageError,
    add_config_arguments,
    add_executor_arguments,
    check_output_file,
    config_from_args,
    executor_from_args,
    int_at_least,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("reference", help="4D tree A: a sequence folder of .swc or .mat frames (missing days allowed)")
    p.add_argument("moving", help="4D tree B: a sequence folder, registered onto A")
    add_config_arguments(p, registration=True)
    p.add_argument("--n-t", type=int_at_least(2), default=32, metavar="N",
                   help="common time samples of the trajectories (default: %(default)s)")
    p.add_argument("--steps", type=int_at_least(2), default=5, metavar="N",
                   help="4D trees along the geodesic for --out / --image (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write the registered 4D trees and the geodesic as sequence folders into this folder (created "
                        "if missing; its parent must exist) (default: nothing written)")
    p.add_argument("--image", default=None, metavar="FILE",
                   help="the 4D geodesic as a grid picture (.png) or video (.gif, .mp4); its folder must exist "
                        "(default: none)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out / --image")
    add_executor_arguments(p)


def _read(folder: str, options: object) -> object:
    from ..io import read_sequence

    path = Path(folder)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such folder")
    if not path.is_dir():
        raise UsageError(f"{path} is a file; register4d takes two sequence folders (one frame file per time)")
    return read_sequence(path, options).sequence


def run(args: argparse.Namespace) -> int:
    import torch  # here, not at import: building the parser (--help) must not import torch

    from ..io import write_sequence
    from ..render import IMAGE_SUFFIXES, VIDEO_SUFFIXES
    from ..temporal import register4d

    image = check_output_file(Path(args.image), args.overwrite, IMAGE_SUFFIXES + VIDEO_SUFFIXES, "--image") \
        if args.image else None  # fail before the work
    if args.out and not Path(args.out).parent.is_dir():
        raise UsageError(f"--out {args.out}: the folder {Path(args.out).parent} does not exist (create it first)")
    cfg = config_from_args(args)
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    a, b = _read(args.reference, opts), _read(args.moving, opts)
    with executor_from_args(args) as executor:
        t0 = time.perf_counter()
        res = register4d(a, b, lambdas=cfg.lambdas, rotation=cfg.rotation, n_t=args.n_t,
                         registration=cfg.registration_settings(), cross=cfg.cross_settings(), executor=executor)
    seconds = time.perf_counter() - t0
    written: list[str] = []
    path = res.geodesic(args.steps) if (args.out or image) else []
    if args.out:
        out = Path(args.out)
        ref_seq, mov_seq, mov_reg = res.decoded()
        note = f"torch4dtree register4d {args.reference} {args.moving}; branch type = common slot"
        folders = [("A", ref_seq), ("B", mov_seq), ("B_time_warped", mov_reg)]
        folders += [(f"geodesic_{k:02d}", s) for k, s in enumerate(path)]
        for name, seq in folders:
            written += [str(p) for p in write_sequence(out / name, seq, overwrite=args.overwrite, comment=note)]
    if image is not None:
        from ..render import render_grid, save_image, save_video

        rows = [f"tau = {k / (args.steps - 1):.2f}" for k in range(args.steps)]
        title = (f"{Path(args.reference).name}  ->  {Path(args.moving).name}\n4D distance "
                 f"{res.distance_before:.3g} (before)  ->  {res.distance_after_spatial:.3g} (space)  ->  "
                 f"{res.distance_after_temporal:.3g} (time)")
        if image.suffix.lower() in VIDEO_SUFFIXES:
            frames = render_grid(path, row_labels=rows, title=title, video=True, color="label")
            written.append(str(save_video(image, frames, fps=8, overwrite=args.overwrite)))
        else:
            cols = [f"t = {t:.3g}" for t in path[0].times.tolist()[:: max(1, len(path[0]) // 8)]]
            sub = [s[list(range(0, len(s), max(1, len(s) // 8)))] for s in path]
            img = render_grid(sub, row_labels=rows, col_labels=cols, title=title, color="label")
            written.append(str(save_image(image, img, overwrite=args.overwrite)))
    summary = {
        "distance_before": res.distance_before, "distance_after_spatial": res.distance_after_spatial,
        "distance_after_temporal": res.distance_after_temporal, "warp": [float(x) for x in res.warp],
        "seconds": seconds, "stage_seconds": res.seconds, "frames": [len(a), len(b)],
        "slots": res.layout.num_slots, "components": res.pca.n_components_,
        "kept_index_order": res.kept_index_order, "spatial_candidate": res.spatial_candidate, "written": written,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"A {args.reference}: {len(a)} frames; B {args.moving}: {len(b)} frames; {res.layout.num_slots} slots, "
              f"{res.pca.n_components_} components")
        print(f"4D distance before registration:    {res.distance_before:.6g}")
        print(f"after spatial registration:         {res.distance_after_spatial:.6g}")
        print(f"after temporal registration:        {res.distance_after_temporal:.6g}   ({seconds:.2f} s)")
        print("time warp of B (every 4th of n_t): " + " ".join(f"{float(x):.3f}" for x in res.warp[::4]))
        for p in written:
            print(f"wrote {p}")
    return 0
