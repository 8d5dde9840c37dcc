"""Table 3 of the paper: temporal registration of 4D plants, 4D distance before and after, beside the paper's figures.

Everything runs on one source, the one Table 1's 4D rows use (:func:`.data.primary_source`: the paper's ``.mat``
trees when present, else the synthetic plants, else SWC). The distance is :mod:`torch4dtree.temporal`'s 4D distance
between trajectories in the tree space (``n_t`` common times); *before* is with the identity time warp (after any
spatial registration), *after* with the optimal one. Four rows per kind:

* **(a) pairs**: every pair of plants of the kind (the paper drew 6 tomato and 4 maize pairs at random; all pairs
  is more pairs and no draw), each registered in space and time by :func:`~torch4dtree.temporal.register4d`
  (:func:`.pairs.registered_pairs`, shared with Table 1). Frames sit at their acquisition days. Before = after the
  spatial registration, after = after the temporal one.
* **(a) unsynchronised pairs**: the paper "randomly resample[d] the 4D sequences to simulate unsynchronised 4D
  plants" before pairing them (its scripts register a plant's ``_altered`` copy, frames evenly spaced, onto another
  plant). Here the moving plant of each pair above loses its missing days (below) and its frames are re-timed by
  its random warp; its frames keep their coordinates in the pair's tree space, so the spatial registration is that
  of the row above and only the timing changes.
* **(b) warped copy**: each plant against a copy of itself whose frames are re-timed by a random warp ``gamma``.
  Same trees, so the correspondence is known and this isolates the temporal registration: both trajectories are
  built from the plant's frames in its own tree space (PCA of its frames, all components: coefficient distances
  are tree distances).
* **(b) warped copy, missing days**: the copy also loses days -- the Pheno4D ``_alt`` / ``_altered`` copy (the days
  the paper's authors removed for these experiments) where there is one, else a random 40 % of the interior
  frames (first and last kept, at least 3 frames). Twice: with the same trees as above (trajectories only: what
  the missing days alone cost), and through the whole pipeline, as in the paper's scripts: the copy's own
  within-sequence registration, spatial registration onto the original, temporal registration
  (:func:`~torch4dtree.temporal.register4d`). Beside the first, ``unwarped``: the distance of the copy with missing
  days at its true days (no warp), what the missing days alone cost -- the floor the registration is up against.

**Random warps.** One per plant (in the data's plant order, whatever ``quick`` keeps, so a quick run is a subset):
``gamma = random_warp(strength=WARP_STRENGTH)`` (smooth, monotone; mean ``|gamma - id|`` about 0.145 on ``[0, 1]``),
drawn from ``settings.generator(SEED_OFFSET)`` with the simulated missing days. Frame ``j`` at normalised time
``u_j`` (first day 0, last 1) is shown by the copy at ``gamma(u_j)``: the copy is the plant running on another
clock. (a) unsynchronised and (b) share a plant's warp and missing days.

**Recovered-warp error** (rows (b)). :func:`~torch4dtree.temporal.register_trajectories` returns ``xi`` with
``mov(xi(t)) ~ ref(t)``. The copy ``c`` holds frame ``j`` at ``gamma(u_j)`` and both trajectories are linear between
frames, so ``c(xi*(t)) = a(t)`` exactly for ``xi*`` the piecewise-linear map ``u_j -> gamma(u_j)`` through the
copy's frames: the true warp is ``gamma`` (forward, not its inverse) at the frames, linear in between
(:func:`true_warp`). Error = mean ``|xi - xi*|`` on ``linspace(0, 1, n_t)``; the identity's error (mean
``|t - xi*|``) stands beside it as the size of the warp. With missing days no warp makes the copy equal the plant
between kept frames; ``xi*`` is the same map through the kept frames. The copy is passed to the registration
:func:`~torch4dtree.temporal.trajectory.fine_size` samples, as :func:`~torch4dtree.temporal.register4d` passes the
moving plant: its ``n_t`` samples alone cut the corners its frames make between grid times, differently from the
plant's samples, and no warp of them removes more than ~90 % (tomato) / ~94 % (maize) of the distance of (b) on
Pheno4D at ``n_t = 32`` (``register_trajectories``' module constants).

Absolute distances are in each source's units (ours: mm-based SRVF norms; the paper's its own scaling): compare the
after / before ratios of the means. Timing: one temporal registration (the DP on a pair's trajectories) against
the paper's 6 ms (maize) to 37 ms (tomato).
"""

