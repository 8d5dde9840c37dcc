"""``torch4dtree benchmark all``: every benchmark in one run, with ratios against the references.

Sections (each the dict of its own benchmark): ``curves`` (:func:`.curves.benchmark_curves`: curve registration
vs fdasrsf, which is only importable in the benchmark venv, ``benchmarks/requirements.txt``), ``trees``
(:func:`.trees.benchmark_trees`: consecutive-day Pheno4D pairs vs the paper's 2.3 s), ``4d``
(:func:`.fourd.benchmark_4d`: spatiotemporal registration of Pheno4D plants, a 4D geodesic, temporal registration)
and ``model`` (:func:`.model.benchmark_model`: fit, 4D mean, sampling, decoding). A section that needs the Pheno4D
data is replaced by ``{"skipped": why}`` when the data is missing (with a line in ``notes``).

``ratios``: ``{name: {"ours_s", "reference_s", "reference", "ratio", "what"}}`` with ``ratio = reference_s /
ours_s`` (above 1: ours is faster), both means (the paper's figures are averages); ``reference_s`` and ``ratio``
are ``None`` when the reference is not available (fdasrsf not installed, data missing).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["FULL", "QUICK", "benchmark_all", "ratios"]

# moderate sizes: the whole run takes a few minutes on 2 shared cores
FULL: dict[str, dict[str, Any]] = {
    "curves": {"pairs": 1000, "T": 100, "fdasrsf_pairs": 30, "single_reps": 30},
    "trees": {"T": 64, "source": "swc"},
    "4d": {"T": 64, "all_pairs": True},
    "temporal_one_pair": {"pairs": 50, "n_t": 32, "k": 10},
    "model": {},
}
# about a minute: the CLI's --quick (a first look, the tests)
QUICK: dict[str, dict[str, Any]] = {
    "curves": {"pairs": 50, "T": 50, "fdasrsf_pairs": 3, "single_reps": 10, "kinds": ("random",)},
    "trees": {"T": 32, "source": "swc", "max_pairs": 4},
    "4d": {"T": 16, "all_pairs": False},
    "temporal_one_pair": {"pairs": 20, "n_t": 32, "k": 10},
    "model": {"plants": 3, "frames": 4, "T": 16, "n_t": 8, "samples": 1000, "single": 50, "decode": 2, "repeats": 1},
}


def _temporal_one_pair(pairs: int, n_t: int, k: int) -> dict[str, float]:
    """One temporal registration per call (as the paper times it), mean and median over ``pairs`` warped pairs; the
    moving trajectory is passed finer, as ``register4d`` passes it."""
    from ..evaluate.stats import summary
    from ..temporal.registration import register_trajectories
    from ..temporal.trajectory import OVERSAMPLE
    from .temporal import warped_trajectory_pairs

    ref, mov, _ = warped_trajectory_pairs(pairs, n_t, k, seed=2, oversample=OVERSAMPLE)
    register_trajectories(ref[0], mov[0])  # warm-up (numba)
    times = []
    for i in range(pairs):
        t0 = time.perf_counter()
        register_trajectories(ref[i], mov[i])
        times.append(time.perf_counter() - t0)
    return {**summary(times), "n_t": n_t, "k": k}


def _ratio(ours: float | None, reference_s: float | None, reference: str, what: str) -> dict[str, Any]:
    ok = ours is not None and reference_s is not None and ours > 0
    return {"ours_s": ours, "reference_s": reference_s, "reference": reference,
            "ratio": reference_s / ours if ok else None, "what": what}


def _get(d: Any, *keys: str) -> Any:
    """``d[k1][k2]...`` or ``None`` where a level is missing (skipped sections, fdasrsf absent)."""
    for k in keys:
        if not isinstance(d, dict) or d.get(k) is None:
            return None
        d = d[k]
    return d


def ratios(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The ratio table of a :func:`benchmark_all` result (module doc)."""
    from .fourd import PAPER_SECONDS as PAPER_4D
    from .model import PAPER_SECONDS as PAPER_MODEL
    from .trees import PAPER_SECONDS as PAPER_TREE

    curves, trees, fourd, model = (result.get(k, {}) for k in ("curves", "trees", "4d", "model"))
    fda = "fdasrsf 2.7.3" if _get(curves, "fdasrsf_available") else "fdasrsf (not importable here: no reference)"
    paper = "paper (MATLAB, unspecified CPU)"
    fda_pair = _get(curves, "all", "fdasrsf_s_per_pair", "mean")
    out = {
        "curve_pair_vs_fdasrsf": _ratio(
            _get(curves, "all", "ours_s_per_pair", "mean"), fda_pair, fda,
            "one pair per call, rotation + warp (fdasrsf: find_rotation_and_seed_coord), all kinds pooled"),
        "curve_pair_batched_1_thread_vs_fdasrsf": _ratio(
            _get(curves, "all", "batched_1_thread_s_per_pair"), fda_pair, fda,
            "ours: a batch of pairs in one call, numba on 1 thread, per pair; fdasrsf one pair per call"),
        "dp_warp_vs_fdasrsf": _ratio(
            _get(curves, "dp_only", "banded_default", "s_per_pair", "mean"),
            _get(curves, "dp_only", "fdasrsf", "s_per_pair", "mean"), fda, "DP warp alone, T = 50, one pair per call"),
        "tree_pair_vs_paper": _ratio(_get(trees, "mean_s"), PAPER_TREE, paper,
                                     "register two 3D trees: every consecutive-day Pheno4D pair, wall clock"),
        "tree_pair_cpu_vs_paper": _ratio(_get(trees, "cpu_mean_s"), PAPER_TREE, paper,
                                         "the same, CPU seconds of this process (what it takes alone)"),
        "temporal_one_pair_vs_paper": _ratio(
            _get(fourd, "temporal_one_pair", "mean"), PAPER_4D["temporal"][0], paper + ", its faster figure (maize)",
            "temporal registration of two trajectories, one per call (synthetic, n_t = 32, k = 10)"),
        "temporal_batched_vs_paper": _ratio(
            None if _get(fourd, "temporal", "batched_ms_per_pair") is None
            else fourd["temporal"]["batched_ms_per_pair"] / 1e3, PAPER_4D["temporal"][0],
            paper + ", its faster figure (maize)", "the same, 1000 pairs in one call, per pair"),
        "mean_4d_vs_paper": _ratio(_get(model, "mean_seconds", "mean"), PAPER_MODEL["mean"], paper,
                                   "the 4D mean (temporal Karcher mean of the trajectories; paper: 7 tomato plants, "
                                   "ours: the model benchmark's synthetic plants)"),
        "sample_one_vs_paper": _ratio(_get(model, "sample_one_seconds", "mean"), PAPER_MODEL["sample"], paper,
                                      "generate one 4D plant (coefficients -> trajectory), one per call"),
        "sample_batched_vs_paper": _ratio(_get(model, "sample_batched_seconds_per_plant"), PAPER_MODEL["sample"],
                                          paper, "the same in one batch, per plant"),
    }
    for kind in ("tomato", "maize"):
        out[f"4d_pair_{kind}_vs_paper"] = _ratio(
            _get(fourd, kind, "pair_seconds"), PAPER_4D[f"{kind}_pair"], paper,
            f"register two {kind} 4D plants in space and time (within-sequence registrations included), one pair")
    out["4d_geodesic_vs_paper"] = _ratio(
        _get(fourd, "tomato", "trajectory_geodesic_seconds"), PAPER_4D["geodesic"], paper,
        "a 4D geodesic between two tomato plants, 5 steps, as trajectories in the tree space (what the paper's "
        "0.025 s most likely covers; it does not say)")
    out["4d_geodesic_decoded_vs_paper"] = _ratio(
        _get(fourd, "tomato", "decoded_geodesic_seconds"), PAPER_4D["geodesic"], paper,
        "the same decoded to 3D trees at every common time (5 x 32 trees; median of 10 calls after the first)")
    return out


