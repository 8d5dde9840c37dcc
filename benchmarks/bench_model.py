"""The generative model's speed and the novelty of its samples; prints one JSON object.

    python benchmarks/bench_model.py [--data ../shared/data/pheno4d] [--T 64] [--n-t 32] [--plants 20] [--frames 10]
                                     [--samples 200] [--batch 10000] [--decode 20] [--threads 1]

* ``fit``: seconds to fit :class:`FourDTreeModel` (default settings) on the Pheno4D ``mat`` tomato plants (5), the
  maize plants (4) and a synthetic tomato set of ``--plants`` plants (``--frames`` frames, seed ``--seed``), with
  the model's own stage timings.
* ``sample``: 4D trees per second from coefficients to trajectories (``model.trajectories(z)``, a batch of
  ``--batch``, the median of 5 runs, and the same in chunks of ``--chunk``; the paper: 0.0001 s a generated 4D plant,
  i.e. 10,000 a second; target >= that)
  and the decoding rate to skeletons (``model.decode``, ``--decode`` samples).
* ``novelty``: on the synthetic set, ``--samples`` samples' ground distances (:mod:`torch4dtree.evaluate.generative`:
  the 4D distance after temporal registration in the model's tree space) to every training plant. The check: no
  sample is closer to a training plant than the median nearest-neighbour distance between training plants / 4.
  (The same check at T = 16 is `tests/model/test_model.py::test_samples_are_new_plants_not_copies`.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

import numba
import torch

from torch4dtree.bench.trees import default_data_root
from torch4dtree.data import synthetic_dataset
from torch4dtree.evaluate import load_eval_data
from torch4dtree.evaluate.generative import PAPER_SECONDS
from torch4dtree.evaluate.generative_metrics import distance_matrix, novelty
from torch4dtree.model import FourDTreeModel
from torch4dtree.settings import ModelSettings


def _fit(seqs: list, n_t: int) -> tuple[FourDTreeModel, dict[str, Any]]:
    t0 = time.perf_counter()
    model = FourDTreeModel(ModelSettings(n_t=n_t)).fit(seqs)
    seconds = time.perf_counter() - t0
    return model, {"plants": len(seqs), "frames": sum(len(s) for s in seqs), "seconds": seconds,
                   "stages": model.report_["seconds"], "modes": model.n_modes, "tree_components": model.population.k}


def _per_tree(model: FourDTreeModel, z: torch.Tensor, chunk: int) -> float:
    """Median over 5 runs of the seconds per 4D tree of ``model.trajectories`` over ``z`` in chunks."""
    times = []
    with torch.no_grad():
        model.trajectories(z[:10])  # warm-up
        for _ in range(5):
            t0 = time.perf_counter()
            for c in z.split(chunk):
                model.trajectories(c)
            times.append(time.perf_counter() - t0)
    return statistics.median(times) / len(z)


def _rates(model: FourDTreeModel, batch: int, chunk: int, n_decode: int, seed: int) -> dict[str, Any]:
    z = model.sample_coefficients(batch, torch.Generator().manual_seed(seed))
    per = _per_tree(model, z, batch)
    per_chunked = _per_tree(model, z, chunk)  # memory-bound: smaller batches stay in cache
    t0 = time.perf_counter()
    seqs = model.decode(z[:n_decode])
    dec = (time.perf_counter() - t0) / n_decode
    return {"batch": batch, "seconds_per_4d_tree": per, "per_second": 1.0 / per,
            "speedup_vs_paper": PAPER_SECONDS["sample"] / per, "meets_10000_per_second": 1.0 / per >= 10_000,
            "chunk": chunk, "per_second_chunked": 1.0 / per_chunked,
            "floats_per_4d_tree": model.n_t * model.population.k,
            "decode_seconds_per_4d_tree": dec, "decoded_per_second": 1.0 / dec,
            "decoded_frames_per_second": sum(len(s) for s in seqs) / (dec * n_decode)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=None, help="Pheno4D folder (default ../shared/data/pheno4d)")
    p.add_argument("--T", type=int, default=64)
    p.add_argument("--n-t", type=int, default=32)
    p.add_argument("--plants", type=int, default=20)
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--samples", type=int, default=200)
    p.add_argument("--batch", type=int, default=10_000)
    p.add_argument("--chunk", type=int, default=1000, help="also time the batch in chunks of this size")
    p.add_argument("--decode", type=int, default=20)
    p.add_argument("--threads", type=int, default=1, help="torch and numba threads")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    numba.set_num_threads(a.threads)
    out: dict[str, Any] = {"settings": vars(a), "threads": a.threads, "paper_seconds": PAPER_SECONDS}

    data = load_eval_data(a.data or default_data_root(), "mat", T=a.T)
    for kind in data.kinds:
        model, fit = _fit([pl.sequence for pl in data.by_kind(kind)], a.n_t)
        out[f"pheno4d_{kind}"] = {"fit": fit, "sample": _rates(model, a.batch, a.chunk, a.decode, a.seed)}

    seqs = [pl.sequence for pl in synthetic_dataset("tomato", plants=a.plants, seed=a.seed, n_frames=a.frames, T=a.T)]
    model, fit = _fit(seqs, a.n_t)
    row: dict[str, Any] = {"fit": fit, "sample": _rates(model, a.batch, a.chunk, a.decode, a.seed)}
    t0 = time.perf_counter()
    train = model.population.trajectories.detach()
    z = model.sample_coefficients(a.samples, torch.Generator().manual_seed(a.seed + 1))
    nov = novelty(distance_matrix(model.trajectories(z).detach(), train), distance_matrix(train))
    row["novelty"] = {**nov, "samples": a.samples, "passes": nov["share_closer"] == 0.0,
                      "seconds": time.perf_counter() - t0}
    out[f"synthetic_tomato_{a.plants}"] = row
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
