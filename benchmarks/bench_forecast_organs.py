"""Does the organ model's forecast beat "the last observed frame stays" and the population mean? Per held-out plant.

usage: python benchmarks/bench_forecast_organs.py TRAIN_DIR HELDOUT_DIR [--n 20] [--seed 0] [--T 32]
                                                  [--model CHECKPOINT] [--paper [CHECKPOINT]] [--json OUT.json]

Fits :class:`torch4dtree.model.OrganModel` on the sequence folders of TRAIN_DIR (or loads ``--model``), observes
each held-out plant over its first half (``n // 2`` frames) and forecasts the rest (``--n`` continuations,
:func:`torch4dtree.model.forecast_organs`). Measure, per plant, of the **final frame**: the five morphometrics of
:mod:`torch4dtree.evaluate.morphometrics` (total length, height, spread, tips, branch points), ``log1p`` and divided
by the training plants' standard deviation at their final frame; the error is the Euclidean distance to the truth's.
The forecast's point is the feature-wise median of its continuations' final frames. Baselines:

* **last**: the last observed frame stays (its features);
* **4D mean** (with ``--paper``): the final frame of the paper model's 4D mean
  (:class:`torch4dtree.model.FourDTreeModel` fit on TRAIN_DIR, or loaded, ``decode`` of zero coefficients);
* **medoid**: the organ model's mean plant, the training plant whose final frame is closest to the feature-wise
  median (a real plant, as a decoded mean would be one);
* **median**: the training plants' feature-wise median of their final frames (not one plant: the best constant
  guess per feature, a stronger baseline than any mean plant);
* **regression** (a reference, not a baseline): the final features predicted from the observed plant's own features
  at its last observed age by ridge regression over the training plants (their features read at that age, linear
  between frames; the ridge chosen by leave-one-out over the training plants): how much a point forecast can gain
  from what the first half shows, with no plant built.

Prints, per plant and overall, the errors and the share of held-out plants where the forecast is closer than each
(strictly), and the median relative error of the final total length of each.
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
from torch4dtree.model import FourDTreeModel, load
from torch4dtree.model.organ_forecast import forecast_organs
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence

RIDGES = (1.0, 5.0, 20.0, 100.0)
# added to standard deviations so a feature constant over the training plants divides by a small number, not 0
STD_FLOOR = 1e-9


def final_features(seq: TreeSequence) -> np.ndarray:
    """``(F,)`` morphometrics of a 4D tree's last frame."""
    return tree_features(seq.frames[[len(seq) - 1]])


def frame_features(seq: TreeSequence) -> np.ndarray:
    """``(n, F)`` ``log1p`` morphometrics of every frame."""
    return np.log1p(np.stack([tree_features(seq.frames[[j]]) for j in range(len(seq))]))


