"""Benchmark of the curve registration engine against fdasrsf (when it is importable).

Both tools register the same unit-length 3D open curves with an SO(3) rotation and a DP warp; both
results are scored with OUR discrete energy ``||q_ref - O warp_srvf(q_mov, gamma)||^2`` (fdasrsf's
returned warp and rotation are applied to our curves), so the energy ratio compares the optimisers,
not two discretisations. fdasrsf is optional: its fields are ``None`` when it is not installed.
"""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ..curves.register import dp_warp, register_curves
from ..curves.rotation import random_rotation
from ..curves.srvf import curve_length, resample_polylines, srvf, srvf_sq_distance, warp_curve
from ..curves.warps import random_warp
from ..evaluate.stats import summary

__all__ = ["benchmark_curves", "curve_pairs", "pheno4d_paths", "smooth_random_curves"]

MIN_LENGTH = 1e-12  # a path of coincident points keeps a finite scale
TIE_TOL = 1e-9  # relative: an energy within rounding of the reference's is "not worse"


def smooth_random_curves(B: int, T: int, d: int = 3, generator: torch.Generator | None = None,
                         modes: int = 5) -> Tensor:
    """Smooth random curves of unit length ``(B, T, d)``: random Fourier modes with amplitudes ``1/k``."""
    s = torch.linspace(0, 1, T, dtype=torch.float64)
    k = torch.arange(1, modes + 1, dtype=torch.float64)
    c = torch.randn(B, modes, d, generator=generator, dtype=torch.float64) / k[:, None]
    ph = torch.rand(B, modes, d, generator=generator, dtype=torch.float64) * 2 * math.pi
    x = torch.einsum("bkd,bkdt->btd", c, torch.sin(math.pi * k[None, :, None, None] * s + ph[..., None]))
    return x / curve_length(x)[:, None, None]


def helices(B: int, T: int, generator: torch.Generator | None = None) -> Tensor:
    """Unit-length helices with random radius, pitch and number of turns ``(B, T, 3)``."""
    s = torch.linspace(0, 1, T, dtype=torch.float64)
    turns = 1 + 2 * torch.rand(B, 1, generator=generator, dtype=torch.float64)
    radius = 0.5 + torch.rand(B, 1, generator=generator, dtype=torch.float64)
    pitch = 0.5 + 2 * torch.rand(B, 1, generator=generator, dtype=torch.float64)
    ang = 2 * math.pi * turns * s
    x = torch.stack([radius * torch.cos(ang), radius * torch.sin(ang), pitch * s.expand(B, T)], -1)
    return x / curve_length(x)[:, None, None]


def pheno4d_paths(root: str | Path, T: int, per_file: int = 4, min_nodes: int = 20) -> Tensor:
    """The ``per_file`` longest root-to-leaf paths of every Pheno4D SWC file, resampled to ``T`` points.

    Returns ``(N, T, 3)`` unit-length curves (empty if the folder has no SWC file).
    """
    from ..io.swc import read_swc_skeleton

    paths: list[np.ndarray] = []
    for f in sorted(Path(root).glob("*/*.swc")):
        sk = read_swc_skeleton(f, repair=True)
        parent = sk.parent
        is_leaf = np.ones(len(parent), bool)
        is_leaf[parent[parent >= 0]] = False
        found = []
        for leaf in np.flatnonzero(is_leaf):
            chain = [leaf]
            while parent[chain[-1]] >= 0:
                chain.append(parent[chain[-1]])
            if len(chain) >= min_nodes:
                found.append(sk.xyz[chain[::-1]])
        found.sort(key=len, reverse=True)
        paths.extend(found[:per_file])
    if not paths:
        return torch.zeros(0, T, 3, dtype=torch.float64)
    n = max(len(p) for p in paths)
    pts = torch.zeros(len(paths), n, 3, dtype=torch.float64)
    for i, p in enumerate(paths):
        pts[i, : len(p)] = torch.as_tensor(p, dtype=torch.float64)
        pts[i, len(p):] = pts[i, len(p) - 1]
    counts = torch.tensor([len(p) for p in paths])
    beta = resample_polylines(pts, counts, T)
    beta = beta - beta[:, :1]
    return beta / curve_length(beta).clamp_min(MIN_LENGTH)[:, None, None]