def benchmark_all(root: str | Path | None = None, quick: bool = False,
                  log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run every section (module doc) at the :data:`FULL` (or :data:`QUICK`) sizes; ``root`` is the Pheno4D folder
    (``mat/`` and / or ``swc/`` inside; default :func:`.trees.default_data_root`). ``log`` gets a line per section."""
    from ..curves.dp_numba import warm_up
    from ..evaluate.report import machine
    from .curves import benchmark_curves
    from .fourd import benchmark_4d
    from .model import benchmark_model
    from .trees import benchmark_trees, default_data_root

    root = Path(root) if root is not None else default_data_root()
    sizes = QUICK if quick else FULL
    out: dict[str, Any] = {"quick": quick, "data": str(root), "machine": machine(),
                           "settings": {k: {n: list(v) if isinstance(v, tuple) else v for n, v in s.items()}
                                        for k, s in sizes.items()},
                           "notes": [], "seconds": {}}
    t_all = time.perf_counter()
    say = log or (lambda _: None)

    def section(name: str, run: Callable[[], dict[str, Any]], needs: str | None = None) -> None:
        if needs is not None:
            out[name] = {"skipped": needs}
            out["notes"].append(f"{name}: skipped, {needs}")
            say(f"{name}: skipped ({needs})")
            return
        say(f"{name}...")
        t0 = time.perf_counter()
        out[name] = run()
        out["seconds"][name] = time.perf_counter() - t0
        say(f"{name}: {out['seconds'][name]:.1f} s")

    t0 = time.perf_counter()
    warm_up()  # a cold numba compile (once per install) stays out of every section's time
    out["seconds"]["warm_up"] = time.perf_counter() - t0
    swc, mat = root / "swc", root / "mat"
    missing = f"no Pheno4D data at {root} (swc/ or mat/)"
    section("curves", lambda: benchmark_curves(**sizes["curves"], pheno4d=swc))
    if not swc.is_dir() and "pheno4d" in sizes["curves"].get("kinds", ("pheno4d",)):
        out["notes"].append(f"curves: no Pheno4D paths ({swc} missing), synthetic curves only")
    section("trees", lambda: benchmark_trees(root, **sizes["trees"]), None if swc.is_dir() else f"no {swc}")
    source = "mat" if mat.is_dir() else "swc"  # the paper's trees when present
    section("4d", lambda: {**benchmark_4d(root, source=source, **sizes["4d"]),
                           "temporal_one_pair": _temporal_one_pair(**sizes["temporal_one_pair"])},
            None if (root / source).is_dir() else missing)
    section("model", lambda: benchmark_model(**sizes["model"]))
    out["ratios"] = ratios(out)
    out["ratio_is"] = "reference_s / ours_s: above 1, ours is faster; means against means"
    out["seconds"]["total"] = time.perf_counter() - t_all
    return out
