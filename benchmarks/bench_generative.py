"""Do generated plants look like the plants they were learned from? Fit on train, sample, compare with held out.

usage: python benchmarks/bench_generative.py TRAIN_DIR HELDOUT_DIR OUT_DIR [--n 30] [--seed 0] [--paper]
                                             [--yardstick morpho_eval.py]

Fits :class:`torch4dtree.model.OrganModel` (and, with ``--paper``, the paper's :class:`FourDTreeModel`) on the
sequence folders of TRAIN_DIR, writes ``--n`` samples of each as SWC dataset folders (OUT_DIR/organs,
OUT_DIR/paper) and the training plants as read and written back (OUT_DIR/train_roundtrip, the writer's own effect),
then prints the timings (fit seconds, decoded plants per minute) and, with ``--yardstick`` (a morphometric comparison
script taking REAL_DIR SAMPLE_DIR), its verdict of each folder against HELDOUT_DIR, the training plants included as
the reference a perfect generator would reach.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import torch

from torch4dtree.io import read_dataset, write_sequence
from torch4dtree.io.dataset import LoadOptions
from torch4dtree.model.fourd import FourDTreeModel, sequence_validity
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence


def write_all(out: Path, plants: list[TreeSequence]) -> list[str]:
    """Write plants as sequence folders under ``out``; returns the validity problems found."""
    problems = []
    for p in plants:
        problems += [f"{p.name}: {x}" for x in sequence_validity(p)]
        write_sequence(out / p.name, p, overwrite=True)
    return problems


def run_model(name: str, model: torch.nn.Module, train: list[TreeSequence], out: Path, n: int, seed: int) -> dict:
    """Fit, sample ``n`` plants, write them; the timings and validity."""
    t0 = time.perf_counter()
    model.fit(train)
    fit_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    z = model.sample_coefficients(n, torch.Generator().manual_seed(seed))
    plants = model.decode(z)
    sample_s = time.perf_counter() - t0
    problems = write_all(out / name, plants)
    return {"model": name, "fit_seconds": fit_s, "plants_per_minute": 60 * n / max(sample_s, 1e-9),
            "invalid": problems[:5], "n_invalid": len(problems)}


def yardstick(script: str, real: Path, samples: Path) -> str:
    """The last line of ``script REAL SAMPLES`` (its verdict)."""
    res = subprocess.run([sys.executable, script, str(real), str(samples)], capture_output=True, text=True, check=True)
    return res.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("train")
    ap.add_argument("heldout")
    ap.add_argument("out")
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--T", type=int, default=32)
    ap.add_argument("--paper", action="store_true", help="also fit the paper's FourDTreeModel (slow)")
    ap.add_argument("--yardstick", default=None, help="morphometric comparison script (REAL_DIR SAMPLE_DIR)")
    a = ap.parse_args()
    out = Path(a.out)
    train = [s.sequence for s in read_dataset(a.train, LoadOptions(T=a.T))]
    results = [run_model("organs", OrganModel(), train, out, a.n, a.seed)]
    if a.paper:
        results.append(run_model("paper", FourDTreeModel(), train, out, a.n, a.seed))
    write_all(out / "train_roundtrip", train)
    for r in results:
        print(json.dumps(r))
    if a.yardstick:
        for folder in [Path(a.train), out / "train_roundtrip"] + [out / r["model"] for r in results]:
            print(f"== {folder.name} vs held out")
            print(yardstick(a.yardstick, Path(a.heldout), folder))


if __name__ == "__main__":
    main()