def curve_pairs(kind: str, B: int, T: int, generator: torch.Generator,
                pheno4d: str | Path | None = None) -> tuple[Tensor, Tensor]:
    """``(moving, reference)`` pairs ``(B, T, 3)`` of one kind.

    ``"random"``: a smooth random curve and a perturbed, randomly warped and rotated copy;
    ``"helix"``: a helix and a randomly warped and rotated copy; ``"pheno4d"``: two real plant
    paths (random pairs of root-to-leaf paths, randomly rotated).
    """
    if kind == "random":
        ref = smooth_random_curves(B, T, generator=generator)
        mov = ref + 0.15 * smooth_random_curves(B, T, generator=generator)
        mov = mov / curve_length(mov)[:, None, None]
    elif kind == "helix":
        ref = helices(B, T, generator)
        mov = ref
    elif kind == "pheno4d":
        paths = pheno4d_paths(pheno4d or "", T)
        if len(paths) < 2:
            raise FileNotFoundError(f"no Pheno4D SWC paths under {pheno4d}")
        i = torch.randint(len(paths), (B,), generator=generator)
        j = (i + 1 + torch.randint(len(paths) - 1, (B,), generator=generator)) % len(paths)
        ref, mov = paths[i], paths[j]
    else:
        raise ValueError(f"unknown pair kind {kind!r}")
    if kind != "pheno4d":
        mov = warp_curve(mov, random_warp(B, T, generator=generator, strength=0.5))
    mov = mov @ random_rotation(B, generator=generator).transpose(-1, -2)
    return mov, ref


def _fdasrsf() -> Any | None:
    try:
        import fdasrsf.curve_functions as cf  # optional, GPL: only called, never copied
    except Exception:  # noqa: BLE001 - any import failure means "not available"
        return None
    return cf


def _fdasrsf_register(cf: Any, mov: Tensor, ref: Tensor, rotation: bool) -> tuple[Tensor, Tensor]:
    """fdasrsf's open-curve registration of one pair (its default: one Procrustes rotation, then one DP);
    returns its warp ``(T,)`` and rotation ``(3, 3)``."""
    b1 = (ref - ref.mean(0)).T.contiguous().numpy().copy()
    b2 = (mov - mov.mean(0)).T.contiguous().numpy().copy()
    _, _, R, gam = cf.find_rotation_and_seed_coord(b1, b2, closed=0, rotation=rotation, method="DP")
    return torch.as_tensor(np.asarray(gam), dtype=torch.float64), torch.as_tensor(np.asarray(R), dtype=torch.float64)


def _fdasrsf_iterated(cf: Any, mov: Tensor, ref: Tensor, rounds: int = 5) -> tuple[Tensor, Tensor]:
    """fdasrsf alternated: its registration, then ``rounds`` x (optimal rotation of the warped SRVF with
    ``find_best_rotation``, its DP again on the rotated curve). Returns the best (warp, rotation) seen,
    by our discrete energy, so it is never worse than fdasrsf's default."""
    from fdasrsf.utility_functions import invertGamma

    gam, R = _fdasrsf_register(cf, mov, ref, rotation=True)
    b1 = (ref - ref.mean(0)).T.contiguous().numpy().copy()
    b2 = (mov - mov.mean(0)).T.contiguous().numpy().copy()
    q1 = cf.curve_to_q(b1)[0]
    best = (float(_our_energy(mov[None], ref[None], gam[None], R[None])[0]), gam, R)
    Rn = R.numpy()
    for _ in range(rounds):
        b2w = cf.group_action_by_gamma_coord(Rn @ b2, gam.numpy())
        _, Rd = cf.find_best_rotation(q1, cf.curve_to_q(b2w)[0])
        Rn = Rd @ Rn
        g = invertGamma(cf.optimum_reparam_curve(cf.curve_to_q(Rn @ b2)[0], q1, 0.0, "DP"))
        gam, R = torch.as_tensor(np.asarray(g), dtype=torch.float64), torch.as_tensor(Rn, dtype=torch.float64)
        e = float(_our_energy(mov[None], ref[None], gam[None], R[None])[0])
        if e < best[0]:
            best = (e, gam, R)
    return best[1], best[2]


def _our_energy(mov: Tensor, ref: Tensor, gamma: Tensor, R: Tensor) -> Tensor:
    """Our discrete energy of moving curves under warps ``gamma`` then rotations ``R``: on the curves' own
    ``T``-point grid (the grid our DP optimises on)."""
    return srvf_sq_distance(srvf(ref), srvf(warp_curve(mov, gamma) @ R.transpose(-1, -2)))


