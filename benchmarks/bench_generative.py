"""Do generated plants look like the plants they were learned from? Fit on train, sample, compare with held out.

usage: python benchmarks/bench_generative.py TRAIN_DIR HELDOUT_DIR OUT_DIR [--n N] [--seed 0] [--seeds 1] [--paper]
                                             [--label KIND] [--yardstick morpho_eval.py]
                                             [--against-training] [--events] [--json FILE] [--splits K]
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

Plausibility over seeds (``--seeds K``, K >= 2; the protocol of the plausibility targets): each fitted model draws
``--n`` samples (default: as many as the held-out plants, the equal-size comparison of the training plants' row)
with each of the seeds ``--seed .. --seed + K - 1``; per seed, :func:`compare_populations` against HELDOUT_DIR
(in memory, the same features as the SWC files give); printed: the median and the worst seed of the worst median
ratio at each age after the first (``min(ratio, 1 / ratio)`` over the features), overall, and of the morphometric
1-NNA. Scale row: the training plants against the held-out ones (with the same seeds, ``--n`` of them drawn without
replacement when ``--n`` is smaller than the training set; otherwise all of them, one value), and the real plants
(training and held out together) split at random into sets of the same sizes, one split a seed: how far two real
samples of this population are from each other. With ``--events``,
organs shrinking / vanishing between frames (:func:`torch4dtree.evaluate.generative_organs.event_rates`) in the
first seed's samples (as many as training plants) beside the training and held-out plants. The first seed's
samples are the ones written to OUT_DIR (so ``--yardstick`` checks them); ``--json FILE`` keeps every seed's numbers.

Over random splits (``--splits K`` with ``--seeds``): one fixed split can be unlike the population (its training
plants far from its held-out ones at some age, so that no model copying them passes there). The training and
held-out plants are pooled and split at random K times into sets of the original sizes (split ``i`` is the
permutation of seed ``i``, the same as the ``random splits`` row's seed ``i``); on each split the organ model is fit
on its training plants and judged over the seeds against its held-out plants, and its training plants are judged
against the same held-out plants (the real-vs-real row, the same splits). Printed: the median over splits (worst
split) of each seed-median, and each split's worst median ratio and 1-NNA.

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
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torch4dtree.data import run_synth
from torch4dtree.evaluate.generative_organs import event_rates
from torch4dtree.evaluate.morphometrics import AGES, FEATURES, compare_populations, population_curves
from torch4dtree.evaluate.stats import summary
from torch4dtree.io import read_dataset, write_sequence
from torch4dtree.io.dataset import LoadOptions, sequence_folders
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


def draw(model: torch.nn.Module, n: int, seed: int) -> list[TreeSequence]:
    """``n`` decoded samples of a fitted model with one seed."""
    return model.decode(model.sample_coefficients(n, torch.Generator().manual_seed(seed)))


def run_model(name: str, model: torch.nn.Module, train: list[TreeSequence], out: Path, n: int, seed: int) -> dict:
    """Fit, sample ``n`` plants, write them; the timings and validity."""
    t0 = time.perf_counter()
    model.fit(train)
    fit_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    plants = draw(model, n, seed)
    sample_s = time.perf_counter() - t0
    problems = write_all(out / name, plants)
    return {"model": name, "fit_seconds": fit_s, "plants_per_minute": 60 * n / max(sample_s, 1e-9),
            "invalid": problems[:5], "n_invalid": len(problems)}


SEED_KEYS = ("worst_ratio", "one_nna", *(f"{u}" for u in AGES if u > 0))


def _per_seed(real: np.ndarray, samples: np.ndarray) -> dict:
    """One seed's summaries: worst median ratio overall and at each age after the first, its name, 1-NNA."""
    c = compare_populations(real, samples)
    return {"worst_ratio": c["worst_ratio"], "worst": c["worst"], "one_nna": c["one_nna"], **c["worst_by_age"]}


