"""Measure what gives samples away: organ lengths, crossings, insertion/divergence angles, organs vanishing.

python defects.py MODEL.pt TRAIN_SOURCE [seeds]   (TRAIN_SOURCE: a dataset folder or a .pkl of sequences)
"""
import math, pickle, sys, warnings
from pathlib import Path
import numpy as np
import torch
from torch4dtree.model import load
from torch4dtree.io import LoadOptions, read_dataset
from torch4dtree.curves.srvf import interpolate_curve
from torch4dtree.temporal.within import register_sequence

UPI = 2


def load_any(path):
    d = torch.load(path, weights_only=False)
    if isinstance(d, dict) and "state" in d and "settings" in d:
        from torch4dtree.model.organs import OrganModel
        m = OrganModel(d["settings"]); m.load_state_dict(d["state"]); return m
    return load(path)


def frame_stats(tr):
    """per frame tree (single tree Trees): dict of measures"""
    pts = tr.points.double()
    par = tr.parent.tolist()
    s = tr.s.double()
    L = tr.branch_lengths().double()
    n = len(par)
    depth = [0] * n
    for i in range(n):
        depth[i] = 0 if par[i] < 0 else depth[par[i]] + 1
    out = {"len1": [float(L[i]) for i in range(n) if depth[i] == 1],
           "len2": [float(L[i]) for i in range(n) if depth[i] == 2],
           "main": float(L[0]), "total": float(L.sum()), "n": n,
           "height": float(pts[..., UPI].max() - pts[0, 0, UPI])}
    # insertion angle (deg) between child's base tangent and parent's tangent at s; chord elevation
    ins, elev, az = [], [], []
    for i in range(1, n):
        p = par[i]
        c = pts[i]
        cum = torch.cat([torch.zeros(1, dtype=c.dtype), (c[1:] - c[:-1]).norm(dim=-1).cumsum(0)])
        if cum[-1] <= 0:
            continue
        k = int(torch.searchsorted(cum, 0.1 * cum[-1]).clamp(1, len(c) - 1))
        d = c[k] - c[0]
        pc = pts[p]
        pcum = torch.cat([torch.zeros(1, dtype=c.dtype), (pc[1:] - pc[:-1]).norm(dim=-1).cumsum(0)]) / max(float(L[p]), 1e-12)
        j = int(torch.searchsorted(pcum, s[i].clamp(0, 1)).clamp(1, len(pc) - 1))
        t = pc[j] - pc[j - 1]
        cosang = float((d @ t) / (d.norm() * t.norm() + 1e-12))
        ins.append(math.degrees(math.acos(max(-1, min(1, cosang)))))
        ch = c[-1] - c[0]
        elev.append(math.degrees(math.atan2(float(ch[UPI]), float(ch[:2].norm()) + 1e-12)))
        if p == 0:
            az.append((float(s[i]), math.atan2(float(ch[1]), float(ch[0]))))
    az.sort()
    div = [abs((b[1] - a[1] + math.pi) % (2 * math.pi) - math.pi) * 180 / math.pi for a, b in zip(az[:-1], az[1:])]
    out.update(ins=ins, elev=elev, div=div)
    # crossings: non parent-child pairs whose curves come within 1 % of the plant's size, away from both bases
    size = float((pts.reshape(-1, 3).max(0).values - pts.reshape(-1, 3).min(0).values).norm())
    tol = 0.01 * size
    dense = interpolate_curve(pts, torch.linspace(0.15, 1, 48, dtype=pts.dtype)[None].expand(n, -1)) if n > 1 else None
    cross = 0
    if dense is not None:
        flat = dense.reshape(-1, 3)
        D = torch.cdist(flat, flat).reshape(n, 48, n, 48).amin((1, 3))
        for i in range(n):
            for j in range(i + 1, n):
                if par[j] == i or par[i] == j or (par[i] == par[j] and abs(float(s[i] - s[j])) < 1e-6):
                    continue
                if D[i, j] < tol:
                    cross += 1
    out["cross"] = cross
    out["cross_per_organ"] = cross / max(n - 1, 1)
    return out


def vanish_labels(seq):
    """organs (labels) present in frame k, absent in k+1; and shrinking > 5 %"""
    fr = [seq.frames[i] for i in range(len(seq))]
    van = shr = tot = 0
    for a, b in zip(fr[:-1], fr[1:]):
        la = dict(zip(a.label.tolist(), a.branch_lengths().tolist()))
        lb = dict(zip(b.label.tolist(), b.branch_lengths().tolist()))
        tot += len(la)
        van += sum(k not in lb for k in la)
        shr += sum(k in lb and lb[k] < 0.95 * v for k, v in la.items())
    return van, shr, tot


def vanish_registered(seq):
    al = register_sequence(seq)
    ident = al.identity
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
        shr += int((lb < 0.95 * la).sum())
    return van, shr, tot


