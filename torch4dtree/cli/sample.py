"""``torch4dtree sample RUN/model.pt --n N --seed S --out DIR``: generate 4D trees from a fitted model.

Either model (:func:`torch4dtree.model.load` rebuilds the one the checkpoint holds). Writes ``DIR/sample_NNN/``
sequence folders (SWC frames + times; branch type = the paper model's layout slot, or the organ model's botanical
key index), one video per sample (``DIR/sample_NNN.gif``) and a grid video ``DIR/grid.gif`` (one cell per sample,
animated over time), and ``DIR/samples.json`` (the coefficients: the paper model's mode coefficients, the organ
model's one seed per plant).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .options import UsageError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="a checkpoint written by torch4dtree fit (RUN/model.pt)")
    p.add_argument("--n", type=int, default=4, help="number of 4D trees (default 4)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--video", default="gif", choices=("gif", "mp4", "none"), help="video format (default gif)")
    p.add_argument("--size", type=int, default=None, help="pixels per video cell (default: the run's render_size)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out")


def run(args: argparse.Namespace) -> int:
    import torch

    from ..io import write_sequence
    from ..io.files import write_text_safely
    from ..model import load

    if args.n < 1:
        raise UsageError(f"--n must be at least 1, got {args.n}")
    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise FileExistsError(f"{out} exists and is not empty; pass --overwrite to replace its files")
    model = load(args.model)
    size = args.size or int(getattr(model, "checkpoint_config", {}).get("render_size", 256))
    t0 = time.perf_counter()
    z = model.sample_coefficients(args.n, torch.Generator().manual_seed(args.seed))
    samples = model.decode(z)
    seconds = time.perf_counter() - t0
    written: list[str] = []
    for s in samples:
        written += [str(p) for p in write_sequence(out / s.name, s, overwrite=args.overwrite,
                                                   comment=f"torch4dtree sample {args.model} seed {args.seed}")]
    if args.video != "none":
        from ..render import render_grid, render_sequence, save_video

        for s in samples:
            frames = render_sequence(s, size=size, color="label", caption=True)
            written.append(str(save_video(out / f"{s.name}.{args.video}", frames, fps=8, overwrite=args.overwrite)))
        grid = render_grid(samples, row_labels=[s.name for s in samples], video=True, size=size, color="label",
                           title=f"{args.n} samples, seed {args.seed}")
        written.append(str(save_video(out / f"grid.{args.video}", grid, fps=8, overwrite=args.overwrite)))
    meta = {"model": str(args.model), "seed": args.seed, "n": args.n, "coefficients": z.tolist(),
            "c": float(model.settings.c), "decode_seconds": seconds, "names": [s.name for s in samples]}
    written.append(str(write_text_safely(out / "samples.json", json.dumps(meta, indent=2), overwrite=args.overwrite)))
    print(f"{args.n} samples in {out} ({seconds:.2f} s to sample and decode)")
    for s in samples:
        print(f"  {out / s.name}")
    if args.video != "none":
        print(f"  grid video: {out / ('grid.' + args.video)}")
    return 0