def seed_protocol(models: dict[str, torch.nn.Module], train_dir: Path, heldout_dir: Path, n: int, seeds: list[int]
                  ) -> dict[str, dict]:
    """The plausibility protocol over seeds (module doc): ``{row: {"seeds": [per seed], "summary": {key: summary}}}``
    for each fitted model and the scale rows; real plants read from their folders' SWC files, as the yardstick
    reads them."""
    real = population_curves(heldout_dir)
    train_curves = population_curves(train_dir)
    out: dict[str, dict] = {}
    for name, model in models.items():
        out[name] = {"seeds": [_per_seed(real, population_curves(draw(model, n, s))) for s in seeds]}
    if n < len(train_curves):
        picks = [torch.randperm(len(train_curves), generator=torch.Generator().manual_seed(s))[:n].numpy()
                 for s in seeds]
        out["training plants"] = {"seeds": [_per_seed(real, train_curves[p]) for p in picks]}
    else:
        out["training plants"] = {"seeds": [_per_seed(real, train_curves)]}
    both = np.concatenate([train_curves, real])
    perms = [torch.randperm(len(both), generator=torch.Generator().manual_seed(s)).numpy() for s in seeds]
    k = len(train_curves)
    out["random splits of the real plants"] = {"seeds": [_per_seed(both[p[k:]], both[p[:k]]) for p in perms]}
    for row in out.values():
        row["summary"] = {k: summary(r[k] for r in row["seeds"]) for k in SEED_KEYS}
    return out


def seed_table(result: dict[str, dict], label: str, n: int, held: int) -> list[str]:
    """Markdown: median (worst seed) of the worst median ratio at each age, overall, and of the 1-NNA."""
    ages = [f"{u}" for u in AGES if u > 0]
    lines = [f"| {label} ({n} samples a seed vs {held} held out) | seeds | " + " | ".join(f"worst ratio @ {u}"
                                                                                           for u in ages)
             + " | worst ratio | 1-NNA |", "|---|---|" + "---|" * (len(ages) + 2)]
    for name, row in result.items():
        sm = row["summary"]
        lines.append(f"| {name} | {sm['one_nna']['n']} | " + " | ".join(median_worst(sm[u], "min") for u in ages)
                     + f" | {median_worst(sm['worst_ratio'], 'min')} | {median_worst(sm['one_nna'], 'max')} |")
    return lines


def median_worst(x: dict, worst: str) -> str:
    """``median (worst)`` of a summary over seeds; ``worst`` its key of the worst seed (``min`` or ``max``)."""
    return f"{x['median']:.2f}" if x["n"] == 1 else f"{x['median']:.2f} ({x[worst]:.2f})"


def yardstick(script: str, real: Path, samples: Path) -> str:
    """The output of ``script REAL SAMPLES`` (its verdict), then how far :func:`compare_populations` of the same
    folders is from it (``script --json``): the largest gap of a median ratio and of the 1-NNA."""
    with tempfile.TemporaryDirectory() as tmp:
        js = Path(tmp) / "yardstick.json"
        res = subprocess.run([sys.executable, script, str(real), str(samples), "--json", str(js)], capture_output=True,
                             text=True, check=True)
        theirs = json.loads(js.read_text())
    ours = compare_populations(population_curves(real), population_curves(samples))
    gap = max(abs(ours["features"][k]["ratio"] - v["ratio"]) for k, v in theirs["features"].items())
    return res.stdout + (f"agreement with compare_populations: largest median-ratio gap {gap:.2e}, 1-NNA gap "
                         f"{abs(ours['one_nna'] - theirs['one_nna']):.2e}\n")


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


def split_protocol(train_dir: Path, heldout_dir: Path, T: int, seeds: list[int], splits: int) -> dict:
    """The protocol over ``splits`` random splits of the pooled plants (module doc): ``{"splits": [{"train": names,
    "organs model": {key: summary over seeds}, "training plants": {key: value}}], "summary": {row: {key: summary
    over splits of the seed-medians}}}``."""
    plants = [s.sequence for d in (train_dir, heldout_dir) for s in read_dataset(d, LoadOptions(T=T))]
    curves = np.concatenate([population_curves(train_dir), population_curves(heldout_dir)])
    k = len(sequence_folders(train_dir))
    rows = []
    for i in range(splits):
        p = torch.randperm(len(plants), generator=torch.Generator().manual_seed(i)).numpy()
        train, held = p[:k], p[k:]
        model = OrganModel().fit([plants[j] for j in train])
        per_seed = [_per_seed(curves[held], population_curves(draw(model, len(held), s))) for s in seeds]
        real = _per_seed(curves[held], curves[train])
        rows.append({"train": [plants[j].name for j in train],
                     "organs model": {key: summary(r[key] for r in per_seed) for key in SEED_KEYS},
                     "organs model worst": [r["worst"] for r in per_seed],
                     "training plants": {key: real[key] for key in SEED_KEYS}, "training plants worst": real["worst"]})
    out = {"organs model": {key: summary(r["organs model"][key]["median"] for r in rows) for key in SEED_KEYS},
           "training plants": {key: summary(r["training plants"][key] for r in rows) for key in SEED_KEYS}}
    return {"splits": rows, "summary": out}


