"""Populations of growing plants from an independent simulator (CPlantBox), as dataset folders.

Benchmark data source, never run in CI: the plants come from CPlantBox (``pip install cplantbox``, see
``benchmarks/requirements.txt``), a functional-structural plant model whose example parameter files (shipped in
its package data, ``plantbox/modelparameter/structural/plant/``) describe real species. Nobody on this project
designed these shapes, so they test whether a generative model reproduces plants it did not help to invent.

Each plant is one CPlantBox simulation (its own random seed: the parameter files' standard deviations apply) with a
per-plant jitter of the growth rates and maximal lengths (a log-normal factor, ``--jitter``) and organs that
start growing ``--plastochron`` days after they are created (so organs appear over time), observed on
``--frames`` irregular days in the kind's span (:data:`KINDS`, jittered per plant; ``--same-days``: every plant on
the same evenly spaced days, for comparisons across plants). Kind ``tree`` is a young woody tree from a parameter
file of ours (``benchmarks/params/young_tree.xml``: a leader with 3-5 scaffolds, secondary shoots and spurs, no
leaves, shoots bent by tropisms and random turns; its buds break ``ldelay`` days after they form). Each frame is
the shoot (stems and leaf midribs; roots and the seed dropped; organs under 2 mm, just created, left out), a tree
rooted at the stem base:

* written as SWC (``id type x y z radius parent``), millimetres, z up, the base at the origin (the lowest point
  but for drooping leaves); chains between branch points and tips are thinned to about ``--spacing`` mm;
* ``type``: every node's organ, by botanical position (:func:`botanical_label`: ``1`` then per level two digits for
  the node on the parent, in the order nodes grew along it, and one for the slot at that node, leaves 1-4 and
  stems 5-9; ``1015032`` = the 2nd leaf at node 3 of the main shoot; the stem base takes the main shoot's label),
  so one organ keeps its label over a plant's frames and the k-th leaf on a stem, or the shoot at node n, has the
  same label in every plant of a kind;
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
    "tree": ("young_tree.xml", 20.0, 200.0),  # ours, in benchmarks/params: a young woody tree (leader, scaffolds)
}
PARAMS = Path(__file__).resolve().parent / "params"  # parameter files written for these benchmarks
STEM, LEAF = 3, 4  # CPlantBox organ types kept (1 seed, 2 root dropped)
CM_TO_MM = 10.0
MIN_ORGAN = 2.0  # mm: shorter organs are left out (just created, not yet seen by a scanner)
MIN_EDGE = 0.01  # mm: shorter edges would vanish in the files' 3 decimals and make zero-length branches


def parameter_file(kind: str) -> Path:
    """The parameter file of a kind: ``benchmarks/params`` if it is there, else the CPlantBox example of that name
    (from the installed package's data)."""
    import plantbox as pb

    ours = PARAMS / KINDS[kind][0]
    examples = Path(pb.__file__).parent / "modelparameter" / "structural" / "plant"
    return ours if ours.is_file() else examples / KINDS[kind][0]


def frame_days(rng: np.random.Generator, frames: int, first: float, last: float, jitter: bool = True) -> np.ndarray:
    """``frames`` increasing whole days: the span jittered by a few days, the inner days by up to a third of a
    step (irregular scans); without ``jitter`` evenly spaced over the span (every plant on the same days)."""
    if not jitter:
        return np.round(np.linspace(first, last, frames))
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
    stem and leaf type whose file sets no delay (``ldelay < 0``) starting to grow ``plastochron / vigour`` days
    after it is created (the example files start every organ at once, so a plant would never add organs, which
    real shoots do); delays a file sets (the tree's buds) are divided by the vigour."""
    import plantbox as pb

    rng = np.random.default_rng(seed)
    vigour, size = math.exp(rng.normal(0, jitter)), math.exp(rng.normal(0, jitter / 2))
    plant = pb.MappedPlant()
    plant.readParameters(str(parameter_file(kind)), verbose=False)
    for ot in (STEM, LEAF):
        for rp in plant.getOrganRandomParameter(ot):
            rp.r = rp.r * vigour
            rp.lmax = rp.lmax * size
            rp.ldelay = (plastochron if rp.ldelay < 0 else rp.ldelay) / vigour
    plant.setSeed(seed)
    plant.initialize(False)
    return plant


def _position(organ: object) -> tuple[int, int]:
    """``(node, slot)`` of an organ on its parent: the node is the rank (1-based) of its attachment point among the
    parent's attachment points of shoot organs (in the order they grew along the parent); the slot is its place at
    that node by kind: leaves 1-4, stems 5-9 (in creation order), so a leaf keeps its slot whether a shoot grows
    beside it or not."""
    parent = organ.getParent()
    kids = [parent.getChild(i) for i in range(parent.getNumberOfChildren())]
    kids = [k for k in kids if k.organType() in (STEM, LEAF)]
    nodes = sorted({k.parentNI for k in kids})
    same = sorted(k.getId() for k in kids if k.parentNI == organ.parentNI and k.organType() == organ.organType())
    slot = same.index(organ.getId()) + (1 if organ.organType() == LEAF else 5)
    if nodes.index(organ.parentNI) >= 99 or slot > (4 if organ.organType() == LEAF else 9):
        raise RuntimeError(f"organ {organ.getId()}: node {nodes.index(organ.parentNI) + 1}, slot {slot} do not fit")
    return nodes.index(organ.parentNI) + 1, slot


def botanical_label(organ: object) -> int:
    """The organ's botanical position as an integer: ``1`` followed by three digits per level from the seed down,
    two for the node it grows from on its parent and one for its slot at that node (:func:`_position`: leaves
    1-4, stems 5-9). ``1015032`` is the 2nd leaf at node 3 of the main shoot (node 1, slot 5 on the seed): the
    same number names the same position in every frame of a plant and in every plant of a kind (the k-th leaf on
    a stem, the shoot at node n). At most five levels (16 digits, exact in a float64); never 99 (the package's
    spur label) nor -1."""
    digits = []
    while organ.organType() in (STEM, LEAF):
        node, slot = _position(organ)
        digits.append(f"{node:02d}{slot}")
        organ = organ.getParent()
    if len(digits) > 5:
        raise RuntimeError(f"botanical position {digits[::-1]} is deeper than five levels")
    return int("1" + "".join(reversed(digits)))


def botanical_path(label: int) -> str:
    """``1015032`` -> ``"1.5/3.2"`` (``node.slot`` per level, :func:`botanical_label` read back)."""
    digits = str(label)[1:]
    return "/".join(f"{int(digits[i:i + 2])}.{digits[i + 2]}" for i in range(0, len(digits), 3))


def shoot_skeleton(plant: object, spacing: float, min_organ: float = MIN_ORGAN
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plant's shoot now: ``xyz (n, 3)`` mm (base at the origin), ``parent (n,)`` (-1 at the base), ``label
    (n,)``: every node's organ (:func:`botanical_label`; the base, which CPlantBox gives to the seed, takes the
    main shoot's); chains thinned to about ``spacing`` mm (a node is kept wherever the organ changes); organs
    shorter than ``min_organ`` mm (not yet visible to a scanner) left out with what they carry."""
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
        lab.update(dict.fromkeys(own, botanical_label(organ)))
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
                   plastochron: float, same_days: bool = False) -> dict:
    """Grow one plant and write its sequence folder; returns its record for ``population.json``."""
    rng = np.random.default_rng(seed + 7919)
    _, first, last = KINDS[kind]
    days = frame_days(rng, frames, first, last, jitter=not same_days)
    plant = make_plant(kind, seed, jitter, plastochron)
    folder.mkdir(parents=True, exist_ok=True)
    times, nodes, now = {}, [], 0.0
    for d in days:
        plant.simulate(float(d) - now, False)
        now = float(d)
        xyz, parent, label = shoot_skeleton(plant, spacing)
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
    ap.add_argument("--same-days", action="store_true",
                    help="every plant observed on the same evenly spaced days (for comparisons across plants)")
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
                                     a.plastochron, a.same_days)
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
            "jitter": a.jitter, "spacing_mm": a.spacing, "plastochron_days": a.plastochron, "same_days": a.same_days,
            "units": "mm, z up, base at the origin",
            "type_column": "organ label: its botanical position, 1 then three digits per level from the seed down "
                           "(two: the node on the parent in growth order; one: the slot there, leaves 1-4, stems 5-9): "
                           "1015032 = the 2nd leaf at node 3 of the main shoot",
            "plants": records}
    (out / "population.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