from __future__ import annotations

import statistics
import time
import timeit
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from ..curves.warps import random_warp
from ..data.synthetic import evaluate_warp
from ..settings import TIME_WEIGHT
from ..space.pca import TreePCA
from ..temporal import AlignedSequence, SpatiotemporalRegistration, register4d, register_sequence
from ..temporal.registration import register_trajectories
from ..temporal.trajectory import fine_size, resample_trajectory
from ..trees.structures import TreeSequence
from .data import EvalData, EvalSettings, Plant4D, primary_source
from .pairs import aligned_sequence, registered_pairs
from .paper import SECONDS
from .stats import fmt, md_table, summary

__all__ = ["PAPER_TABLE3", "PlantWarp", "markdown", "plant_warps", "run", "true_warp", "warp_error", "warped_copies"]

# the paper's Table 3: (a) between pairs of plants, (b) between a plant and its randomly warped copy
PAPER_TABLE3 = {
    "pairs": {"tomato": {"before": {"mean": 382.0, "median": 384.0, "std": 69.0},
                         "after": {"mean": 279.0, "median": 282.0, "std": 47.0}},
              "maize": {"before": {"mean": 59.0, "median": 60.0, "std": 12.0},
                        "after": {"mean": 34.0, "median": 37.0, "std": 11.0}}},
    "warped": {"tomato": {"before": {"mean": 356.0, "median": 375.0, "std": 138.0},
                          "after": {"mean": 26.0, "median": 27.0, "std": 5.0}},
               "maize": {"before": {"mean": 71.0, "median": 70.0, "std": 8.0},
                         "after": {"mean": 15.0, "median": 16.0, "std": 3.0}}},
}
PAPER_SECONDS = {"maize": SECONDS["temporal_maize"], "tomato": SECONDS["temporal_tomato"]}
# rows of the table: (key, label, the paper's part it stands beside)
ROWS = (("pairs", "(a) pairs", "pairs"), ("pairs_unsync", "(a) unsynchronised pairs", "pairs"),
        ("warped", "(b) warped copy", "warped"), ("warped_missing", "(b) warped copy, missing days", "warped"),
        ("warped_missing_pipeline", "(b) warped copy, missing days, whole pipeline", "warped"))
WARPED_ROWS = ("warped", "warped_missing", "warped_missing_pipeline")
SEED_OFFSET = 3  # settings.generator stream of this table
WARP_STRENGTH = 1.0
WARP_GRID = 1001  # points of each random warp (evaluated piecewise linearly at the frames)
DROP_SHARE = 0.4  # simulated missing days: share of interior frames (the Pheno4D altered copies drop 30-55 %)
QUICK_PLANTS = 2  # plants per kind in (b) with settings.quick (pairs: .pairs.plant_pairs' own limit)
TOL = 1e-9


@dataclass(frozen=True)
class PlantWarp:
    """A plant's random clock: ``gamma (WARP_GRID,)`` on ``linspace(0, 1, WARP_GRID)``; ``keep``: its frames kept with
    missing days (indices into the plant's sequence); ``altered``: whether they are the Pheno4D altered copy's."""

    gamma: Tensor
    keep: list[int]
    altered: bool

    def at(self, u: Tensor) -> Tensor:
        """``gamma(u)``: where the copy shows the frames at normalised times ``u``."""
        return evaluate_warp(torch.linspace(0, 1, len(self.gamma), dtype=torch.float64), self.gamma, u)


