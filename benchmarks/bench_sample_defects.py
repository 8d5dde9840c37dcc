"""What gives generated plants away: the organ model's samples against its training plants, measure by measure.

    python benchmarks/bench_sample_defects.py --model RUN/model.pt --train DATASET [--seeds 10] [--per-seed 4]
    python benchmarks/bench_sample_defects.py --pheno4d tomato [--data DIR] [--seeds 10] [--per-seed 4]

A reader spots a generated plant by what no real one does: a leaf longer than any real leaf, long leaves on a short
stem, leaves crossing in the crown, the same plant twice, organs that vanish or shrink from one frame to the next,
plants too small at mid-growth. Each measure below is computed on the training plants and on ``--seeds`` x
``--per-seed`` samples (``model.sample(per_seed, generator=torch.Generator().manual_seed(seed))``), final frame
unless said, and printed as a markdown table of ``median [p10, p90] max``; then for the distributions a two-sample
KS test and the share of samples beyond the training maximum, the donors (samples that copy one training plant;
organ model only) and the median total length at evenly spaced ages. Training organs that vanish are counted along
the within-sequence registration's tracks (docs/method.md §5), the samples' along their labels.
"""

from __future__ import annotations

import argparse
import math
import pickle
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.stats import ks_2samp
from torch import Tensor

from torch4dtree.bench.trees import default_data_root
from torch4dtree.curves.srvf import interpolate_curve
from torch4dtree.evaluate.model_report import age_columns
from torch4dtree.io import LoadOptions, read_dataset, read_sequence
from torch4dtree.model import FourDTreeModel, OrganModel, load
from torch4dtree.temporal import register_sequence
from torch4dtree.trees import Trees, TreeSequence

UP = 2  # the vertical axis of the plants' coordinates
BASE_FRACTION = 0.1  # a child's base direction: from its first point to 10 % of its length
CROSS_FROM = 0.15  # crossings are looked for from 15 % of each branch's length (away from the shared bases)
CROSS_POINTS = 48  # points per branch in the crossing test
CROSS_TOL = 0.01  # two branches cross when they come within 1 % of the plant's size
SAME_NODE = 1e-6  # siblings whose attachments differ by less than this share one node (they touch at their bases)
TINY = 1e-12  # keeps angles defined for zero-length vectors
SHRINK = 0.95  # an organ shrinks when it is more than 5 % shorter at the next frame
KS_MEASURES = ("l1", "ins", "elev", "div", "pmax", "cross")
BEYOND_MEASURES = ("ratio", "cross_organ")
PHENO4D = {"tomato": ([f"tom_{i}_seq" for i in range(1, 6)], 64),  # the .mat sequences of each kind and their T
           "maize": ([f"maize0{i}_seq" for i in range(1, 5)], 32)}


def cumulative_length(curve: Tensor) -> Tensor:
    """``(T, 3) -> (T,)`` arc length from the curve's first point to each of its points."""
    steps = (curve[1:] - curve[:-1]).norm(dim=-1)
    return torch.cat([torch.zeros(1, dtype=curve.dtype), steps.cumsum(0)])


