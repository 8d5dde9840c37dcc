"""``torch4dtree forecast RUN/model.pt SEQ --until T --out DIR``: complete a 4D tree observed over its first days.

Writes ``DIR/forecast/`` (the conditional mode at the model's time step from the last observed time to ``T``),
``DIR/forecast_NNN/`` (``--n`` conditional samples) as sequence folders and ``DIR/forecast.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from .options import UsageError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="a checkpoint written by torch4dtree fit (RUN/model.pt)")
    p.add_argument("sequence", help="the observed part: a sequence folder of frame files")
    p.add_argument("--until", type=float, required=True, help="forecast up to this time (data units)")
    p.add_argument("--steps", type=int, default=8, help="forecast times after the last observation (default 8)")
    p.add_argument("--n", type=int, default=3, help="conditional samples (default 3)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the samples (default: %(default)s)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out")


def run(args: argparse.Namespace) -> int:
    import torch

    from ..config import Config
    from ..io import read_sequence, write_sequence
    from ..io.files import write_text_safely
    from ..model import load

    model = load(args.model)
    known = {f.name for f in dataclasses.fields(Config)}
    cfg = Config(**{k: v for k, v in model.checkpoint_config.items() if k in known})
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    seq = read_sequence(Path(args.sequence), opts).sequence
    last = float(seq.times[-1])
    if not args.until > last:
        raise UsageError(f"--until {args.until} must be after the last observed time {last}")
    if args.steps < 1 or args.n < 0:
        raise UsageError("--steps must be at least 1 and --n at least 0")
    times = torch.linspace(last, args.until, args.steps + 1, dtype=torch.float64)[1:]
    f = model.forecast(seq, times, n=args.n, generator=torch.Generator().manual_seed(args.seed))
    out = Path(args.out)
    written = [str(p) for p in write_sequence(out / "forecast", f.mean, overwrite=args.overwrite)]
    for s in f.samples:
        written += [str(p) for p in write_sequence(out / s.name, s, overwrite=args.overwrite)]
    meta = {"model": args.model, "written": written, "sequence": args.sequence, "times": times.tolist(), "rate": f.rate,
            "gain": f.gain, "coefficients": f.coefficients.tolist(), "covariance": f.covariance.tolist()}
    write_text_safely(out / "forecast.json", json.dumps(meta, indent=2), overwrite=args.overwrite)
    print(f"forecast of {seq.name} from t = {last:.4g} to {args.until:.4g} in {out} (time rate {f.rate:.2f}, "
          f"gain {f.gain:.2f})")
    return 0
