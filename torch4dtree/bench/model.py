"""Benchmark of the generative model (``torch4dtree benchmark all``): fit time, the 4D mean, sampling and decoding.

The paper (MATLAB, unspecified CPU) gives 0.0006 s for the mean of seven registered 4D tomato plants (Fig. 6) and
0.0001 s on average to generate a 4D tomato plant (Fig. 7). A :class:`~torch4dtree.model.FourDTreeModel` is fitted
on a small synthetic set (no data needed), then timed:

* ``mean``: the 4D mean alone (the temporal Karcher mean of the plants' trajectories, as the model's fit runs it),
  mean over ``repeats`` runs;
* ``sample``: coefficients -> trajectories, one plant per call (mean over ``single`` calls: like the paper's "per
  generated plant") and in one batch of ``samples`` plants (seconds per plant);
* ``decode``: trajectories -> 4D trees (the skeletons of every frame; the paper's figure does not include it).
"""

from __future__ import annotations

import time
from typing import Any

import torch

from ..evaluate.paper import SECONDS
from ..evaluate.stats import summary

__all__ = ["PAPER_SECONDS", "benchmark_model"]

PAPER_SECONDS = {"mean": SECONDS["mean_4d"], "sample": SECONDS["sample"]}


def benchmark_model(plants: int = 5, frames: int = 8, T: int = 32, n_t: int = 32, kind: str = "tomato",
                    seed: int = 0, samples: int = 10000, single: int = 200, decode: int = 4, repeats: int = 3
                    ) -> dict[str, Any]:
    """Fit on ``plants`` synthetic ``kind`` plants of ``frames`` frames (``T`` points per branch, ``n_t`` common
    times) and time the stages of the module doc. Returns a JSON-safe dict (seconds; ``*_per_s`` rates)."""
    from ..data import synthetic_dataset
    from ..model import FourDTreeModel
    from ..model.trajectory import TrajectoryMean
    from ..settings import ModelSettings

    seqs = [p.sequence for p in synthetic_dataset(kind, plants, seed, n_frames=frames, T=T, dtype=torch.float64)]
    t0 = time.perf_counter()
    model = FourDTreeModel(ModelSettings(n_t=n_t)).fit(seqs)
    fit_s = time.perf_counter() - t0
    alpha = model.population.trajectories
    mean_s = []
    for _ in range(repeats):  # a fresh mean each time, with the model's settings
        t0 = time.perf_counter()
        TrajectoryMean(model.settings.mean_iters, registration=model.settings.temporal).fit(alpha)
        mean_s.append(time.perf_counter() - t0)
    g = torch.Generator().manual_seed(seed)
    model.trajectories(model.sample_coefficients(2, g))  # first call: lazy set-up stays out of the timing
    one = []
    for _ in range(single):
        t0 = time.perf_counter()
        model.trajectories(model.sample_coefficients(1, g))
        one.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    z = model.sample_coefficients(samples, g)
    model.trajectories(z)
    batch_s = (time.perf_counter() - t0) / samples
    t0 = time.perf_counter()
    decoded = model.decode(z[:decode])
    decode_s = (time.perf_counter() - t0) / decode
    return {
        "plants": plants, "frames": frames, "T": T, "n_t": n_t, "kind": kind, "modes": model.n_modes,
        "slots": model.report_["population"]["slots"], "tree_components": model.population.k,
        "fit_seconds": fit_s, "fit_stage_seconds": model.report_["seconds"],
        "mean_seconds": summary(mean_s), "sample_one_seconds": summary(one),
        "sample_batched_seconds_per_plant": batch_s, "sample_batched_plants_per_s": 1.0 / batch_s,
        "batch": samples,
        "decode_seconds_per_plant": decode_s, "decode_frames_per_s": sum(len(s) for s in decoded) / (decode_s * decode),
        "paper_seconds": PAPER_SECONDS,
    }