def _kept_days(plant: Plant4D, generator: torch.Generator) -> tuple[list[int], bool]:
    """The frames of ``plant`` left with missing days: its altered copy's days when it has one, else a random
    ``DROP_SHARE`` of its interior frames removed (always drawn, so every plant uses the generator alike)."""
    n = len(plant.sequence)
    perm = torch.randperm(max(n - 2, 0), generator=generator) + 1
    if plant.altered is not None:
        times = plant.sequence.times
        keep = [int(i) for t in plant.altered.times for i in torch.nonzero(torch.isclose(times, t))[:, 0]]
        if len(keep) == len(plant.altered) and keep and keep[0] == 0 and keep[-1] == n - 1:
            return keep, True
        # an altered copy whose days are not the plant's, or that loses the first or last day, has no true warp
    drop = min(round(DROP_SHARE * (n - 2)), n - 3)
    return sorted(set(range(n)) - set(perm[:max(drop, 0)].tolist())), False


def plant_warps(data: EvalData, settings: EvalSettings) -> dict[str, PlantWarp]:
    """Every plant's random warp and kept days (module doc), drawn in plant order from ``settings``' generator."""
    g = settings.generator(SEED_OFFSET)
    out = {}
    for p in data.plants:
        gamma = random_warp(1, WARP_GRID, generator=g, strength=WARP_STRENGTH)[0]
        keep, altered = _kept_days(p, g)
        out[p.name] = PlantWarp(gamma, keep, altered)
    return out


def true_warp(u: Tensor, s: Tensor, n_t: int) -> Tensor:
    """The warp ``xi*`` on ``linspace(0, 1, n_t)`` that registers a copy showing frames at normalised times ``s`` onto
    the plant showing them at ``u``: piecewise linear through ``(u_j, s_j)`` (module doc)."""
    return evaluate_warp(u, s, torch.linspace(0, 1, n_t, dtype=torch.float64))


def warp_error(warp: Tensor, truth: Tensor) -> float:
    """Mean absolute difference of two warps on the same grid (normalised time)."""
    return float((warp.double() - truth.double()).abs().mean())


def _stats(before: Sequence[float], after: Sequence[float]) -> dict[str, Any]:
    return {"n": len(before), "before": summary(before), "after": summary(after),
            "ratio": statistics.fmean(after) / statistics.fmean(before) if before else float("nan"),
            "lowered": sum(a < b - TOL for a, b in zip(after, before)),
            "raised": sum(a > b + TOL for a, b in zip(after, before))}


def _pairs(data: EvalData, kind: str, settings: EvalSettings, warps: dict[str, PlantWarp], progress: bool
           ) -> tuple[dict[str, Any], dict[str, Any], list[float]]:
    """Rows (a) and (a) unsynchronised, and each pair's temporal registration time (best of 3, seconds)."""
    rows = registered_pairs(data, kind, settings, progress)
    real, unsync, seconds = [], [], []
    for ref, mov, r in rows:
        # the temporal registration as register4d runs it (with its time coordinate)
        seconds.append(min(timeit.repeat(lambda r=r: register_trajectories(r.alpha_ref, r.alpha_mov_fine,
                                                                           time_weight=TIME_WEIGHT),
                                         number=1, repeat=3)))
        real.append({"reference": ref, "moving": mov, "unregistered": r.distance_before,
                     "before": r.distance_after_spatial, "after": r.distance_after_temporal,
                     "kept_index_order": r.kept_index_order})
        unsync.append(_unsynchronised(r, warps[mov], settings.n_t) | {"reference": ref, "moving": mov})
    out = []
    for table in (real, unsync):
        res = _stats([x["before"] for x in table], [x["after"] for x in table])
        out.append(res | {"rows": table})
    out[0]["unregistered"] = summary(x["unregistered"] for x in real)
    return out[0], out[1], seconds


