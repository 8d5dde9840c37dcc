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
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ..curves.register import dp_warp, register_curves
from ..curves.rotation import random_rotation
from ..curves.srvf import curve_length, resample_polylines, srvf, srvf_sq_distance, warp_curve
from ..curves.warps import random_warp

__all__ = ["benchmark_curves", "curve_pairs", "pheno4d_paths", "smooth_random_curves"]


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
    return beta / curve_length(beta).clamp_min(1e-12)[:, None, None]


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
    """fdasrsf's open-curve registration of one pair; returns its warp ``(T,)`` and rotation ``(3, 3)``."""
    b1 = (ref - ref.mean(0)).T.contiguous().numpy().copy()
    b2 = (mov - mov.mean(0)).T.contiguous().numpy().copy()
    _, _, R, gam = cf.find_rotation_and_seed_coord(b1, b2, closed=0, rotation=rotation, method="DP")
    return torch.as_tensor(np.asarray(gam), dtype=torch.float64), torch.as_tensor(np.asarray(R), dtype=torch.float64)


def _our_energy(mov: Tensor, ref: Tensor, gamma: Tensor, R: Tensor) -> Tensor:
    """Our discrete energy of moving curves under warps ``gamma`` then rotations ``R``."""
    return srvf_sq_distance(srvf(ref), srvf(warp_curve(mov, gamma) @ R.transpose(-1, -2)))


# runs of the batched call per kind (median reported)
BATCH_REPS = 3


