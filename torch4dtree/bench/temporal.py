"""Benchmarks of the 4D half: temporal registration speed and warp recovery, within-sequence registration
(identity accuracy on synthetic plants with ground truth, time on Pheno4D), and growth-clock recovery.

Every function returns a JSON-serialisable dict; ``python -m torch4dtree.bench.temporal [section ...]`` prints them.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..curves.srvf import interpolate_curve, srvf, srvf_sq_distance
from ..curves.warps import invert_warp, random_warp
from ..evaluate.oracle import label_features, pca_trajectories
from ..evaluate.paper import SECONDS
from ..temporal.registration import register_trajectories, time_warp_trajectory
from ..temporal.trajectory import OVERSAMPLE, fine_size
from ..temporal.within import AlignedSequence, identity_accuracy, register_sequence

__all__ = ["benchmark_growth_clocks", "benchmark_pheno4d_within", "benchmark_synthetic_within",
           "benchmark_temporal", "smooth_trajectories", "warped_trajectory_pairs"]

PAPER_TEMPORAL_SECONDS = (SECONDS["temporal_maize"], SECONDS["temporal_tomato"])  # one pair: maize, tomato


def smooth_trajectories(B: int, n_t: int, k: int, generator: torch.Generator, warp: Tensor | None = None,
                        modes: int = 3) -> Tensor:
    """Smooth random trajectories ``(B, n_t, k)`` (drift plus ``modes`` low-frequency sines), evaluated at
    ``warp (B, n_t)`` (default: the grid) -- call twice with one generator state to get a curve and its
    time-warped copy."""
    m = torch.arange(1, modes + 1, dtype=torch.float64)
    amp = torch.randn(B, modes, k, generator=generator, dtype=torch.float64) / m[:, None] * 0.5
    phase = torch.rand(B, modes, k, generator=generator, dtype=torch.float64) * 2 * math.pi
    drift = torch.randn(B, k, generator=generator, dtype=torch.float64)
    start = torch.randn(B, k, generator=generator, dtype=torch.float64)
    t = torch.linspace(0, 1, n_t, dtype=torch.float64).expand(B, n_t) if warp is None else warp
    waves = torch.sin(0.5 * math.pi * m[None, :, None, None] * t[:, None, None, :] + phase[..., None])
    return start[:, None] + drift[:, None] * t[..., None] + torch.einsum("bmk,bmkn->bnk", amp, waves)


def warped_trajectory_pairs(B: int, n_t: int, k: int, seed: int = 0, strength: float = 1.0, oversample: int = 1
                            ) -> tuple[Tensor, Tensor, Tensor]:
    """``(ref, mov, true)``: trajectories, their copies time-warped by smooth random warps ``gamma``, and the
    warp that registers ``mov`` onto ``ref`` (``gamma^{-1}``) on the grid, ``(B, n_t, k), (B, m, k), (B, n_t)``;
    ``mov`` has ``m = fine_size(n_t, oversample=oversample)`` samples (``n_t`` by default)."""
    fine = random_warp(B, 2001, generator=torch.Generator().manual_seed(seed + 1), strength=strength)
    grid = torch.linspace(0, 1, n_t, dtype=torch.float64).expand(B, n_t)
    m = fine_size(n_t, oversample=oversample)
    gamma = interpolate_curve(fine[..., None], torch.linspace(0, 1, m, dtype=torch.float64).expand(B, m))[..., 0]
    ref = smooth_trajectories(B, n_t, k, torch.Generator().manual_seed(seed))
    mov = smooth_trajectories(B, m, k, torch.Generator().manual_seed(seed), warp=gamma)
    true = interpolate_curve(invert_warp(fine)[..., None], grid)[..., 0]
    return ref, mov, true


def _best_of(fn: Callable[[], object], repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def benchmark_temporal(pairs: int = 1000, n_t: int = 32, k: int = 10, repeats: int = 5,
                       grid: Sequence[int] = (16, 32, 64), neighbourhoods: Sequence[int] = (3, 4, 6),
                       refines: Sequence[int] = (0, 16), accuracy_pairs: int = 300) -> dict:
    """Speed of :func:`register_trajectories` (one pair, and batched) and warp recovery vs ``n_t`` and the DP lattice.

    Accuracy rows: mean / 95th percentile / max over pairs of the mean absolute warp error on ``[0, 1]``, the
    distance left after registration relative to the one before, and how far the optimiser is from what the
    true warp achieves on the same grid (``(d - d_true) / d_before``; 0 = as good as the truth).
    """
    ref, mov, _ = warped_trajectory_pairs(pairs, n_t, k, seed=0)
    register_trajectories(ref[:4], mov[:4])  # warm-up (numba)
    batched = _best_of(lambda: register_trajectories(ref, mov), repeats) / pairs
    singles = [_best_of(lambda i=i: register_trajectories(ref[i], mov[i]), repeats) for i in range(50)]
    # the moving trajectory OVERSAMPLE times finer, as register4d passes it (adds the refinement on the fine polyline)
    fine = warped_trajectory_pairs(pairs, n_t, k, seed=0, oversample=OVERSAMPLE)[1]
    register_trajectories(ref[:4], fine[:4])
    batched_fine = _best_of(lambda: register_trajectories(ref, fine), repeats) / pairs
    singles_fine = [_best_of(lambda i=i: register_trajectories(ref[i], fine[i]), repeats) for i in range(50)]
    out: dict = {"n_t": n_t, "k": k, "pairs": pairs, "batched_ms_per_pair": 1e3 * batched,
                 "batched_pairs_per_s": 1.0 / batched, "single_pair_ms_median": 1e3 * statistics.median(singles),
                 "oversample": OVERSAMPLE, "batched_fine_ms_per_pair": 1e3 * batched_fine,
                 "single_pair_fine_ms_median": 1e3 * statistics.median(singles_fine),
                 "paper_seconds": PAPER_TEMPORAL_SECONDS, "torch_threads": torch.get_num_threads(), "accuracy": []}
    for nt in grid:
        r0, m0, true = warped_trajectory_pairs(accuracy_pairs, nt, k, seed=1)
        at_truth = srvf_sq_distance(srvf(r0), srvf(time_warp_trajectory(m0, true))).sqrt()
        for nb in neighbourhoods:
            for ref_steps in refines:
                r = register_trajectories(r0, m0, neighbourhood=nb, refine=ref_steps)
                run = partial(register_trajectories, r0, m0, neighbourhood=nb, refine=ref_steps)
                dt = _best_of(run, 3) / accuracy_pairs
                err = (r.warp - true).abs().mean(-1)
                gap = (r.distance - at_truth) / r.distance_before
                out["accuracy"].append({
                    "n_t": nt, "neighbourhood": nb, "refine": ref_steps, "ms_per_pair": 1e3 * dt,
                    "warp_mae_mean": float(err.mean()), "warp_mae_p95": float(err.quantile(0.95)),
                    "warp_mae_max": float(err.max()),
                    "residual_ratio_median": float((r.distance / r.distance_before).median()),
                    "gap_to_truth_p95": float(gap.quantile(0.95)), "gap_to_truth_max": float(gap.max()),
                })
    return out


def benchmark_synthetic_within(kinds: Sequence[str] = ("tomato", "maize"), seeds: Sequence[int] = range(6),
                               n_frames: int = 8, T: int = 24, lps: Sequence[float] = (1.0, 30.0, 50.0, 100.0, 300.0)
                               ) -> dict:
    """Identity accuracy of :func:`register_sequence` against the synthetic ground truth, per ``lp``."""
    from ..data import synthetic_plant

    out: dict = {}
    for kind in kinds:
        for lp in lps:
            rows = []
            for seed in seeds:
                seq = synthetic_plant(kind, seed, n_frames=n_frames, T=T).sequence
                t0 = time.perf_counter()
                al = register_sequence(seq, lambdas=(1.0, 1.0, lp))
                dt = time.perf_counter() - t0
                acc = identity_accuracy(al, seq.frames.label)
                rows.append((float(acc.per_pair.min()), float(acc.per_pair.mean()), acc.sequence, dt))
            out[f"{kind} lp={lp:g}"] = {
                "worst_pair": min(r[0] for r in rows), "mean_pair": statistics.fmean(r[1] for r in rows),
                "sequence_mean": statistics.fmean(r[2] for r in rows), "sequence_min": min(r[2] for r in rows),
                "seconds_mean": statistics.fmean(r[3] for r in rows), "plants": len(rows), "frames": n_frames,
            }
    return out


def benchmark_pheno4d_within(root: str | Path | None = None, T: int = 64, lambdas: Sequence[float] = (1.0, 1.0, 1.0)
                             ) -> dict:
    """Time :func:`register_sequence` on Pheno4D tomato 3 (SWC, ``T`` points) and its hand-corrected ``.mat`` twin."""
    from ..io import LoadOptions, read_sequence

    here = Path(__file__).resolve().parents[2]
    base = Path(root) if root is not None else here.parent / "shared" / "data" / "pheno4d"
    out: dict = {}
    for label, folder in (("swc Tomato_3", base / "swc" / "Tomato_3"), ("mat tom_3_seq", base / "mat" / "tom_3_seq")):
        if not folder.is_dir():
            out[label] = None
            continue
        seq = read_sequence(folder, LoadOptions(T=T)).sequence
        t0 = time.perf_counter()
        al = register_sequence(seq, lambdas=lambdas)
        dt = time.perf_counter() - t0
        out[label] = {"frames": len(seq), "branches": seq.frames.num_branches.tolist(), "slots": al.num_slots,
                      "seconds": dt, "seconds_per_pair": dt / max(len(seq) - 1, 1),
                      "distances": [round(float(x), 3) for x in al.distances]}
    return out


# ----------------------------------------------------------------------------- growth clocks


def _pipeline_features(a: AlignedSequence, b: AlignedSequence, lambdas: Sequence[float]) -> list[Tensor]:
    """Both sequences in sequence ``a``'s layout, as the pipeline would do it without labels: register ``b``'s
    representative onto ``a``'s (with a rotation about the vertical), carry ``b``'s matched slots (warped into
    ``a``'s parameterisations, their ``s`` moved with the parent's warp) into ``a``'s slots; slots of ``b``
    matching nothing are dropped."""
    from ..curves.srvf import warp_srvf
    from ..trees.registration import register_trees

    rep_a, rep_b = a.representative(), b.representative()
    reg = register_trees(rep_b, rep_a, lambdas, rotation="vertical")
    O = reg.rotation.double()
    la, lb = rep_a.label.tolist(), rep_b.label.tolist()
    n, S_a = len(b), a.num_slots
    M, d = a.aligned.q.shape[2:]
    q = torch.zeros(n, S_a, M, d, dtype=torch.float64)
    s = b.aligned.s.new_zeros(n, S_a)
    gamma_of = {lb[mb]: reg.gamma[mb].double() for mb, _ in reg.matches}
    grid = torch.linspace(0, 1, M + 1, dtype=torch.float64)
    parent_b = b.aligned.slot_parent.tolist()
    for mb, ma in reg.matches:
        sb, sa = lb[mb], la[ma]
        q[:, sa] = warp_srvf(b.aligned.q[:, sb], gamma_of[sb].expand(n, -1)) @ O.T
        if parent_b[sb] >= 0 and parent_b[sb] in gamma_of:
            g = gamma_of[parent_b[sb]]
            s[:, sa] = torch.from_numpy(np.interp(b.aligned.s[:, sb].numpy(), g.numpy(), grid.numpy()))
    like = a.aligned
    w_q, w_s = like.weights()
    fb = torch.cat([(q * (w_q / M).sqrt()[None, :, None, None]).flatten(1), s[:, 1:] * w_s[1:].sqrt()], 1)
    return [like.features(), fb]


def benchmark_growth_clocks(kind: str = "tomato", pairs: int = 6, n_frames: int = 10, T: int = 24, k: int = 5,
                            n_t: int = 32, lambdas: Sequence[float] = (1.0, 1.0, 50.0), layouts: Sequence[str] = (
                                "labels", "pipeline")) -> dict:
    """Recover the relative growth clock of two synthetic plants from their trajectories.

    Trajectories: every frame's features (``labels``: an oracle layout by ground-truth organ; ``pipeline``:
    within-sequence registration of each plant, then plant ``b`` carried into plant ``a``'s layout through
    their representatives), projected on the top ``k`` principal directions of both plants' frames, resampled
    on ``n_t`` times. The recovered warp of ``b`` onto ``a`` is compared with
    :func:`torch4dtree.data.relative_warp` ``(a, b, t)`` (mean absolute error on the grid), and with the
    identity as a baseline.
    """
    from ..data import relative_warp, synthetic_dataset

    plants = synthetic_dataset(kind, plants=2 * pairs, seed=7, n_frames=n_frames, T=T, dtype=torch.float64)
    grid = torch.linspace(0, 1, n_t, dtype=torch.float64)
    register_trajectories(grid[:, None], grid[:, None])  # warm-up (numba) outside the timings
    out: dict = {}
    for layout in layouts:
        errs, base, secs = [], [], []
        for p in range(pairs):
            a, b = plants[2 * p], plants[2 * p + 1]
            if layout == "labels":
                feats = label_features([a.sequence, b.sequence], T)
            else:
                ala = register_sequence(a.sequence, lambdas=lambdas)
                alb = register_sequence(b.sequence, lambdas=lambdas)
                feats = _pipeline_features(ala, alb, lambdas)
            ta, tb = pca_trajectories(feats, [a.times, b.times], k, n_t)
            t0 = time.perf_counter()
            r = register_trajectories(ta, tb)
            secs.append(time.perf_counter() - t0)
            true = relative_warp(a, b, grid)
            errs.append(float((r.warp - true).abs().mean()))
            base.append(float((grid - true).abs().mean()))
        out[layout] = {"warp_mae_mean": statistics.fmean(errs), "warp_mae_max": max(errs),
                       "identity_mae_mean": statistics.fmean(base), "per_pair": [round(e, 4) for e in errs],
                       "register_ms_mean": 1e3 * statistics.fmean(secs)}
    out.update({"kind": kind, "pairs": pairs, "n_frames": n_frames, "k": k, "n_t": n_t})
    return out


SECTIONS: dict[str, Callable[[], dict]] = {
    "temporal": benchmark_temporal, "synthetic": benchmark_synthetic_within, "pheno4d": benchmark_pheno4d_within,
    "clocks": benchmark_growth_clocks,
}

if __name__ == "__main__":
    for name in sys.argv[1:] or list(SECTIONS):
        print(json.dumps({name: SECTIONS[name]()}, indent=1), flush=True)
