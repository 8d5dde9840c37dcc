"""Do generated plants look like the plants they were learned from? Fit on train, sample, compare with held out.

usage: python benchmarks/bench_generative.py TRAIN_DIR HELDOUT_DIR OUT_DIR [--n 30] [--seed 0] [--paper]
                                             [--label KIND] [--yardstick morpho_eval.py]
                                             [--against-training]
       python benchmarks/bench_generative.py --speed OUT_DIR [--plants 100] [--frames 10] [--kind tomato]
                                             [--seed 11] [--samples 1000] [--T 32]

Comparison (the first form): fits :class:`torch4dtree.model.OrganModel` (and, with ``--paper``, the paper's
:class:`FourDTreeModel`) on the sequence folders of TRAIN_DIR, writes ``--n`` samples of each as SWC dataset folders
(OUT_DIR/organs, OUT_DIR/paper) and the training plants as read and written back (OUT_DIR/train_roundtrip, the
writer's own effect), prints the timings (fit seconds, decoded plants per minute) and the morphometric table
(:func:`torch4dtree.evaluate.morphometrics.compare_populations` of each folder's plants against HELDOUT_DIR as
read from the SWC files: worst median ratio at ages after the first, largest KS, 1-NNA; the training plants are the
reference a perfect generator would reach), one row per model side by side. With ``--yardstick`` (a morphometric
comparison script taking REAL_DIR SAMPLE_DIR), also its verdict of each folder.

Speed (``--speed``): writes ``--plants`` synthetic plants of ``--frames`` frames with the package
(``torch4dtree synth``) into OUT_DIR/data (kept for a rerun), then times reading them, fitting the organ model and
sampling and decoding ``--samples`` plants separately, with the process's peak memory; the targets are a fit under
10 minutes and at least 1,000 decoded 4D plants a minute on the 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from torch4dtree.data import run_synth
from torch4dtree.evaluate.morphometrics import AGES, FEATURES, compare_populations, population_curves
from torch4dtree.io import read_dataset, write_sequence
from torch4dtree.io.dataset import LoadOptions
from torch4dtree.model.fourd import FourDTreeModel, sequence_validity
from torch4dtree.model.organs import OrganModel
from torch4dtree.trees.structures import TreeSequence

FIT_LIMIT_SECONDS = 600.0  # the speed targets
PLANTS_PER_MINUTE = 1000.0


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
    """The output of ``script REAL SAMPLES`` (its verdict)."""
    res = subprocess.run([sys.executable, script, str(real), str(samples)], capture_output=True, text=True, check=True)
    return res.stdout


def morphometric_table(heldout: Path, folders: dict[str, Path], label: str) -> list[str]:
    """Markdown rows: each folder's plants against the held-out ones (:func:`compare_populations`), then each
    folder's median ratio per feature at every age."""
    real = population_curves(heldout)
    lines = [f"| {label}: plants vs held out | worst median ratio | KS max | 1-NNA |", "|---|---|---|---|"]
    ratios = [f"| {label}: median ratio vs held out | " + " | ".join(f"u = {u:g}" for u in AGES) + " |",
              "|---|" + "---|" * len(AGES)]
    for name, folder in folders.items():
        c = compare_populations(real, population_curves(folder))
        lines.append(f"| {name} | {c['worst_ratio']:.2f} ({c['worst']}) | {c['ks_max']:.2f} | {c['one_nna']:.2f} |")
        ratios += [f"| {name}: {f} | " + " | ".join(f"{c['features'][f'{f}@{u}']['ratio']:.2f}" for u in AGES) + " |"
                   for f in FEATURES]
    return lines + [""] + ratios