# points of the independent fine discretisation used to score warps off the optimiser's grid
FINE_T = 2001


def fine_energy(mov: Tensor, ref: Tensor, gamma: Tensor, R: Tensor, fine: int = FINE_T) -> Tensor:
    """The same energy on an independent fine discretisation: both curves are interpolated by cubic splines
    in their parameter (a smooth curve through the samples, not the polyline whose knots a lattice warp can
    sit on to cut corners), the warp linearly, and the SRVFs compared on ``fine`` points.
    ``(B, T, d), (B, T, d), (B, T), (B, d, d) -> (B,)``."""
    from scipy.interpolate import CubicSpline

    T = mov.shape[1]
    s = np.linspace(0.0, 1.0, T)
    sf = np.linspace(0.0, 1.0, fine)
    out = []
    for b in range(mov.shape[0]):
        ref_f = CubicSpline(s, ref[b].numpy(), axis=0)(sf)
        g = np.clip(np.interp(sf, s, gamma[b].numpy()), 0.0, 1.0)
        mov_f = CubicSpline(s, mov[b].numpy(), axis=0)(g) @ R[b].numpy().T
        out.append(float(srvf_sq_distance(srvf(torch.from_numpy(ref_f)), srvf(torch.from_numpy(mov_f)))))
    return torch.tensor(out, dtype=torch.float64)


def _set_threads(n: int | None) -> int | None:
    """Set numba's thread count (``None``: leave it); returns the previous count."""
    try:
        import numba
    except ImportError:  # pragma: no cover - torch backend
        return None
    before = numba.get_num_threads()
    if n is not None:
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    return before


def _compare(e_o: Tensor, e_f: Tensor) -> dict[str, float]:
    """Mean energy ratio (mean of ours / mean of theirs) and the share of pairs where ours is not worse."""
    return {"ratio_of_means": float(e_o.mean() / e_f.mean()),
            "not_worse": float((e_o <= e_f * (1 + TIE_TOL)).double().mean())}


# runs of the batched call per kind and thread setting (median reported), interleaved
BATCH_REPS = 3


