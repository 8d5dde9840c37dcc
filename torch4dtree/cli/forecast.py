"""``torch4dtree forecast RUN/model.pt SEQ --until T --out DIR``: complete a 4D tree observed over its first days.

With the paper's model: ``DIR/forecast/`` (the conditional mode at ``--steps`` times from the last observed time to
``T``) and ``DIR/forecast_NNN/`` (``--n`` conditional samples). With the organ model
(:func:`~torch4dtree.model.forecast_organs`), which has no conditional mode and grows plants at its own ages (the
training plants' frames): ``1 + --n`` continuations at those ages up to ``T``, the first as ``DIR/forecast/``, the
others as ``DIR/forecast_NNN/``. Both write sequence folders and ``DIR/forecast.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING

from .options import UsageError

if TYPE_CHECKING:
    import torch

    from ..model import OrganModel
    from ..trees import TreeSequence

STEPS = 8  # the paper's model: forecast times after the last observation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="a checkpoint written by torch4dtree fit (RUN/model.pt)")
    p.add_argument("sequence", help="the observed part: a sequence folder of frame files")
    p.add_argument("--until", type=float, required=True, help="forecast up to this time (data units)")
    p.add_argument("--steps", type=int, default=None,
                   help=f"forecast times after the last observation (default {STEPS}; the paper's model only)")
    p.add_argument("--n", type=int, default=3, help="conditional samples (default 3)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the samples (default: %(default)s)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out")


def run(args: argparse.Namespace) -> int:
    import torch

    from ..config import Config
    from ..io import read_sequence, write_sequence
    from ..io.files import write_text_safely
    from ..model import OrganModel, load

    model = load(args.model)
    known = {f.name for f in dataclasses.fields(Config)}
    cfg = Config(**{k: v for k, v in model.checkpoint_config.items() if k in known})
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    seq = read_sequence(Path(args.sequence), opts).sequence
    last = float(seq.times[-1])
    if not args.until > last:
        raise UsageError(f"--until {args.until} must be after the last observed time {last}")
    if args.n < 0:
        raise UsageError("--n must be at least 0")
    out = Path(args.out)
    generator = torch.Generator().manual_seed(args.seed)
    if isinstance(model, OrganModel):
        return _forecast_organs(model, seq, args, out, generator)
    steps = STEPS if args.steps is None else args.steps
    if steps < 1:
        raise UsageError("--steps must be at least 1")
    times = torch.linspace(last, args.until, steps + 1, dtype=torch.float64)[1:]
    f = model.forecast(seq, times, n=args.n, generator=generator)
    written = [str(p) for p in write_sequence(out / "forecast", f.mean, overwrite=args.overwrite)]
    for s in f.samples:
        written += [str(p) for p in write_sequence(out / s.name, s, overwrite=args.overwrite)]
    meta = {"model": args.model, "kind": "paper", "written": written, "sequence": args.sequence,
            "times": times.tolist(), "rate": f.rate, "gain": f.gain, "coefficients": f.coefficients.tolist(),
            "covariance": f.covariance.tolist()}
    write_text_safely(out / "forecast.json", json.dumps(meta, indent=2), overwrite=args.overwrite)
    print(f"forecast of {seq.name} from t = {last:.4g} to {args.until:.4g} in {out} (time rate {f.rate:.2f}, "
          f"gain {f.gain:.2f})")
    return 0


def _forecast_organs(model: OrganModel, seq: TreeSequence, args: argparse.Namespace, out: Path,
                     generator: torch.Generator) -> int:
    """The organ model's forecast (module doc): ``1 + --n`` continuations at its ages in ``(last, --until]``."""
    from ..io import write_sequence
    from ..io.files import write_text_safely
    from ..model import forecast_organs

    if args.steps is not None:
        raise UsageError("--steps: the organ model has no time step to set; it forecasts at its own ages (the "
                         "training plants' frames)")
    last, end = float(seq.times[-1]), float(model.times()[-1])
    if not end > last:
        raise UsageError(f"{seq.name} is observed up to t = {last:.4g}, at or after the organ model's last age "
                         f"t = {end:.4g}: the organ model grows no plant beyond its training plants' span")
    futures = forecast_organs(model, seq, n=1 + args.n, generator=generator)
    keep = [j for j, t in enumerate(futures[0].times.tolist()) if t <= args.until]
    if not keep:
        raise UsageError(f"--until {args.until}: the organ model's first age after t = {last:.4g} is "
                         f"t = {float(futures[0].times[0]):.4g} (it grows plants only at its ages, the training "
                         f"plants' frames)")
    written: list[str] = []
    names = []
    for i, f in enumerate(futures):
        name = "forecast" if i == 0 else f.name
        names.append(name)
        written += [str(p) for p in write_sequence(out / name, f[keep], overwrite=args.overwrite)]
    times = futures[0].times[keep].tolist()
    meta = {"model": args.model, "kind": "organs", "written": written, "sequence": args.sequence, "times": times,
            "until": args.until, "seed": args.seed, "continuations": names,
            "note": "the organ model has no conditional mode: forecast/ is the first continuation drawn, "
                    "forecast_NNN/ the others; times are the model's ages after the last observed time, up to "
                    "--until (its last age at most)"}
    write_text_safely(out / "forecast.json", json.dumps(meta, indent=2), overwrite=args.overwrite)
    print(f"forecast of {seq.name} from t = {last:.4g} to {times[-1]:.4g} in {out} ({len(futures)} continuations "
          f"by the organ model at its ages; it grows no plant beyond t = {end:.4g})")
    return 0