def frame_stats(tree: Trees) -> dict[str, Any]:
    """The measures of one frame (a one-tree :class:`Trees`).

    Returns ``len1`` / ``len2`` the lengths of the layer-1 (leaves) / layer-2 branches, ``main`` the main stem's
    length, ``total`` all branches', ``n`` the branch count, ``height`` the highest point above the root; per side
    branch ``ins`` its insertion angle (degrees between its base direction and its parent's tangent at its
    attachment: leaves stand off the stem at typical angles), ``elev`` its chord's elevation (degrees above the
    horizontal); ``div`` the divergence (degrees of azimuth) between consecutive organs on the main stem
    (phyllotaxis); ``cross`` the branch pairs, neither parent of the other nor at one node, that come within
    :data:`CROSS_TOL` of the plant's size away from their bases (crossing leaves), and ``cross_per_organ``.
    """
    pts = tree.points.double()
    par = tree.parent.tolist()
    s = tree.s.double()
    L = tree.branch_lengths().double()
    n = len(par)
    depth = tree.depth.tolist()
    out: dict[str, Any] = {"len1": [float(L[i]) for i in range(n) if depth[i] == 1],
                           "len2": [float(L[i]) for i in range(n) if depth[i] == 2],
                           "main": float(L[0]), "total": float(L.sum()), "n": n,
                           "height": float(pts[..., UP].max() - pts[0, 0, UP])}
    ins, elev, az = [], [], []
    for i in range(1, n):
        p = par[i]
        c = pts[i]
        cum = cumulative_length(c)
        if cum[-1] <= 0:
            continue
        k = int(torch.searchsorted(cum, BASE_FRACTION * cum[-1]).clamp(1, len(c) - 1))
        d = c[k] - c[0]
        pc = pts[p]
        pcum = cumulative_length(pc) / max(float(L[p]), TINY)
        j = int(torch.searchsorted(pcum, s[i].clamp(0, 1)).clamp(1, len(pc) - 1))
        t = pc[j] - pc[j - 1]
        cosang = float((d @ t) / (d.norm() * t.norm() + TINY))
        ins.append(math.degrees(math.acos(max(-1, min(1, cosang)))))
        ch = c[-1] - c[0]
        elev.append(math.degrees(math.atan2(float(ch[UP]), float(ch[:2].norm()) + TINY)))
        if p == 0:
            az.append((float(s[i]), math.atan2(float(ch[1]), float(ch[0]))))
    az.sort()
    div = [abs((b[1] - a[1] + math.pi) % (2 * math.pi) - math.pi) * 180 / math.pi for a, b in zip(az[:-1], az[1:])]
    out.update(ins=ins, elev=elev, div=div)
    flat_pts = pts.reshape(-1, 3)
    tol = CROSS_TOL * float((flat_pts.max(0).values - flat_pts.min(0).values).norm())
    cross = 0
    if n > 1:
        grid = torch.linspace(CROSS_FROM, 1, CROSS_POINTS, dtype=pts.dtype)[None].expand(n, -1)
        flat = interpolate_curve(pts, grid).reshape(-1, 3)
        D = torch.cdist(flat, flat).reshape(n, CROSS_POINTS, n, CROSS_POINTS).amin((1, 3))
        for i in range(n):
            for j in range(i + 1, n):
                if par[j] == i or par[i] == j or (par[i] == par[j] and abs(float(s[i] - s[j])) < SAME_NODE):
                    continue
                if D[i, j] < tol:
                    cross += 1
    out["cross"] = cross
    out["cross_per_organ"] = cross / max(n - 1, 1)
    return out


def vanish_labels(seq: TreeSequence) -> tuple[int, int, int]:
    """``(vanishing, shrinking, organ-frames)`` along the organ labels: organs of frame k absent at frame k + 1, and
    present but more than 5 % shorter (real organs do not disappear or shrink while a plant grows)."""
    fr = [seq.frames[i] for i in range(len(seq))]
    van = shr = tot = 0
    for a, b in zip(fr[:-1], fr[1:]):
        la = dict(zip(a.label.tolist(), a.branch_lengths().tolist()))
        lb = dict(zip(b.label.tolist(), b.branch_lengths().tolist()))
        tot += len(la)
        van += sum(k not in lb for k in la)
        shr += sum(k in lb and lb[k] < SHRINK * v for k, v in la.items())
    return van, shr, tot


def vanish_registered(seq: TreeSequence) -> tuple[int, int, int]:
    """:func:`vanish_labels` along the tracks of :func:`~torch4dtree.temporal.register_sequence` (for plants whose
    labels are not organ identities, such as scanned ones)."""
    ident = register_sequence(seq).identity
    lens = seq.frames.branch_lengths()
    ptr = seq.frames.ptr[:-1]
    van = shr = tot = 0
    for k in range(len(seq) - 1):
        a, b = ident[k], ident[k + 1]
        pres = a >= 0
        tot += int(pres.sum())
        van += int((pres & (b < 0)).sum())
        both = pres & (b >= 0)
        la = lens[(a + ptr[k])[both]]
        lb = lens[(b + ptr[k + 1])[both]]
        shr += int((lb < SHRINK * la).sum())
    return van, shr, tot


def quantiles(a: np.ndarray) -> str:
    """``median [p10, p90] max`` of ``a``, or ``n/a`` when it is empty."""
    if len(a) == 0:
        return "n/a"
    return f"{np.percentile(a, 50):.3g} [{np.percentile(a, 10):.3g}, {np.percentile(a, 90):.3g}] max {a.max():.3g}"


