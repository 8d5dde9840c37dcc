"""Forecast against its baselines on held-out synthetic plants, over dataset seeds.

Setting of ``tests/test_model.py::test_forecast_beats_baselines``: ``synthetic_dataset(kind, plants=12, seed=s,
n_frames=6, T=16)``, fit ``FourDTreeModel(n_t=16)`` on the first 7 plants, forecast the last 5 from their first
half; error = mean over the later frames of the distance in tree-PCA coordinates to the whole-sequence encoding.

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_forecast.py --kinds tomato maize --seeds 3 4 5 6 7 8

``--plants 20`` holds out 13 plants instead of 5 (the same 7 fit: plant ``i`` of a dataset does not depend on the
count), for a less noisy margin.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from torch4dtree.data import synthetic_dataset
from torch4dtree.model import FourDTreeModel
from torch4dtree.settings import ModelSettings
from torch4dtree.temporal.registration import time_warp_trajectory


def run(kind: str, seed: int, plants: int = 12) -> dict[str, Any]:
    """Fit on the first 7 plants, forecast the others; their forecast / baseline errors (summed over plants)."""
    seqs = [p.sequence for p in synthetic_dataset(kind, plants=plants, seed=seed, n_frames=6, T=16)]
    t0 = time.perf_counter()
    m = FourDTreeModel(ModelSettings(n_t=16)).fit(seqs[:7])
    fit_s = time.perf_counter() - t0
    errs = {"forecast": 0.0, "last": 0.0, "mean": 0.0}
    for h in seqs[7:]:
        half = len(h) // 2
        truth = m.population.transform(h).frame_coefficients[half:]
        prefix = m.population.transform(h[list(range(half))]).frame_coefficients
        f = m.forecast(h[list(range(half))], h.times[half:], decode=False)
        u = ((h.times[half:] - h.times[0]) / float(m.duration)).clamp(0, 1)
        pop = time_warp_trajectory(m.mean.trajectory, u.to(m.mean.trajectory))
        for key, x in (("forecast", f.trajectory), ("last", prefix[-1][None]), ("mean", pop)):
            errs[key] += float((x - truth).norm(dim=-1).mean())
    return {"kind": kind, "seed": seed, "errors": errs, "fit_seconds": fit_s, "report": m.report_["forecast"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kinds", nargs="+", default=["tomato", "maize"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[3, 4, 5, 6, 7, 8])
    ap.add_argument("--plants", type=int, default=12, help="7 fit, the rest held out (the test: 12)")
    args = ap.parse_args()
    for kind in args.kinds:
        wins, margins = 0, []
        for seed in args.seeds:
            r = run(kind, seed, args.plants)
            e = r["errors"]
            base = min(e["last"], e["mean"])
            wins += e["forecast"] < base
            margins.append(1 - e["forecast"] / base)
            print(f"{kind} seed {seed}: forecast {e['forecast']:.1f}  mean {e['mean']:.1f}  last {e['last']:.1f}"
                  f"  margin {100 * margins[-1]:+.1f} %  (fit {r['fit_seconds']:.1f} s; gain shrink "
                  f"{r['report']['shrink']}, analogue {r['report'].get('analogue', 0.0)})", flush=True)
        print(f"{kind}: wins {wins} / {len(args.seeds)}, mean margin {100 * sum(margins) / len(margins):+.1f} %")


if __name__ == "__main__":
    main()