def benchmark_curves(pairs: int = 1000, T: int = 100, fdasrsf_pairs: int = 40, single_reps: int = 30,
                     kinds: tuple[str, ...] = ("random", "helix", "pheno4d"),
                     pheno4d: str | Path | None = None, seed: int = 0, fdasrsf_rounds: int = 5,
                     **register_kw: Any) -> dict[str, Any]:
    """Time and score our curve registration (so3 rotation + DP warp) against fdasrsf on the same pairs.

    Settings: ``register_curves`` defaults; fdasrsf 2.7.3 ``find_rotation_and_seed_coord`` (its default: one
    rotation, one DP) and the same alternated for ``fdasrsf_rounds`` rounds (``fdasrsf_iterated``, a second
    reference). Energies of every tool are scored twice: on the curves' own ``T`` grid (the one our DP
    optimises on) and on an independent fine discretisation (:func:`fine_energy`); ratios are
    mean(ours) / mean(theirs) over the same pairs.

    Times, all in this process and interleaved: one pair per call (ours and fdasrsf alternate, pair by
    pair: mean and median over ``fdasrsf_pairs`` pairs per kind); a batch of ``pairs`` pairs in one call
    with numba on 1 thread (like for like with fdasrsf, which runs on one) and on all threads (the
    median of ``BATCH_REPS`` runs each, alternating). Speedups divide means by means.

    Returns a dict: per kind under ``"kinds"`` and pooled (``"all"``), plus ``"dp_only"`` (DP warp alone,
    T = 50: our banded default, our full lattice and fdasrsf's DP, times and energies on both grids).
    fdasrsf fields are ``None`` when it is not importable.
    """
    if pheno4d is None:
        from .trees import default_data_root

        pheno4d = default_data_root() / "swc"
    cf = _fdasrsf()
    g = torch.Generator().manual_seed(seed)
    kw = {"rotation": "so3", **register_kw}
    threads = _set_threads(None)
    out: dict[str, Any] = {"pairs": pairs, "T": T, "rotation": kw["rotation"], "fdasrsf_pairs": fdasrsf_pairs,
                           "fdasrsf_rounds": fdasrsf_rounds, "fdasrsf_available": cf is not None,
                           "torch_threads": torch.get_num_threads(), "numba_threads": threads, "fine_T": FINE_T}
    t0 = time.perf_counter()
    warm_m, warm_r = curve_pairs("random", 2, T, g)
    register_curves(warm_m[:1], warm_r[:1], **kw)  # serial kernel
    register_curves(warm_m.repeat(8, 1, 1), warm_r.repeat(8, 1, 1), **kw)  # parallel kernel
    dp_warp(srvf(warm_r[:1]), srvf(warm_m[:1]))
    dp_warp(srvf(warm_r[:1]), srvf(warm_m[:1]), neighbourhood=6, band=None)
    out["numba_first_call_s"] = time.perf_counter() - t0

    per_kind: dict[str, Any] = {}
    pooled: dict[str, list] = {k: [] for k in ("t_ours", "t_fda", "t_fda_it", "b1", "bn", "eo", "ef", "ei", "fo",
                                               "ff", "fi", "c_ours", "c_fda")}
    for kind in kinds:
        if kind == "pheno4d" and not Path(pheno4d).is_dir():
            continue
        mov, ref = curve_pairs(kind, pairs, T, g, pheno4d)
        b1, bn = [], []
        for _ in range(BATCH_REPS):  # alternate the thread settings: a shared VM's timings swing by +-40 %
            for n, acc in ((1, b1), (threads, bn)):
                _set_threads(n)
                t = time.perf_counter()
                res = register_curves(mov, ref, **kw)
                acc.append((time.perf_counter() - t) / pairs)
        _set_threads(threads)
        n = min(fdasrsf_pairs, pairs)
        k: dict[str, Any] = {"batched_1_thread_s_per_pair": statistics.median(b1),
                             f"batched_{threads}_threads_s_per_pair": statistics.median(bn),
                             "ours_mean_distance": float(res.distance.mean())}
        pooled["b1"].append(statistics.median(b1))
        pooled["bn"].append(statistics.median(bn))
        t_o, t_f, t_i, gams, Rs, gi, Ri, c_o, c_f = [], [], [], [], [], [], [], [], []
        for i in range(max(n, single_reps if cf is None else 0)):  # interleaved, pair by pair
            j = i % pairs
            t, c = time.perf_counter(), time.process_time()
            register_curves(mov[j], ref[j], **kw)
            t_o.append(time.perf_counter() - t)
            c_o.append(time.process_time() - c)
            if cf is not None and i < n:
                t, c = time.perf_counter(), time.process_time()
                gm, R = _fdasrsf_register(cf, mov[j], ref[j], rotation=kw["rotation"] != "none")
                t_f.append(time.perf_counter() - t)
                c_f.append(time.process_time() - c)
                t = time.perf_counter()
                gm2, R2 = _fdasrsf_iterated(cf, mov[j], ref[j], fdasrsf_rounds)
                t_i.append(time.perf_counter() - t)
                gams.append(gm)
                Rs.append(R)
                gi.append(gm2)
                Ri.append(R2)
        k["ours_s_per_pair"] = summary(t_o)
        k["ours_cpu_s_per_pair"] = summary(c_o)
        pooled["t_ours"] += t_o
        pooled["c_ours"] += c_o
        if cf is not None and n > 0:
            G, Rt, GI, RI = torch.stack(gams), torch.stack(Rs), torch.stack(gi), torch.stack(Ri)
            m, r = mov[:n], ref[:n]
            e_o, f_o = res.energy[:n], fine_energy(m, r, res.gamma[:n], res.rotation[:n])
            e_f, f_f = _our_energy(m, r, G, Rt), fine_energy(m, r, G, Rt)
            e_i, f_i = _our_energy(m, r, GI, RI), fine_energy(m, r, GI, RI)
            pooled["c_fda"] += c_f
            k.update({"fdasrsf_s_per_pair": summary(t_f), "fdasrsf_iterated_s_per_pair": summary(t_i),
                      "fdasrsf_cpu_s_per_pair": summary(c_f),
                      "grid_vs_fdasrsf": _compare(e_o, e_f), "fine_vs_fdasrsf": _compare(f_o, f_f),
                      "grid_vs_fdasrsf_iterated": _compare(e_o, e_i), "fine_vs_fdasrsf_iterated": _compare(f_o, f_i),
                      "fine_over_grid": {"ours": float(f_o.mean() / e_o.mean()),
                                         "fdasrsf": float(f_f.mean() / e_f.mean()),
                                         "fdasrsf_iterated": float(f_i.mean() / e_i.mean())},
                      "mean_distance_fine": {"ours": float(f_o.sqrt().mean()), "fdasrsf": float(f_f.sqrt().mean()),
                                             "fdasrsf_iterated": float(f_i.sqrt().mean())}})
            for key, v in (("t_fda", t_f), ("t_fda_it", t_i), ("eo", [e_o]), ("ef", [e_f]), ("ei", [e_i]),
                           ("fo", [f_o]), ("ff", [f_f]), ("fi", [f_i])):
                pooled[key] += v
        per_kind[kind] = k
    out["kinds"] = per_kind
    allk: dict[str, Any] = {"ours_s_per_pair": summary(pooled["t_ours"]),
                            "ours_cpu_s_per_pair": summary(pooled["c_ours"]),
                            "batched_1_thread_s_per_pair": statistics.median(pooled["b1"]),
                            f"batched_{threads}_threads_s_per_pair": statistics.median(pooled["bn"])}
    if pooled["t_fda"]:
        eo, ef, ei, fo, ff, fi = (torch.cat(pooled[x]) for x in ("eo", "ef", "ei", "fo", "ff", "fi"))
        tf, ti, to = summary(pooled["t_fda"]), summary(pooled["t_fda_it"]), allk["ours_s_per_pair"]
        cf_, co = summary(pooled["c_fda"]), allk["ours_cpu_s_per_pair"]
        allk.update({"fdasrsf_s_per_pair": tf, "fdasrsf_iterated_s_per_pair": ti, "fdasrsf_cpu_s_per_pair": cf_,
                     "speedup_one_pair_by_means": tf["mean"] / to["mean"],
                     "speedup_one_pair_cpu_by_means": cf_["mean"] / co["mean"],
                     "speedup_batched_1_thread_by_means": tf["mean"] / allk["batched_1_thread_s_per_pair"],
                     f"speedup_batched_{threads}_threads_by_means":
                         tf["mean"] / allk[f"batched_{threads}_threads_s_per_pair"],
                     "grid_vs_fdasrsf": _compare(eo, ef), "fine_vs_fdasrsf": _compare(fo, ff),
                     "grid_vs_fdasrsf_iterated": _compare(eo, ei), "fine_vs_fdasrsf_iterated": _compare(fo, fi)})
    out["all"] = allk
    out["dp_only"] = _dp_only(cf, g, T=50, pairs=fdasrsf_pairs)
    return out