def ridge_predict(x: np.ndarray, y: np.ndarray, x_new: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge regression of ``y (P, F)`` on standardised ``x (P, F)``, evaluated at ``x_new (F,)``."""
    mu, sd = x.mean(0), x.std(0) + STD_FLOOR
    xs = (x - mu) / sd
    coef = np.linalg.solve(xs.T @ xs + ridge * np.eye(x.shape[1]), xs.T @ (y - y.mean(0)))
    return y.mean(0) + ((x_new - mu) / sd) @ coef


def regression(train_curves: list[tuple[np.ndarray, np.ndarray]], y: np.ndarray, x_new: np.ndarray, age: float,
               scale: np.ndarray) -> np.ndarray:
    """The regression reference (module doc): the training plants' features at ``age`` (their ``(frames, ages)``
    curves) -> final features ``y``, the ridge of :data:`RIDGES` with the least leave-one-out error."""
    x = np.stack([[np.interp(age, u, f[:, j]) for j in range(f.shape[1])] for f, u in train_curves])
    P = len(x)

    def loo(ridge: float) -> float:
        return float(np.mean([np.linalg.norm((ridge_predict(np.delete(x, i, 0), np.delete(y, i, 0), x[i], ridge)
                                              - y[i]) / scale) for i in range(P)]))

    best = min(RIDGES, key=loo)
    return ridge_predict(x, y, x_new, best)


def forecast_scores(model: OrganModel, train: list[TreeSequence], held: list[TreeSequence], n: int = 20,
                    seed: int = 0, mean_plant: np.ndarray | None = None) -> dict:
    """Per held-out plant, the final frame's standardised morphometric error of the forecast, the baselines and the
    regression reference (module doc; ``mean_plant``: the 4D mean's final features, if any); returns
    ``{"plants": [...], "win": {baseline: share}, "median_error": {...}, "median_length_rel_error": {...}}``."""
    t0, span = float(model.time_start), float(model.duration)
    curves = [(frame_features(s), (s.times.double().numpy() - t0) / span) for s in train]
    train_final = np.stack([f[-1] for f, _ in curves])
    scale = train_final.std(0) + STD_FLOOR
    median = np.median(train_final, 0)
    guesses = {"median": median, "medoid": train_final[np.argmin((((train_final - median) / scale) ** 2).sum(1))]}
    if mean_plant is not None:
        guesses["4d_mean"] = np.log1p(mean_plant)
    rows = []
    for i, s in enumerate(held):
        k = len(s) // 2
        g = torch.Generator().manual_seed(seed + i)
        futures = forecast_organs(model, s[list(range(k))], n=n, generator=g)
        truth = np.log1p(final_features(s))
        seen = frame_features(s[list(range(k))])[-1]
        age = (float(s.times[k - 1]) - t0) / span
        plant = {"forecast": np.median(np.log1p(np.stack([final_features(f) for f in futures])), 0), "last": seen,
                 **guesses, "regression": regression(curves, train_final, seen, age, scale)}
        rows.append({"plant": s.name, "observed": k, "frames": len(s),
                     "error": {key: float(np.linalg.norm((x - truth) / scale)) for key, x in plant.items()},
                     "length_rel_error": {key: float(abs(np.expm1(x[0]) / np.expm1(truth[0]) - 1))
                                          for key, x in plant.items()},
                     "truth": np.expm1(truth).tolist(), "forecast": np.expm1(plant["forecast"]).tolist()})
    names = list(rows[0]["error"])
    e = {key: np.array([r["error"][key] for r in rows]) for key in names}
    rl = {key: np.array([r["length_rel_error"][key] for r in rows]) for key in names}
    return {"plants": rows, "win": {key: float((e["forecast"] < e[key]).mean()) for key in names if key != "forecast"},
            "median_error": {key: float(np.median(v)) for key, v in e.items()},
            "median_length_rel_error": {key: float(np.median(v)) for key, v in rl.items()}}


def paper_mean(train: list[TreeSequence], checkpoint: str | None) -> tuple[np.ndarray, float]:
    """The final frame's features of the paper model's 4D mean (fit on ``train`` or loaded) and the fit's seconds."""
    t0 = time.perf_counter()
    model = load(checkpoint) if checkpoint and Path(checkpoint).exists() else FourDTreeModel().fit(train)
    if not isinstance(model, FourDTreeModel):
        sys.exit(f"{checkpoint}: not a FourDTreeModel checkpoint")
    mean = model.decode(torch.zeros(model.n_modes, dtype=torch.float64))[0]
    return final_features(mean), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("train")
    ap.add_argument("heldout")
    ap.add_argument("--n", type=int, default=20, help="continuations per plant")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--T", type=int, default=32)
    ap.add_argument("--model", default=None, help="a fitted OrganModel checkpoint (else fit on TRAIN_DIR)")
    ap.add_argument("--paper", nargs="?", const="", default=None,
                    help="add the paper model's 4D mean (fit on TRAIN_DIR, minutes; or a FourDTreeModel checkpoint)")
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
    mean_plant = None
    if a.paper is not None:
        mean_plant, seconds = paper_mean(train, a.paper or None)
        print(f"paper model: {seconds:.0f} s; its 4D mean's final frame {np.round(mean_plant, 1).tolist()}")
    t3 = time.perf_counter()
    res = forecast_scores(model, train, held, a.n, a.seed, mean_plant)
    t4 = time.perf_counter()
    print(f"read {t1 - t0:.1f} s, fit {t2 - t1:.1f} s, forecast {t4 - t3:.1f} s; measure: final frame's "
          f"log1p({', '.join(FEATURES)}) / training sd, Euclidean")
    for r in res["plants"]:
        print(f"  {r['plant']}: observed {r['observed']}/{r['frames']}  "
              + "  ".join(f"{key} {v:.2f}" for key, v in r["error"].items()))
    m, lr = res["median_error"], res["median_length_rel_error"]
    print(f"forecast beats, of {len(held)} plants: "
          + ", ".join(f"{key} {100 * v:.0f} %" for key, v in res["win"].items()))
    print("median error: " + " / ".join(f"{key} {v:.2f}" for key, v in m.items()))
    print("final length rel. error: " + " / ".join(f"{key} {v:.2f}" for key, v in lr.items()))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
