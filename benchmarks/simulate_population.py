"""Populations of growing plants from an independent simulator (CPlantBox), as dataset folders.

Benchmark data source, never run in CI: the plants come from CPlantBox (``pip install cplantbox``, see
``benchmarks/requirements.txt``), a functional-structural plant model whose example parameter files (shipped in
its package data, ``plantbox/modelparameter/structural/plant/``) describe real species. Nobody on this project
designed these shapes, so they test whether a generative model reproduces plants it did not help to invent.

Each plant is one CPlantBox simulation (its own random seed: the parameter files' standard deviations apply) with a
per-plant jitter of the growth rates and maximal lengths (a log-normal factor, ``--jitter``) and organs that
start growing ``--plastochron`` days after they are created (so organs appear over time), observed on
``--frames`` irregular days in the kind's span (:data:`KINDS`, jittered per plant). Each frame is the shoot (stems
and leaf midribs; roots and the seed dropped; organs under 2 mm, just created, left out), a tree rooted at the stem
base:

* written as SWC (``id type x y z radius parent``), millimetres, z up, the base at the origin (the lowest point
  but for drooping leaves); chains between branch points and tips are thinned to about ``--spacing`` mm;
* ``type``: a stable organ label per plant (1 + the organ's rank in order of appearance; the stem base gets its
  stem's label), so one organ keeps its label over a plant's frames;
* ``times.json`` ``{file name: day}`` beside the frames; ``population.json`` records the settings.

Layout (what ``torch4dtree.io.read_dataset`` and :mod:`torch4dtree.evaluate.morphometrics` read)::

    OUT/<kind>_<NN>/day_<DDD>.swc, times.json
    OUT/population.json   (settings and per-plant seeds; not dataset.json, which marks the package's synth output)

usage: PYTHONPATH=. .venv-bench/bin/python benchmarks/simulate_population.py --kind wheat --plants 40 --out DIR
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

# kind -> (CPlantBox parameter file, first day, last day): spans where the shoot grows visibly
KINDS = {
    "maize": ("maize.xml", 6.0, 40.0),
    "sunflower": ("Heliantus_Pages_2013.xml", 8.0, 60.0),
    "lupin": ("Lupinus_albus_Leitner_2014.xml", 8.0, 50.0),
    "rapeseed": ("Brassica_napus_a_Leitner_2010.xml", 8.0, 60.0),
    "wheat": ("Triticum_aestivum_adapted_2023.xml", 6.0, 50.0),
}
STEM, LEAF = 3, 4  # CPlantBox organ types kept (1 seed, 2 root dropped)
CM_TO_MM = 10.0
MIN_ORGAN = 2.0  # mm: shorter organs are left out (just created, not yet seen by a scanner)
MIN_EDGE = 0.01  # mm: shorter edges would vanish in the files' 3 decimals and make zero-length branches


def parameter_file(kind: str) -> Path:
    """The CPlantBox example parameter file of a kind (from the installed package's data)."""
    import plantbox as pb

    return Path(pb.__file__).parent / "modelparameter" / "structural" / "plant" / KINDS[kind][0]


def frame_days(rng: np.random.Generator, frames: int, first: float, last: float) -> np.ndarray:
    """``frames`` increasing whole days: the span jittered by a few days, the inner days by up to a third of a
    step (irregular scans)."""
    a = first + rng.integers(-2, 3)
    b = last + rng.integers(-4, 5)
    days = np.linspace(a, b, frames)
    step = (b - a) / max(frames - 1, 1)
    days[1:-1] += rng.uniform(-step / 3, step / 3, frames - 2)
    days = np.round(days)
    for j in range(1, frames):  # strictly increasing after rounding
        days[j] = max(days[j], days[j - 1] + 1)
    return days


def make_plant(kind: str, seed: int, jitter: float, plastochron: float) -> object:
    """A CPlantBox plant of a kind, initialised, with the growth rate ``r`` and maximal length ``lmax`` of every
    stem and leaf type scaled by per-plant log-normal factors (sd ``jitter``; ``lmax`` by half of it) and every
    stem and leaf starting to grow ``plastochron / vigour`` days after it is created (``ldelay``): the example
    files start every organ at once, so a plant would never add organs, which real shoots do."""
    import plantbox as pb

    rng = np.random.default_rng(seed)
    vigour, size = math.exp(rng.normal(0, jitter)), math.exp(rng.normal(0, jitter / 2))
    plant = pb.MappedPlant()
    plant.readParameters(str(parameter_file(kind)), verbose=False)
    for ot in (STEM, LEAF):
        for rp in plant.getOrganRandomParameter(ot):
            rp.r = rp.r * vigour
            rp.lmax = rp.lmax * size
            rp.ldelay = plastochron / vigour
    plant.setSeed(seed)
    plant.initialize(False)
    return plant


def shoot_skeleton(plant: object, labels: dict[int, int], spacing: float, min_organ: float = MIN_ORGAN
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plant's shoot now: ``xyz (n, 3)`` mm (base at the origin), ``parent (n,)`` (-1 at the base), ``label
    (n,)``; chains thinned to about ``spacing`` mm; organs shorter than ``min_organ`` mm (not yet visible to a
    scanner) left out with what they carry. ``labels`` maps CPlantBox organ ids to labels, extended here in order
    of appearance."""
    nodes = np.array([[v.x, v.y, v.z] for v in plant.nodes]) * CM_TO_MM
    segs = np.array([[s.x, s.y] for s in plant.segments], dtype=int).reshape(-1, 2)
    keep = np.isin(np.array(plant.organTypes), (STEM, LEAF))
    segs = segs[keep]
    if len(segs) == 0:
        raise RuntimeError("no shoot yet")
    lab: dict[int, int] = {}
    hidden: set[int] = set()
    for organ in sorted(plant.getOrgans(STEM) + plant.getOrgans(LEAF), key=lambda o: o.getId()):
        own = [int(n) for n in list(organ.getNodeIds())[1:]]  # the first node is the parent organ's
        if organ.getLength(True) * CM_TO_MM < min_organ:
            hidden.update(own)
            continue
        label = labels.setdefault(int(organ.getId()), len(labels) + 1)
        lab.update(dict.fromkeys(own, label))
    par = {int(c): int(p) for p, c in segs}
    roots = {int(p) for p, _ in segs} - set(par)
    if len(roots) != 1:
        raise RuntimeError(f"the shoot has {len(roots)} bases")
    base = roots.pop()
    children: dict[int, list[int]] = {}
    for c, p in par.items():
        if c not in hidden:
            children.setdefault(p, []).append(c)
    if base not in children:
        raise RuntimeError("no visible shoot yet")
    lab[base] = lab[min(children[base])]
    # thin chains: keep the base, branch points, tips and a node every ~spacing mm of arc length
    out_ids, out_par = [base], [-1]
    stack = [(base, 0)]  # (kept node, its row)
    while stack:
        start, row = stack.pop()
        for c in sorted(children.get(start, [])):
            prev, arc, node = start, 0.0, c
            while True:
                arc += float(np.linalg.norm(nodes[node] - nodes[prev]))
                kids = children.get(node, [])
                if len(kids) != 1 or arc >= spacing or lab[kids[0]] != lab[node]:
                    break
                prev, node = node, kids[0]
            if arc < MIN_EDGE:  # the same point as the chain's start: its children hang there
                stack.append((node, row))
                continue
            out_ids.append(node)
            out_par.append(row)
            stack.append((node, len(out_ids) - 1))
    ids = np.array(out_ids)
    xyz = nodes[ids] - nodes[base]
    return xyz, np.array(out_par), np.array([lab[i] for i in ids])


def write_swc(path: Path, xyz: np.ndarray, parent: np.ndarray, label: np.ndarray, comment: str) -> None:
    """One SWC file: node ``i`` has id ``i + 1``, radius 1 (unknown)."""
    lines = [f"# {comment}", "# id type x y z radius parent"]
    lines += [f"{i + 1} {int(t)} {x:.3f} {y:.3f} {z:.3f} 1 {p + 1 if p >= 0 else -1}"
              for i, ((x, y, z), p, t) in enumerate(zip(xyz, parent, label))]
    path.write_text("\n".join(lines) + "\n")


def simulate_plant(kind: str, seed: int, folder: Path, frames: int, jitter: float, spacing: float,
                   plastochron: float) -> dict:
    """Grow one plant and write its sequence folder; returns its record for ``population.json``."""
    rng = np.random.default_rng(seed + 7919)
    _, first, last = KINDS[kind]
    days = frame_days(rng, frames, first, last)
    plant = make_plant(kind, seed, jitter, plastochron)
    folder.mkdir(parents=True, exist_ok=True)
    labels: dict[int, int] = {}
    times, nodes, now = {}, [], 0.0
    for d in days:
        plant.simulate(float(d) - now, False)
        now = float(d)
        xyz, parent, label = shoot_skeleton(plant, labels, spacing)
        name = f"day_{int(d):03d}.swc"
        write_swc(folder / name, xyz, parent, label, f"CPlantBox {KINDS[kind][0]} seed {seed} day {d:g}")
        times[name] = float(d)
        nodes.append(len(xyz))
    (folder / "times.json").write_text(json.dumps(times, indent=1) + "\n")
    return {"name": folder.name, "seed": seed, "days": [float(d) for d in days], "nodes": nodes}


def main(argv: list[str] | None = None) -> None:
    """Command line (module doc)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kind", choices=sorted(KINDS), required=True)
    ap.add_argument("--plants", type=int, default=40)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0, help="plant i uses seed 1000 * seed + i + 1")
    ap.add_argument("--jitter", type=float, default=0.15, help="sd of the log growth-rate factor per plant")
    ap.add_argument("--spacing", type=float, default=10.0, help="mm between kept chain nodes")
    ap.add_argument("--plastochron", type=float, default=2.0, help="days from an organ's creation to its growth")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for i in range(a.plants):
        seed = 1000 * a.seed + i + 1
        stdout = os.dup(1)  # CPlantBox prints warnings on stdout from C++
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            try:
                rec = simulate_plant(a.kind, seed, out / f"{a.kind}_{i:02d}", a.frames, a.jitter, a.spacing,
                                     a.plastochron)
            finally:
                sys.stdout.flush()
                os.dup2(stdout, 1)
                os.close(stdout)
        records.append(rec)
        print(f"{rec['name']}: days {rec['days'][0]:g}-{rec['days'][-1]:g}, nodes {rec['nodes'][0]}-{rec['nodes'][-1]}",
              flush=True)
    import plantbox

    meta = {"format": "cplantbox-population", "kind": a.kind, "parameter_file": KINDS[a.kind][0],
            "cplantbox": getattr(plantbox, "__version__", "2.1.1"), "seed": a.seed, "frames": a.frames,
            "jitter": a.jitter, "spacing_mm": a.spacing, "plastochron_days": a.plastochron,
            "units": "mm, z up, base at the origin",
            "type_column": "organ label: 1 + the organ's rank in order of appearance in its plant",
            "plants": records}
    (out / "population.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