def _dp_only(cf: Any | None, g: torch.Generator, T: int, pairs: int) -> dict[str, Any]:
    """DP warp alone (no rotation), ``pairs`` random pairs of ``T`` points, one pair per call, interleaved:
    our banded default, our full lattice (slopes up to 6: fdasrsf's 23 steps) and fdasrsf's DP; times
    (mean, median) and mean energies on our grid and on the fine one."""
    mov, ref = curve_pairs("random", pairs, T, g)
    eye = torch.eye(3, dtype=torch.float64).expand(pairs, 3, 3)
    q1, q2 = srvf(ref), srvf(mov)
    names = ["banded_default", "full_lattice"] + (["fdasrsf"] if cf is not None else [])
    times: dict[str, list[float]] = {k: [] for k in names}
    gam: dict[str, list[Tensor]] = {k: [] for k in names}
    for i in range(pairs):
        for name in names:
            t = time.perf_counter()
            if name == "banded_default":
                gm = dp_warp(q1[i], q2[i]).gamma
            elif name == "full_lattice":
                gm = dp_warp(q1[i], q2[i], neighbourhood=6, band=None).gamma
            else:
                from fdasrsf.curve_functions import curve_to_q, optimum_reparam_curve
                from fdasrsf.utility_functions import invertGamma

                Q1 = curve_to_q(ref[i].T.contiguous().numpy().copy())[0]
                Q2 = curve_to_q(mov[i].T.contiguous().numpy().copy())[0]
                gm = torch.as_tensor(invertGamma(optimum_reparam_curve(Q2, Q1, 0.0, "DP")), dtype=torch.float64)
            times[name].append(time.perf_counter() - t)
            gam[name].append(gm)
    res: dict[str, Any] = {"T": T, "pairs": pairs}
    for name in names:
        G = torch.stack(gam[name])
        res[name] = {"s_per_pair": summary(times[name]),
                     "energy_grid_mean": float(_our_energy(mov, ref, G, eye).mean()),
                     "energy_fine_mean": float(fine_energy(mov, ref, G, eye).mean())}
    if cf is None:
        res["fdasrsf"] = None
    return res