def _unsynchronised(r: SpatiotemporalRegistration, warp: PlantWarp, n_t: int) -> dict[str, Any]:
    """The moving plant of a registered pair, its missing days dropped and its frames re-timed by its warp, registered
    again onto the reference in the pair's tree space."""
    mov = r.sequences[1]
    coeffs = r.pca.transform(r.layout)[len(r.sequences[0]):]  # the layout holds the reference's frames first
    u = mov.normalized_times().double()[warp.keep]
    s = warp.at(u)
    alpha = resample_trajectory(coeffs[warp.keep], s, fine_size(n_t, s))  # as register4d's moving one
    t = register_trajectories(r.alpha_ref, alpha, time_weight=TIME_WEIGHT)  # register4d's temporal step
    return {"before": float(t.distance_before), "after": float(t.distance), "frames": len(warp.keep),
            "of": len(mov), "altered": warp.altered}


def warped_copies(aligned: AlignedSequence, warp: PlantWarp, n_t: int) -> list[dict[str, Any]]:
    """(b) with the same trees: the plant against its frames re-timed by its warp, all of them and those kept with
    missing days (none when it has too few frames to lose any), in the plant's own tree space (module doc)."""
    coeffs = TreePCA(n_components=max(len(aligned) - 1, 1)).fit(aligned.aligned).transform(aligned.aligned)
    u = aligned.normalized_times().double()
    alpha = resample_trajectory(coeffs, u, n_t)
    grid = torch.linspace(0, 1, n_t, dtype=torch.float64)
    out = []
    for keep in (list(range(len(aligned))), warp.keep)[:1 + (len(warp.keep) < len(aligned))]:
        s = warp.at(u[keep])
        t0 = time.perf_counter()
        t = register_trajectories(alpha, resample_trajectory(coeffs[keep], s, fine_size(n_t, s)))  # as register4d's
        seconds = time.perf_counter() - t0
        truth = true_warp(u[keep], s, n_t)
        # the copy at its true times (no warp): what the missing days alone cost (0 with every frame)
        floor = register_trajectories(alpha, resample_trajectory(coeffs[keep], u[keep], n_t)).distance_before
        out.append({"before": float(t.distance_before), "after": float(t.distance), "unwarped": float(floor),
                    "warp_error": warp_error(t.warp, truth), "identity_error": warp_error(grid, truth),
                    "frames": len(keep), "of": len(aligned), "altered": warp.altered and len(keep) < len(aligned),
                    "seconds": seconds})
    return out


def _warped_missing(plant: Plant4D, aligned: AlignedSequence, warp: PlantWarp, settings: EvalSettings
                    ) -> dict[str, Any]:
    """(b) with missing days: the copy (kept frames at their warped times) through the whole pipeline."""
    u = plant.sequence.normalized_times().double()[warp.keep]
    s = warp.at(u)
    times = plant.sequence.times
    span = times[-1] - times[0]
    frames = plant.altered.frames if warp.altered else plant.sequence.frames[warp.keep]
    copy = TreeSequence(frames, (times[0] + s.to(times.dtype) * span), f"{plant.name} (warped, missing days)")
    t0 = time.perf_counter()
    mov = register_sequence(copy)  # the library's defaults, as .pairs.aligned_sequence registers the plants
    r = register4d(aligned, mov, settings.lambdas, settings.rotation, settings.n_t, cross=settings.cross_settings())
    seconds = time.perf_counter() - t0
    truth = true_warp(u, s, settings.n_t)
    return {"unregistered": r.distance_before, "before": r.distance_after_spatial, "after": r.distance_after_temporal,
            "warp_error": warp_error(r.warp, truth), "identity_error": warp_error(r.times, truth),
            "frames": len(warp.keep), "of": len(plant.sequence), "altered": warp.altered, "seconds": seconds}