def describe(seqs: list[TreeSequence], labelled: bool) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """One population's table cells (measure -> text) and the arrays the tests between populations compare:
    ``l1`` leaf lengths over all frames, ``ins`` / ``elev`` / ``div`` angles, ``pmax`` the longest leaf per plant,
    ``cross`` crossings per plant, ``ratio`` longest leaf / main stem, ``cross_organ`` crossings per organ (final
    frames). ``labelled``: count vanishing organs along the labels, else along registered tracks."""
    fin = [frame_stats(s.frames[len(s) - 1]) for s in seqs]
    allf = [frame_stats(s.frames[i]) for s in seqs for i in range(len(s))]

    def cat(key: str, src: list[dict[str, Any]]) -> np.ndarray:
        return np.array([x for f in src for x in f[key]])

    def per_plant(key: str) -> np.ndarray:
        return np.array([f[key] for f in fin])

    l1, l2 = cat("len1", allf), cat("len2", allf)
    pmax = np.array([max(f["len1"] or [0]) for f in fin])
    ratio = np.array([max(f["len1"] or [0]) / f["main"] for f in fin])
    v = [vanish_labels(s) if labelled else vanish_registered(s) for s in seqs]
    van, shr, tot = map(sum, zip(*v))
    res = {
        "plants": str(len(seqs)),
        "leaf (layer-1) length, all frames": quantiles(l1),
        "layer-2 length, all frames": quantiles(l2),
        "longest layer-1 organ per plant (final)": quantiles(pmax),
        "longest leaf / main stem (final)": quantiles(ratio),
        "main stem (final)": quantiles(per_plant("main")),
        "total length (final)": quantiles(per_plant("total")),
        "height (final)": quantiles(per_plant("height")),
        "branches (final)": quantiles(per_plant("n")),
        "insertion angle deg (final)": quantiles(cat("ins", fin)),
        "chord elevation deg (final)": quantiles(cat("elev", fin)),
        "divergence on main deg (final)": quantiles(cat("div", fin)),
        "crossings per plant (final)": quantiles(per_plant("cross")),
        "crossings per organ (final)": quantiles(per_plant("cross_per_organ")),
        "organ-frames vanishing next frame": f"{van}/{tot} = {100 * van / max(tot, 1):.2f} %",
        "organ-frames shrinking >5 % next frame": f"{shr}/{tot} = {100 * shr / max(tot, 1):.2f} %",
    }
    arrays = {"l1": l1, "ins": cat("ins", fin), "elev": cat("elev", fin), "div": cat("div", fin), "pmax": pmax,
              "cross": per_plant("cross"), "ratio": ratio, "cross_organ": per_plant("cross_per_organ")}
    return res, arrays


def donors(model: OrganModel, seeds: int, n_per: int) -> tuple[np.ndarray, int, int]:
    """Copies of training plants: per sample the share of its organs taken from its most used training plant (1: the
    whole plant is one training plant), the number of sample pairs with identical organ choices, and of samples.
    Samples are drawn as in :func:`samples` (the same seeds); :meth:`OrganModel.grow` tells which training organ each
    sample organ copies."""
    links = model.links()
    shares, sigs = [], []
    for seed in range(seeds):
        z = model.sample_coefficients(n_per, torch.Generator().manual_seed(seed))
        for row in model.grow([int(x) for x in z.reshape(-1)]).chosen:
            r = row[row >= 0].numpy()
            pl = links.plant[r]
            shares.append(np.bincount(pl).max() / len(pl))
            sigs.append(tuple(r.tolist()))
    same = sum(a == b for i, a in enumerate(sigs) for b in sigs[i + 1:])
    return np.array(shares), same, len(sigs)


def totals_by_age(seqs: list[TreeSequence], columns: int = 5) -> list[list[tuple[int, float]]]:
    """Per plant, at ``columns`` evenly spaced normalised ages (:func:`age_columns`), its branch count and total
    length (a plant too small at mid-growth shows here, not in its final frame)."""
    out = []
    for s in seqs:
        a = age_columns(s, columns)
        f = a.frames
        totals = torch.stack([f[i].branch_lengths().sum() for i in range(len(a))])
        out.append([(int(n), float(t)) for n, t in zip(f.num_branches, totals)])
    return out


def median_by_age(rows: list[list[tuple[int, float]]], columns: int) -> str:
    """The median total length at each age column over the plants that have every column."""
    full = np.array([[t for _, t in r] for r in rows if len(r) == columns])
    if len(full) == 0:
        return "n/a"
    return " ".join(f"{x:.0f}" for x in np.median(full, axis=0)) + f" ({len(full)} of {len(rows)} plants)"


def samples(model: OrganModel | FourDTreeModel, seeds: int, n_per: int) -> list[TreeSequence]:
    """``n_per`` samples of ``model`` for each seed ``0 .. seeds - 1``."""
    return [p for seed in range(seeds) for p in model.sample(n_per, generator=torch.Generator().manual_seed(seed))]


