"""Does the organ model's forecast beat "the last observed frame stays" and the population mean? Per held-out plant.

usage: python benchmarks/bench_forecast_organs.py TRAIN_DIR HELDOUT_DIR [--n 10] [--seed 0] [--T 32]
                                                  [--model CHECKPOINT] [--json OUT.json]

Fits :class:`torch4dtree.model.OrganModel` on the sequence folders of TRAIN_DIR (or loads ``--model``), observes
each held-out plant over its first half (``n // 2`` frames) and forecasts the rest (``--n`` continuations,
:func:`torch4dtree.model.forecast_organs`). Measure, per plant, of the **final frame**: the five morphometrics of
:mod:`torch4dtree.evaluate.morphometrics` (total length, height, spread, tips, branch points), ``log1p`` and divided
by the training plants' standard deviation at their final frame; the error is the Euclidean distance to the truth's.
The forecast's point is the feature-wise median of its continuations' final frames. Baselines:

* **last**: the last observed frame stays (its features);
* **mean**: the population's mean plant at the final age, the training plants' feature-wise median of their final
  frames (the organ model has no decoded mean plant: a median by feature is the best constant guess per feature).

Prints, per plant and overall, the errors and the share of held-out plants where the forecast is closer than each
baseline (strictly), and the median relative error of the final total length of each.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from torch4dtree.evaluate.morphometrics import FEATURES, tree_features
from torch4dtree.io import read_dataset
from torch4dtree.io.dataset import LoadOptions
from torch4dtree.model import load
from torch4dtree.model.organ_forecast import forecast_organs
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence


def final_features(seq: TreeSequence) -> np.ndarray:
    """``(F,)`` morphometrics of a 4D tree's last frame."""
    return tree_features(seq.frames[[len(seq) - 1]])


def forecast_scores(model: OrganModel, train: list[TreeSequence], held: list[TreeSequence], n: int = 10,
                    seed: int = 0) -> dict:
    """Per held-out plant, the final frame's standardised morphometric error of the forecast and of both baselines
    (module doc); returns ``{"plants": [...], "win_last", "win_mean", "median": {...}}``."""
    train_final = np.log1p(np.stack([final_features(s) for s in train]))
    scale = train_final.std(0) + 1e-9
    mean_pred = np.median(train_final, 0)
    rows = []
    for i, s in enumerate(held):
        k = len(s) // 2
        g = torch.Generator().manual_seed(seed + i)
        futures = forecast_organs(model, s[list(range(k))], n=n, generator=g)
        truth = np.log1p(final_features(s))
        fc = np.median(np.log1p(np.stack([final_features(f) for f in futures])), 0)
        last = np.log1p(tree_features(s.frames[[k - 1]]))

        def err(x: np.ndarray, truth: np.ndarray = truth) -> float:
            return float(np.linalg.norm((x - truth) / scale))

        def rel_len(x: np.ndarray, truth: np.ndarray = truth) -> float:
            return float(abs(np.expm1(x[0]) / np.expm1(truth[0]) - 1))

        rows.append({"plant": s.name, "observed": k, "frames": len(s),
                     "error": {"forecast": err(fc), "last": err(last), "mean": err(mean_pred)},
                     "length_rel_error": {"forecast": rel_len(fc), "last": rel_len(last), "mean": rel_len(mean_pred)},
                     "truth": np.expm1(truth).tolist(), "forecast": np.expm1(fc).tolist()})
    e = {k: np.array([r["error"][k] for r in rows]) for k in ("forecast", "last", "mean")}
    rl = {k: np.array([r["length_rel_error"][k] for r in rows]) for k in ("forecast", "last", "mean")}
    return {"plants": rows, "win_last": float((e["forecast"] < e["last"]).mean()),
            "win_mean": float((e["forecast"] < e["mean"]).mean()),
            "median_error": {k: float(np.median(v)) for k, v in e.items()},
            "median_length_rel_error": {k: float(np.median(v)) for k, v in rl.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("train")
    ap.add_argument("heldout")
    ap.add_argument("--n", type=int, default=10, help="continuations per plant")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--T", type=int, default=32)
    ap.add_argument("--model", default=None, help="a fitted OrganModel checkpoint (else fit on TRAIN_DIR)")
    ap.add_argument("--json", default=None, help="write the per-plant results here")
    a = ap.parse_args()
    t0 = time.perf_counter()
    train = [s.sequence for s in read_dataset(a.train, LoadOptions(T=a.T))]
    held = [s.sequence for s in read_dataset(a.heldout, LoadOptions(T=a.T))]
    t1 = time.perf_counter()
    model = load(a.model) if a.model and Path(a.model).exists() else OrganModel().fit(train)
    if not isinstance(model, OrganModel):
        sys.exit(f"{a.model}: not an OrganModel checkpoint")
    t2 = time.perf_counter()
    res = forecast_scores(model, train, held, a.n, a.seed)
    t3 = time.perf_counter()
    print(f"read {t1 - t0:.1f} s, fit {t2 - t1:.1f} s, forecast {t3 - t2:.1f} s; measure: final frame's "
          f"log1p({', '.join(FEATURES)}) / training sd, Euclidean")
    for r in res["plants"]:
        e = r["error"]
        print(f"  {r['plant']}: observed {r['observed']}/{r['frames']}  forecast {e['forecast']:.2f}  last "
              f"{e['last']:.2f}  mean {e['mean']:.2f}")
    m, lr = res["median_error"], res["median_length_rel_error"]
    print(f"forecast beats last frame on {100 * res['win_last']:.0f} %, the mean on {100 * res['win_mean']:.0f} % of "
          f"{len(held)} plants; median error forecast {m['forecast']:.2f} / last {m['last']:.2f} / mean "
          f"{m['mean']:.2f}; final length rel. error {lr['forecast']:.2f} / {lr['last']:.2f} / {lr['mean']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