def _warped(data: EvalData, kind: str, settings: EvalSettings, warps: dict[str, PlantWarp], progress: bool
            ) -> dict[str, dict[str, Any]]:
    """The (b) rows of ``kind`` (:data:`WARPED_ROWS`)."""
    plants = [p for p in data.by_kind(kind) if len(p.sequence) >= 2]
    plants = plants[:QUICK_PLANTS] if settings.quick else plants
    tables: dict[str, list[dict[str, Any]]] = {k: [] for k in WARPED_ROWS}
    for p in tqdm(plants, desc=f"warped copies ({kind})", unit="plant", disable=not progress):
        aligned = aligned_sequence(data, p.name)
        for key, res in zip(WARPED_ROWS, warped_copies(aligned, warps[p.name], settings.n_t)):
            tables[key].append(res | {"plant": p.name})
        if len(warps[p.name].keep) < len(p.sequence):  # too few frames to lose any: no row
            tables[WARPED_ROWS[2]].append(_warped_missing(p, aligned, warps[p.name], settings) | {"plant": p.name})
    out = {}
    for key, table in tables.items():
        res = _stats([x["before"] for x in table], [x["after"] for x in table])
        res["warp_error"] = summary(x["warp_error"] for x in table)
        res["identity_error"] = summary(x["identity_error"] for x in table)
        # copies whose recovered warp is farther from the truth than the identity (registration made timing worse)
        res["warp_worse_than_identity"] = sum(x["warp_error"] > x["identity_error"] for x in table)
        res["altered"] = sum(x["altered"] for x in table)
        if table and "unwarped" in table[0]:
            res["unwarped"] = summary(x["unwarped"] for x in table)
        out[key] = res | {"rows": table}
    return out


def run(datas: dict[str, EvalData], settings: EvalSettings, progress: bool = False) -> dict[str, Any]:
    source = primary_source(datas)
    data = datas[source]
    warps = plant_warps(data, settings)
    pheno4d = source in ("mat", "swc")  # the paper measured Pheno4D: its figures stand beside those only
    table: dict[str, Any] = {"source": source, "n_t": settings.n_t, "warp_strength": WARP_STRENGTH,
                             "drop_share": DROP_SHARE, "kinds": {}, "worse_than_paper": []}
    timings: dict[str, Any] = {}
    for kind in data.kinds:
        t0 = time.perf_counter()
        row: dict[str, Any] = {}
        seconds: list[float] = []
        if len(data.by_kind(kind)) >= 2:
            row["pairs"], row["pairs_unsync"], seconds = _pairs(data, kind, settings, warps, progress)
        t1 = time.perf_counter()
        row.update(_warped(data, kind, settings, warps, progress))
        t2 = time.perf_counter()
        for key, _, part in ROWS:
            paper = PAPER_TABLE3[part].get(kind) if pheno4d else None
            if key in row and paper is not None:
                row[key]["paper"] = {**paper, "ratio": paper["after"]["mean"] / paper["before"]["mean"]}
                if row[key]["n"] and row[key]["ratio"] > row[key]["paper"]["ratio"]:
                    table["worse_than_paper"].append([kind, key])
        table["kinds"][kind] = row
        if seconds:
            timings[f"temporal_register_{kind}"] = {
                "seconds": statistics.median(seconds), "paper_seconds": PAPER_SECONDS.get(kind) if pheno4d else None,
                "what": f"one temporal registration of two 4D {kind} plants (DP on their trajectories, n_t = "
                        f"{settings.n_t}; median over the {len(seconds)} Table 3 (a) pairs of the best of 3; paper: "
                        "6 ms maize to 37 ms tomato)"}
        timings[f"table3_pairs_{kind}"] = {
            "seconds": t1 - t0, "paper_seconds": None,
            "what": f"Table 3 (a), {kind}: register4d of every pair (shared with Table 1: free when it ran first) "
                    "and the unsynchronised re-registrations"}
        timings[f"table3_warped_{kind}"] = {
            "seconds": t2 - t1, "paper_seconds": None,
            "what": f"Table 3 (b), {kind}: warped copies (trajectories only) and warped copies with missing days "
                    "(within-sequence, spatial and temporal registration)"}
    return {"table3": table, "timings": timings}


def _paper_cell(stats: dict[str, float] | None) -> str:
    return "/".join(fmt(stats[s]) for s in ("mean", "median", "std")) if stats else "-"