def fit_pheno4d(kind: str, folder: str | Path | None = None) -> tuple[OrganModel, list[TreeSequence]]:
    """The default :class:`OrganModel` fitted on the Pheno4D ``.mat`` plants of one kind (tomato at T = 64, maize at
    T = 32; no plant held out), and those plants. ``folder``: the ``mat`` folder (default under
    :func:`~torch4dtree.bench.trees.default_data_root`)."""
    names, T = PHENO4D[kind]
    root = Path(folder) if folder is not None else default_data_root() / "mat"
    seqs = [read_sequence(root / n, LoadOptions(T=T)).sequence for n in names]
    return OrganModel().fit(seqs), seqs


def read_training(source: str, T: int) -> list[TreeSequence]:
    """The training plants: a dataset folder (read at ``T`` points per branch) or a pickled list of 4D trees."""
    if source.endswith(".pkl"):
        with open(source, "rb") as f:
            return pickle.load(f)
    return [loaded.sequence for loaded in read_dataset(source, LoadOptions(T=T))]


def report(model: OrganModel | FourDTreeModel, train: list[TreeSequence], seeds: int, n_per: int,
           labelled_train: bool = False, columns: int = 5) -> dict[str, np.ndarray]:
    """Print every measure for ``train`` and the samples; return both populations' arrays (``train_*`` /
    ``sample_*``)."""
    gen = samples(model, seeds, n_per)
    r_train, a_train = describe(train, labelled_train)
    r_samp, a_samp = describe(gen, True)
    print(f"| measure | training plants ({len(train)}) | samples ({len(gen)}: {seeds} seeds x {n_per}) |")
    print("|---|---|---|")
    for k in r_train:
        print(f"| {k} | {r_train[k]} | {r_samp[k]} |")
    for k in KS_MEASURES:
        if len(a_train[k]) and len(a_samp[k]):
            ks = ks_2samp(a_train[k], a_samp[k])
            print(f"KS {k}: D={ks.statistic:.3f} p={ks.pvalue:.3g}  share of samples > training max: "
                  f"{100 * np.mean(a_samp[k] > a_train[k].max()):.1f} %")
    for k in BEYOND_MEASURES:
        print(f"beyond training max {k}: {100 * np.mean(a_samp[k] > a_train[k].max()):.1f} % "
              f"(max {a_samp[k].max():.3g} vs {a_train[k].max():.3g})")
    if isinstance(model, OrganModel):
        shares, same, n = donors(model, seeds, n_per)
        print(f"donors: whole copies of one training plant {100 * np.mean(shares == 1):.1f} %, median top-donor "
              f"share {np.median(shares):.2f}, identical organ choices {same} of {n * (n - 1) // 2} pairs; kernel "
              f"width {model.donor_bandwidth():.3g} sd ({len(model.summary)} training plants)")
    print(f"median total length at {columns} ages: training {median_by_age(totals_by_age(train, columns), columns)}"
          f" / samples {median_by_age(totals_by_age(gen, columns), columns)}")
    return {f"train_{k}": v for k, v in a_train.items()} | {f"sample_{k}": v for k, v in a_samp.items()}


def main(argv: list[str] | None = None) -> None:
    """Command line: see the module doc."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", help="a saved model (RUN/model.pt of `torch4dtree fit`); needs --train")
    src.add_argument("--pheno4d", choices=sorted(PHENO4D),
                     help="fit the default organ model on the Pheno4D .mat plants of this kind; they are the training "
                          "plants")
    ap.add_argument("--train", help="the model's training plants: the dataset folder it was fitted on, or a .pkl of "
                                    "a list of TreeSequence")
    ap.add_argument("--T", type=int, default=32, help="points per branch when reading --train (default 32)")
    ap.add_argument("--data", help="the Pheno4D mat folder (default: $TORCH4DTREE_PHENO4D/mat or ../shared/data/"
                                   "pheno4d/mat)")
    ap.add_argument("--seeds", type=int, default=10, help="sample with generator seeds 0 .. N-1 (default 10)")
    ap.add_argument("--per-seed", type=int, default=4, help="samples per seed (default 4)")
    ap.add_argument("--labelled-train", action="store_true",
                    help="count the training organs that vanish along their labels (synthetic plants' true organs) "
                         "instead of the within-sequence registration's tracks")
    ap.add_argument("--arrays", help="pickle the measured arrays (dict of numpy arrays) to this file")
    args = ap.parse_args(argv)
    if args.model and not args.train:
        ap.error("--model needs --train (the plants it was fitted on)")
    warnings.simplefilter("ignore")
    if args.pheno4d:
        model, train = fit_pheno4d(args.pheno4d, args.data)
    else:
        model, train = load(args.model), read_training(args.train, args.T)
    arrays = report(model, train, args.seeds, args.per_seed, args.labelled_train)
    if args.arrays:
        with open(args.arrays, "wb") as f:
            pickle.dump(arrays, f)


if __name__ == "__main__":
    main()