def peak_gb() -> float:
    """The process's peak resident memory (GB; Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def _timed(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    """``fn()``, its wall-clock seconds and this process's CPU seconds (on a shared machine the second says what
    the stage costs, the first what it took)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def speed(out: Path, plants: int, frames: int, kind: str, seed: int, samples: int, T: int) -> dict:
    """The speed check (module doc): seconds (wall clock and CPU) to read, fit and sample, decoded plants a minute,
    peak memory."""
    data = out / "data"
    _, synth_s, _ = _timed(lambda: None if data.exists() else run_synth(kind, plants, seed, str(data), frames=frames,
                                                                                  variation=True))
    loaded, read_s, read_cpu = _timed(lambda: read_dataset(data, LoadOptions(T=T)))
    train = [s.sequence for s in loaded]
    model = OrganModel()
    _, fit_s, fit_cpu = _timed(lambda: model.fit(train))
    z = model.sample_coefficients(samples, torch.Generator().manual_seed(0))
    decoded, sample_s, sample_cpu = _timed(lambda: model.decode(z))
    per_minute = 60 * len(decoded) / max(sample_s, 1e-9)
    return {"plants": len(train), "frames": sum(len(s) for s in train), "kind": kind, "T": T,
            "threads": torch.get_num_threads(), "synth_seconds": synth_s,
            "read_seconds": read_s, "read_cpu_seconds": read_cpu, "fit_seconds": fit_s, "fit_cpu_seconds": fit_cpu,
            "sample_seconds": sample_s, "sample_cpu_seconds": sample_cpu, "decoded_per_minute": per_minute,
            "decoded_per_cpu_minute": 60 * len(decoded) / max(sample_cpu, 1e-9), "peak_memory_gb": peak_gb(),
            "fit_under_10_min": fit_s < FIT_LIMIT_SECONDS, "at_least_1000_a_minute": per_minute >= PLANTS_PER_MINUTE}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", help="TRAIN_DIR HELDOUT_DIR OUT_DIR, or OUT_DIR with --speed")
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=None, help="samples' seed (0), or the speed data's seed (11)")
    ap.add_argument("--T", type=int, default=32)
    ap.add_argument("--paper", action="store_true", help="also fit the paper's FourDTreeModel (slow)")
    ap.add_argument("--label", default="plants", help="the kind named in the morphometric table")
    ap.add_argument("--against-training", action="store_true", help="also compare the samples with the training plants")
    ap.add_argument("--yardstick", default=None, help="morphometric comparison script (REAL_DIR SAMPLE_DIR)")
    ap.add_argument("--speed", action="store_true", help="the speed check instead (module doc)")
    ap.add_argument("--plants", type=int, default=100)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--kind", default="tomato")
    ap.add_argument("--samples", type=int, default=1000)
    a = ap.parse_args()
    if a.speed:
        if len(a.folders) != 1:
            ap.error("--speed takes one folder, OUT_DIR")
        print(json.dumps(speed(Path(a.folders[0]), a.plants, a.frames, a.kind, 11 if a.seed is None else a.seed,
                               a.samples, a.T)))
        return
    if len(a.folders) != 3:
        ap.error("give TRAIN_DIR HELDOUT_DIR OUT_DIR")
    train_dir, heldout, out = (Path(f) for f in a.folders)
    seed = 0 if a.seed is None else a.seed
    train = [s.sequence for s in read_dataset(train_dir, LoadOptions(T=a.T))]
    results = [run_model("organs", OrganModel(), train, out, a.n, seed)]
    if a.paper:
        results.append(run_model("paper", FourDTreeModel(), train, out, a.n, seed))
    write_all(out / "train_roundtrip", train)
    for r in results:
        print(json.dumps(r))
    folders = {"training plants": train_dir, "training plants, written back": out / "train_roundtrip",
               **{f"{r['model']} model": out / r["model"] for r in results}}
    print("\n".join(morphometric_table(heldout, folders, a.label)))
    if a.against_training:
        print("\n".join(morphometric_table(train_dir, {k: v for k, v in folders.items() if "model" in k},
                                            f"{a.label} (reference: the training plants)")))
    if a.yardstick:
        for folder in folders.values():
            print(f"== {folder.name} vs held out")
            print(yardstick(a.yardstick, heldout, folder))


if __name__ == "__main__":
    main()