def _median_time(fn: Callable[[], object], reps: int) -> float:
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def benchmark_curves(pairs: int = 1000, T: int = 100, fdasrsf_pairs: int = 40, single_reps: int = 30,
                     kinds: tuple[str, ...] = ("random", "helix", "pheno4d"),
                     pheno4d: str | Path | None = None, seed: int = 0,
                     **register_kw: Any) -> dict[str, Any]:
    """Time and score our curve registration (so3 rotation + DP warp) against fdasrsf on the same pairs.

    Args:
        pairs: batch size of the batched timing (per kind; median of ``BATCH_REPS`` runs).
        T: points per curve.
        fdasrsf_pairs: pairs per kind registered one by one by both tools for the energy comparison
            and fdasrsf's timing (fdasrsf takes ~30 ms a pair).
        single_reps: single-pair calls timed (median).
        kinds: pair kinds (see :func:`curve_pairs`); ``"pheno4d"`` is skipped if its folder is missing.
        pheno4d: folder holding ``<plant>/<file>.swc``; default ``../shared/data/pheno4d/swc`` relative
            to the repository.
        register_kw: passed to :func:`~torch4dtree.curves.register_curves`.

    Returns:
        A flat dict: ``pairs, T, ours_s_per_pair`` (single-pair median), ``ours_batched_s_per_pair``,
        ``fdasrsf_s_per_pair``, ``speedup`` (fdasrsf single / ours single), ``speedup_batched``,
        ``energy_ratio_ours_over_fdasrsf`` (mean of our energies / mean of theirs, both in our discrete
        energy), ``ours_not_worse_fraction``, per-kind entries under ``"kinds"``, the DP-only timings at
        50 points (``dp50_*``) and ``numba_first_call_s`` (compile or cache load). fdasrsf fields are
        ``None`` when it is not importable.
    """
    if pheno4d is None:
        from .trees import default_data_root

        pheno4d = default_data_root() / "swc"
    cf = _fdasrsf()
    g = torch.Generator().manual_seed(seed)
    kw = {"rotation": "so3", **register_kw}
    out: dict[str, Any] = {"pairs": pairs, "T": T, "rotation": kw["rotation"], "fdasrsf_pairs": fdasrsf_pairs,
                           "fdasrsf_available": cf is not None, "torch_threads": torch.get_num_threads()}
    try:
        import numba

        out["numba_threads"] = numba.get_num_threads()
    except ImportError:
        out["numba_threads"] = None
    t0 = time.perf_counter()
    warm_m, warm_r = curve_pairs("random", 2, T, g)
    register_curves(warm_m[:1], warm_r[:1], **kw)  # serial kernel
    register_curves(warm_m.repeat(8, 1, 1), warm_r.repeat(8, 1, 1), **kw)  # parallel kernel
    dp_warp(srvf(warm_r[:1]), srvf(warm_m[:1]))
    out["numba_first_call_s"] = time.perf_counter() - t0

    per_kind: dict[str, Any] = {}
    singles, batched, theirs_t, e_ours, e_theirs = [], [], [], [], []
    for kind in kinds:
        if kind == "pheno4d" and not Path(pheno4d).is_dir():
            continue
        mov, ref = curve_pairs(kind, pairs, T, g, pheno4d)
        batch_times = []
        for _ in range(BATCH_REPS):  # the median of a few runs: a shared VM's timings swing by +-40 %
            t = time.perf_counter()
            res = register_curves(mov, ref, **kw)
            batch_times.append((time.perf_counter() - t) / pairs)
        t_batch = statistics.median(batch_times)
        idx = [0]

        def one(idx: list[int] = idx, mov: Tensor = mov, ref: Tensor = ref) -> None:
            i = idx[0] % pairs
            idx[0] += 1
            register_curves(mov[i], ref[i], **kw)

        t_single = _median_time(one, single_reps)
        k: dict[str, Any] = {"ours_s_per_pair": t_single, "ours_batched_s_per_pair": t_batch,
                             "ours_mean_distance": float(res.distance.mean()),
                             "ours_mean_distance_before": float(res.energy_before.sqrt().mean())}
        singles.append(t_single)
        batched.append(t_batch)
        if cf is not None and fdasrsf_pairs > 0:
            n = min(fdasrsf_pairs, pairs)
            gams, Rs, times = [], [], []
            for i in range(n):
                t = time.perf_counter()
                gm, R = _fdasrsf_register(cf, mov[i], ref[i], rotation=kw["rotation"] != "none")
                times.append(time.perf_counter() - t)
                gams.append(gm)
                Rs.append(R)
            e_f = _our_energy(mov[:n], ref[:n], torch.stack(gams), torch.stack(Rs))
            e_o = res.energy[:n]
            k.update({"fdasrsf_s_per_pair": statistics.median(times),
                      "energy_ratio_ours_over_fdasrsf": float(e_o.mean() / e_f.mean()),
                      "ours_not_worse_fraction": float((e_o <= e_f * (1 + 1e-9)).double().mean()),
                      "fdasrsf_mean_distance": float(e_f.sqrt().mean()),
                      "ours_mean_distance_same_pairs": float(e_o.sqrt().mean())})
            theirs_t.append(statistics.median(times))
            e_ours.append(e_o)
            e_theirs.append(e_f)
        per_kind[kind] = k
    out["kinds"] = per_kind
    out["ours_s_per_pair"] = statistics.median(singles) if singles else None
    out["ours_batched_s_per_pair"] = statistics.median(batched) if batched else None
    if theirs_t:
        eo, ef = torch.cat(e_ours), torch.cat(e_theirs)
        out["fdasrsf_s_per_pair"] = statistics.median(theirs_t)
        out["speedup"] = out["fdasrsf_s_per_pair"] / out["ours_s_per_pair"]
        out["speedup_batched"] = out["fdasrsf_s_per_pair"] / out["ours_batched_s_per_pair"]
        out["energy_ratio_ours_over_fdasrsf"] = float(eo.mean() / ef.mean())
        out["ours_not_worse_fraction"] = float((eo <= ef * (1 + 1e-9)).double().mean())
    else:
        for key in ("fdasrsf_s_per_pair", "speedup", "speedup_batched", "energy_ratio_ours_over_fdasrsf",
                    "ours_not_worse_fraction"):
            out[key] = None
    out.update(_dp_only(cf, g, T=50, reps=single_reps))
    return out


def _dp_only(cf: Any | None, g: torch.Generator, T: int, reps: int) -> dict[str, Any]:
    """DP warp alone (no rotation) for one pair of 3D curves of ``T`` points: ours vs fdasrsf."""
    mov, ref = curve_pairs("random", 1, T, g)
    q1, q2 = srvf(ref), srvf(mov)
    res: dict[str, Any] = {f"dp{T}_ours_s": _median_time(lambda: dp_warp(q1, q2), reps)}
    if cf is None:
        res[f"dp{T}_fdasrsf_s"] = None
        return res
    from fdasrsf.curve_functions import curve_to_q, optimum_reparam_curve

    Q1 = curve_to_q(ref[0].T.contiguous().numpy().copy())[0]
    Q2 = curve_to_q(mov[0].T.contiguous().numpy().copy())[0]
    res[f"dp{T}_fdasrsf_s"] = _median_time(lambda: optimum_reparam_curve(Q2, Q1, 0.0, "DP"), reps)
    return res