def markdown(report: dict[str, Any]) -> list[str]:
    t3 = report["table3"]
    lines = ["## Table 3: temporal registration", "",
             f"4D distance ({t3['source']}, n_t = {t3['n_t']}) before (identity time warp, after spatial registration) "
             "and after temporal registration; mean / median / std; ratio = mean after / mean before, to compare "
             "with the paper's (absolute values are in different scalings). (a) every pair of plants of a kind at "
             "their acquisition days; (a) unsynchronised: the moving plant with its missing days removed and "
             "re-timed by a random warp, as the paper's resampling; (b) each plant against a copy of itself "
             f"re-timed by a random warp (strength {t3['warp_strength']}), with the same trees (trajectories only), "
             "with missing days too (the Pheno4D altered copy, else a random "
             f"{round(100 * t3['drop_share'])} % of the interior days), and with missing days through the whole "
             "pipeline (the copy registered within itself and in space before time). Warp error: mean "
             "|recovered - true| on the normalised time grid (the identity's in brackets).", ""]
    rows = []
    for kind, r in t3["kinds"].items():
        for key, label, _ in ROWS:
            if key not in r:
                continue
            x, p = r[key], r[key].get("paper")
            werr = (f"{fmt(x['warp_error']['mean'])} ({fmt(x['identity_error']['mean'])})" if "warp_error" in x
                    else "-")
            rows.append([label, kind, str(x["n"]), _paper_cell(x["before"]), _paper_cell(x["after"]), fmt(x["ratio"]),
                         _paper_cell(p["before"]) if p else "-", _paper_cell(p["after"]) if p else "-",
                         fmt(p["ratio"]) if p else "-", f"{x['lowered']}/{x['n']}", werr])
    lines += md_table(["experiment", "kind", "n", "before mean/median/std", "after mean/median/std", "ratio",
                       "paper before", "paper after", "paper ratio", "lowered", "warp error (identity)"], rows)
    label = {key: name for key, name, _ in ROWS}
    notes = []
    if t3["worse_than_paper"]:
        notes.append("**Worse than the paper's relative reduction** (our after / before ratio is higher): "
                     + "; ".join(f"{label[key]}, {kind}" for kind, key in t3["worse_than_paper"]) + ".")
    raised = [f"{label[key]}, {k}: {r[key]['raised']}" for k, r in t3["kinds"].items() for key in label
              if key in r and r[key]["raised"]]
    if raised:
        notes.append(f"**Distance raised by the temporal registration** on: {'; '.join(raised)}.")
    flat = [f"{label[key]}, {k}: {r[key]['n'] - r[key]['lowered']}" for k, r in t3["kinds"].items() for key in label
            if key in r and r[key]["n"] - r[key]["lowered"] - r[key]["raised"]]
    if flat:
        notes.append(f"Left unchanged by the temporal registration (identity warp kept): {'; '.join(flat)}.")
    worse = [f"{label[key]}, {k}: {r[key]['warp_worse_than_identity']}/{r[key]['n']}" for k, r in t3["kinds"].items()
             for key in WARPED_ROWS if r[key]["warp_worse_than_identity"]]
    if worse:
        notes.append(f"**Recovered warp farther from the truth than the identity** on: {'; '.join(worse)}.")
    floor = [f"{k} {fmt(r['warped_missing']['unwarped']['mean'])} (after {fmt(r['warped_missing']['after']['mean'])})"
             for k, r in t3["kinds"].items() if r["warped_missing"]["n"]]
    if floor:
        notes.append("Missing days alone (same trees, true times, no warp) leave a mean distance of "
                     f"{'; '.join(floor)}: the residual of the missing-days rows is mostly theirs.")
    missing = [f"{k}: {r['warped_missing']['altered']} of {r['warped_missing']['n']} copies from the altered data"
               for k, r in t3["kinds"].items() if r["warped_missing"]["n"]]
    if missing:
        notes.append(f"Missing days: {'; '.join(missing)} (the rest simulated).")
    for n in notes:
        lines += ["", n]
    return lines