def split_table(result: dict, label: str) -> list[str]:
    """Markdown: median over splits (worst split) of each row's seed-median, then one line per split."""
    ages = [f"{u}" for u in AGES if u > 0]
    n = len(result["splits"])
    lines = [f"| {label} over {n} random splits | " + " | ".join(f"worst ratio @ {u}" for u in ages)
             + " | worst ratio | 1-NNA |", "|---|" + "---|" * (len(ages) + 2)]
    for name, sm in result["summary"].items():
        lines.append(f"| {name} | " + " | ".join(median_worst(sm[u], "min") for u in ages)
                     + f" | {median_worst(sm['worst_ratio'], 'min')} | {median_worst(sm['one_nna'], 'max')} |")
    lines += ["", "| split | organs model: worst ratio, 1-NNA (seed-medians) | training plants: worst ratio, 1-NNA |",
              "|---|---|---|"]
    for i, r in enumerate(result["splits"]):
        m, t = r["organs model"], r["training plants"]
        lines.append(f"| {i} | {m['worst_ratio']['median']:.2f}, {m['one_nna']['median']:.2f} | "
                     f"{t['worst_ratio']:.2f} ({r['training plants worst']}), {t['one_nna']:.2f} |")
    return lines


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
    ap.add_argument("--n", type=int, default=None, help="samples a model draws (default: as many as held-out plants)")
    ap.add_argument("--seeds", type=int, default=1, help="the plausibility protocol over this many seeds (module doc)")
    ap.add_argument("--splits", type=int, default=0,
                    help="with --seeds: also the protocol over this many random splits of the pooled plants")
    ap.add_argument("--events", action="store_true", help="organs shrinking / vanishing: samples beside real plants")
    ap.add_argument("--json", default=None, help="write the protocol's numbers here")
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
    held = [s.sequence for s in read_dataset(heldout, LoadOptions(T=a.T))]
    n = len(held) if a.n is None else a.n
    models: dict[str, torch.nn.Module] = {"organs": OrganModel()}
    if a.paper:
        models["paper"] = FourDTreeModel()
    results = [run_model(name, m, train, out, n, seed) for name, m in models.items()]
    write_all(out / "train_roundtrip", train)
    for r in results:
        print(json.dumps(r))
    folders = {"training plants": train_dir, "training plants, written back": out / "train_roundtrip",
               **{f"{r['model']} model": out / r["model"] for r in results}}
    print("\n".join(morphometric_table(heldout, folders, a.label)))
    if a.against_training:
        print("\n".join(morphometric_table(train_dir, {k: v for k, v in folders.items() if "model" in k},
                                            f"{a.label} (reference: the training plants)")))
    record: dict[str, Any] = {"label": a.label, "n": n, "held_out": len(held), "training": len(train),
                              "fits": results}
    if a.seeds > 1:
        seeds = list(range(seed, seed + a.seeds))
        protocol = seed_protocol({f"{k} model": m for k, m in models.items()}, train_dir, heldout, n, seeds)
        print("\n".join(seed_table(protocol, a.label, n, len(held))))
        record["seeds"] = seeds
        record["protocol"] = protocol
        if a.splits > 0:
            by_split = split_protocol(train_dir, heldout, a.T, seeds, a.splits)
            print("\n".join(split_table(by_split, a.label)))
            record["splits"] = by_split
    if a.events:
        k = len(train)
        ev = {f"{name} model": event_rates(draw(m, k, seed)) for name, m in models.items()}
        ev |= {"training plants": event_rates(train), "held-out plants": event_rates(held)}
        print("| organs between frames | shrink | vanish | organ steps |\n|---|---|---|---|")
        for who, e in ev.items():
            print(f"| {who} | {100 * e['shrink']:.2f} % | {100 * e['vanish']:.2f} % | {e['organ_steps']:.0f} |")
        record["events"] = ev
    if a.yardstick:
        for folder in folders.values():
            print(f"== {folder.name} vs held out")
            print(yardstick(a.yardstick, heldout, folder))
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