def describe(name, seqs, labelled):
    fin = [frame_stats(s.frames[len(s) - 1]) for s in seqs]
    allf = [frame_stats(s.frames[i]) for s in seqs for i in range(len(s))]
    cat = lambda key, src: np.array([x for f in src for x in f[key]])
    l1 = cat("len1", allf)
    l2 = cat("len2", allf)
    per_plant_max = [max(f["len1"] or [0]) for f in fin]
    q = lambda a: "n/a" if len(a) == 0 else f"{np.percentile(a, 50):.3g} [{np.percentile(a, 10):.3g}, {np.percentile(a, 90):.3g}] max {a.max():.3g}"
    v = [vanish_labels(s) if labelled else vanish_registered(s) for s in seqs]
    van, shr, tot = map(sum, zip(*v))
    res = {
        "plants": len(seqs),
        "leaf (layer-1) length, all frames": q(l1),
        "layer-2 length, all frames": q(l2),
        "longest layer-1 organ per plant (final)": q(np.array(per_plant_max)),
        "longest leaf / main stem (final)": q(np.array([max(f["len1"] or [0]) / f["main"] for f in fin])),
        "main stem (final)": q(np.array([f["main"] for f in fin])),
        "total length (final)": q(np.array([f["total"] for f in fin])),
        "height (final)": q(np.array([f["height"] for f in fin])),
        "branches (final)": q(np.array([f["n"] for f in fin])),
        "insertion angle deg (final)": q(cat("ins", fin)),
        "chord elevation deg (final)": q(cat("elev", fin)),
        "divergence on main deg (final)": q(cat("div", fin)),
        "crossings per plant (final)": q(np.array([f["cross"] for f in fin])),
        "crossings per organ (final)": q(np.array([f["cross_per_organ"] for f in fin])),
        "organ-frames vanishing next frame": f"{van}/{tot} = {100 * van / max(tot, 1):.2f} %",
        "organ-frames shrinking >5 % next frame": f"{shr}/{tot} = {100 * shr / max(tot, 1):.2f} %",
    }
    arrays = {"l1": l1, "ins": cat("ins", fin), "elev": cat("elev", fin), "div": cat("div", fin),
              "pmax": np.array(per_plant_max), "cross": np.array([f["cross"] for f in fin])}
    return res, arrays


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    model = load_any(sys.argv[1])
    src = sys.argv[2]
    seeds = int(sys.argv[3]) if len(sys.argv) > 3 else 10
    n_per = int(sys.argv[4]) if len(sys.argv) > 4 else 4
    if src.endswith(".pkl"):
        train = pickle.load(open(src, "rb"))
    else:
        T = int(sys.argv[5]) if len(sys.argv) > 5 else 32
        train = [l.sequence for l in read_dataset(src, LoadOptions(T=T))]
    samples = [p for seed in range(seeds) for p in model.sample(n_per, generator=torch.Generator().manual_seed(seed))]
    r_train, a_train = describe("train", train, False)
    r_samp, a_samp = describe("samples", samples, True)
    from scipy.stats import ks_2samp
    print(f"| measure | training plants ({len(train)}) | samples ({len(samples)}: {seeds} seeds x {n_per}) |")
    print("|---|---|---|")
    for k in r_train:
        print(f"| {k} | {r_train[k]} | {r_samp[k]} |")
    for k in ("l1", "ins", "elev", "div", "pmax", "cross"):
        if len(a_train[k]) and len(a_samp[k]):
            ks = ks_2samp(a_train[k], a_samp[k])
            print(f"KS {k}: D={ks.statistic:.3f} p={ks.pvalue:.3g}  share of samples > training max: {100 * np.mean(a_samp[k] > a_train[k].max()):.1f} %")
    pickle.dump((a_train, a_samp), open(src.rstrip('/') + ".arrays.pkl" if not src.endswith('.pkl') else src + ".arrays.pkl", "wb"))


def donors(model, seeds, n_per):
    """per sample: share of its organs copied from its most used training plant; pairs of samples with identical
    organ choice"""
    links = model.links()
    shares, sigs = [], []
    for seed in range(seeds):
        z = model.sample_coefficients(n_per, torch.Generator().manual_seed(seed))
        chosen, *_ = model._grow([int(x) for x in z.reshape(-1)])
        for row in chosen:
            r = row[row >= 0].numpy()
            pl = links.plant[r]
            shares.append(np.bincount(pl).max() / len(pl))
            sigs.append(tuple(r.tolist()))
    same = sum(a == b for i, a in enumerate(sigs) for b in sigs[i + 1:])
    return np.array(shares), same, len(sigs)


def per_age(model, train, seeds, n_per, cols=5):
    from torch4dtree.evaluate.model_report import age_columns
    samples = [p for seed in range(seeds) for p in model.sample(n_per, generator=torch.Generator().manual_seed(seed))]
    def table(seqs):
        out = []
        for s in seqs:
            a = age_columns(s, cols)
            f = a.frames
            out.append([(int(n), float(l)) for n, l in zip(f.num_branches, torch.stack([f[i].branch_lengths().sum() for i in range(len(a))]))])
        return out
    return table(train), table(samples)


def fit_pheno4d(kind: str, folder: str = "/work/shared/data/pheno4d/mat"):
    """The default OrganModel fitted on the Pheno4D .mat plants of one kind (tomato T = 64, maize T = 32), and them."""
    from torch4dtree.io import LoadOptions, read_sequence
    from torch4dtree.model.organs import OrganModel

    names = [f"tom_{i}_seq" for i in range(1, 6)] if kind == "tomato" else [f"maize0{i}_seq" for i in range(1, 5)]
    seqs = [read_sequence(Path(folder) / n, LoadOptions(T=64 if kind == "tomato" else 32)).sequence for n in names]
    return OrganModel().fit(seqs), seqs
