"""What only synthetic data can measure (docs/method.md §7): branch correspondences and growth clocks against
ground truth.

Runs on the ``synthetic`` source only (returns ``{}`` otherwise), per kind:

* **within plants**: every plant's within-sequence registration (:func:`~torch4dtree.temporal.register_sequence`,
  frame ``j`` onto ``j + 1``, the evaluation's ``lambdas``). Its consecutive-frame matches are read back from the
  identity table (two branches of frames ``j`` and ``j + 1`` share a slot exactly when the registration matched
  them) and scored against the organ labels (:func:`~torch4dtree.data.identity_scores`: precision over matched
  pairs, recall over organs present in both frames; spurs ignored); the chained identities are scored by
  :func:`~torch4dtree.temporal.within.identity_accuracy` (share of all branches of all frames sitting in their
  organ's slot). The identities are scored again with ``register_sequence``'s own default ``lp`` (tuned for
  identities) when the evaluation's differs.
* **across plants**: the same normalised time of two plants of the kind (the same frame index when, as in
  ``torch4dtree synth`` sets, plants share their days), at about 1/3, 2/3 and the end of the sequence, one tree
  registered onto the other with a rotation about the vertical (plants grow in any azimuth; ``settings.rotation``
  ``"so3"`` is used when asked for) and scored the same way (leaf ``k`` of one plant is leaf ``k`` of the other).
* **growth-warp recovery**: the same pairs of plants registered in space and time
  (:func:`~torch4dtree.temporal.register4d` on the within-sequence registrations above); the recovered time warp
  against the true relative clock :func:`~torch4dtree.data.relative_warp` (mean absolute error on the normalised
  grid), beside the identity warp (no registration) and an *oracle* layout that puts organs in slots by their
  labels (:func:`.oracle.label_features`), which isolates the
  temporal step from the spatial one. ``register4d`` is given the within-sequence registrations above (``lp``
  relative to each pair's reference frame); called on the raw sequences it would scale ``lp`` by the reference
  plant's last frame instead.

Pairs of plants: every pair while there are at most :data:`ALL_PAIRS_UP_TO` plants (15 pairs of 6 plants),
otherwise disjoint neighbours ``(0, 1), (2, 3), ...`` (an odd last plant pairs with the first), so that the
cost grows linearly beyond that (disjoint pairs alone can miss the pairs whose leaves match across the stem).
Precision and recall are pooled over pairs (counts summed), as
:func:`torch4dtree.bench.hierarchy.identity_accuracy` does.
``quick``: two plants, one pair, the last frame only.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, NamedTuple

import torch
from torch import Tensor

from ..data.synthetic import evaluate_warp, relative_warp
from ..data.truth import IdentityScores, identity_scores
from ..io.dataset import DatasetError
from .data import EvalData, EvalSettings, Plant4D
from .stats import fmt, md_table, summary

__all__ = ["markdown", "pair_matches", "plant_pairs", "pooled", "run", "true_warp", "warp_mae"]

# every pair of plants up to this many plants (28 pairs), disjoint neighbouring pairs beyond (module doc)
ALL_PAIRS_UP_TO = 8

CROSS_AT = (1 / 3, 2 / 3, 1.0)  # normalised times of the cross-plant comparisons
ORACLE_COMPONENTS = 5  # principal directions of the oracle layout's trajectories (as benchmark_growth_clocks)


def pooled(scores: Iterable[IdentityScores]) -> dict[str, Any]:
    """Precision and recall of several registrations with their counts pooled (micro-averaged): ``{"precision",
    "recall", "pairs", "matched", "common"}`` (``nan`` when nothing was counted)."""
    hit_p = tot_p = hit_r = tot_r = pairs = 0
    for sc in scores:
        pairs += 1
        if sc.n_matched:
            hit_p += round(sc.precision * sc.n_matched)
            tot_p += sc.n_matched
        if sc.n_common:
            hit_r += round(sc.recall * sc.n_common)
            tot_r += sc.n_common
    nan = float("nan")
    return {"precision": hit_p / tot_p if tot_p else nan, "recall": hit_r / tot_r if tot_r else nan,
            "pairs": pairs, "matched": tot_p, "common": tot_r}


def plant_pairs(n: int, quick: bool = False) -> list[tuple[int, int]]:
    """Every pair ``(i, k)``, ``i < k``, of ``n <= ALL_PAIRS_UP_TO`` plants; of more, disjoint neighbouring pairs
    (the odd one out pairs with plant 0); one pair when ``quick``."""
    if quick:
        return [(0, 1)] if n >= 2 else []
    if n <= ALL_PAIRS_UP_TO:
        return [(i, k) for i in range(n) for k in range(i + 1, n)]
    pairs = [(i, i + 1) for i in range(0, n - 1, 2)]
    if n % 2 == 1 and n >= 3:
        pairs.append((n - 1, 0))
    return pairs


class _Clock(NamedTuple):
    """A plant's growth clock from its ``dataset.json`` record, shaped as :func:`relative_warp` reads it."""

    grid: Tensor
    values: Tensor

    def warp(self, t: Tensor) -> Tensor:
        return evaluate_warp(self.grid, self.values, t)

    def warp_inverse(self, y: Tensor) -> Tensor:
        return evaluate_warp(self.values, self.grid, y)


def _clock(plant: Plant4D) -> _Clock:
    if plant.truth is None or "growth_warp" not in plant.truth:
        raise DatasetError(f"{plant.name}: no growth clock in the dataset's ground truth")
    gw = plant.truth["growth_warp"]
    return _Clock(torch.tensor(gw["grid"], dtype=torch.float64), torch.tensor(gw["values"], dtype=torch.float64))


def true_warp(a: Plant4D, b: Plant4D, t: Tensor) -> Tensor:
    """The true time warp of plant ``b`` onto ``a`` at normalised times ``t``, from their recorded clocks
    (:func:`~torch4dtree.data.relative_warp`: ``b`` at ``xi(t)`` is as developed as ``a`` at ``t``)."""
    return relative_warp(_clock(a), _clock(b), t)  # type: ignore[arg-type]


def warp_mae(warp: Tensor, true: Tensor) -> float:
    """Mean absolute error of a warp sampled on the normalised grid (the grid's points weigh equally)."""
    return float((warp.double() - true.double()).abs().mean())


def pair_matches(identity: Tensor, j: int) -> list[tuple[int, int]]:
    """The matches of frame ``j`` onto ``j + 1`` in a within-sequence identity table ``(n, S)``.

    ``identity[j, slot]`` is frame ``j``'s branch in that slot (``-1``: none); returns ``(branch_j, branch_j+1)``.

    Example:
        >>> import torch
        >>> pair_matches(torch.tensor([[0, -1, 1], [0, 1, 2]]), 0)
        [(0, 0), (1, 2)]
    """
    a, b = identity[j].tolist(), identity[j + 1].tolist()
    return [(x, y) for x, y in zip(a, b) if x >= 0 and y >= 0]


def _frame_labels(plant: Plant4D) -> list[list[int]]:
    f = plant.sequence.frames
    ptr, lab = f.ptr.tolist(), f.label.tolist()
    return [lab[a:b] for a, b in zip(ptr[:-1], ptr[1:])]


def _slot_labels(plant: Plant4D, aligned: Any) -> list[int]:
    """The organ label of every slot of a within-sequence registration: its branch in the latest frame holding it
    (the branch the representative tree, which the cross-sequence registration sees, takes)."""
    labels = _frame_labels(plant)
    last = aligned.latest_frame().tolist()
    ident = aligned.identity.tolist()
    return [labels[f][ident[f][k]] for k, f in enumerate(last)]


def _within(plant: Plant4D, lambdas: Sequence[float], progress: bool) -> tuple[Any, list[IdentityScores], Any]:
    """One plant's within-sequence registration, its consecutive-pair scores and its chained identity accuracy."""
    from ..temporal.within import identity_accuracy, register_sequence

    seq = plant.sequence.to(torch.float64)
    aligned = register_sequence(seq, lambdas=lambdas, rotation="none", progress=progress)
    labels = _frame_labels(plant)
    ident = aligned.identity.cpu()
    scores = [identity_scores(pair_matches(ident, j), labels[j], labels[j + 1]) for j in range(len(seq) - 1)]
    return aligned, scores, identity_accuracy(aligned, seq.frames.label)


def _within_rows(plants: Sequence[Plant4D], lambdas: Sequence[float], progress: bool
                 ) -> tuple[dict[int, Any], dict[str, Any]]:
    """Every plant's within-sequence registration (by index) and their pooled scores."""
    aligned: dict[int, Any] = {}
    scores: list[IdentityScores] = []
    chained, per_pair = [], []
    for i, plant in enumerate(plants):
        if len(plant.sequence) < 2:
            continue
        aligned[i], sc, acc = _within(plant, lambdas, progress)
        scores += sc
        chained.append(acc.sequence)
        per_pair.append(float(acc.per_pair.mean()))
    return aligned, {**pooled(scores), "lambdas": [float(x) for x in lambdas], "chained_sequence": summary(chained),
                     "chained_pair_mean": summary(per_pair)}


def default_within_lambdas(lambdas: Sequence[float]) -> tuple[float, float, float]:
    """``lambdas`` with the ``lp`` of :func:`~torch4dtree.temporal.register_sequence`'s default (tuned for
    identities between consecutive frames; the evaluation's ``lambdas`` may use another)."""
    from ..settings import WITHIN_LAMBDAS

    return float(lambdas[0]), float(lambdas[1]), WITHIN_LAMBDAS[2]


def _cross_lambdas(settings: EvalSettings) -> tuple[float, float, float]:
    """The cross-plant registrations' lambdas: the pipeline's cross-sequence lp where one is set."""
    lm, ls, lp = settings.lambdas
    return float(lm), float(ls), float(lp if settings.cross_lp is None else settings.cross_lp)


def _nearest_frame(plant: Plant4D, t: float) -> int:
    nt = plant.sequence.normalized_times().double()
    return int((nt - t).abs().argmin())


def _cross(a: Plant4D, b: Plant4D, at: Sequence[float], settings: EvalSettings, rotation: str
           ) -> list[tuple[float, int, int, IdentityScores]]:
    """Frames of ``a`` at normalised times ``at`` registered onto ``b``'s nearest frames, scored."""
    from ..trees.registration import register_trees

    fa_all, fb_all = a.sequence.frames.to(torch.float64), b.sequence.frames.to(torch.float64)
    la, lb = _frame_labels(a), _frame_labels(b)
    out = []
    for t in at:
        ja, jb = _nearest_frame(a, t), _nearest_frame(b, t)
        reg = register_trees(fa_all[ja], fb_all[jb], _cross_lambdas(settings), rotation,
                             positions=settings.cross_positions, order_tol=settings.cross_order_tol)
        out.append((t, ja, jb, identity_scores(reg.matches, la[ja], lb[jb])))
    return out


@contextmanager
def _deterministic() -> Iterator[None]:
    """Deterministic torch kernels inside (restored after)."""
    was, warn = torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(was, warn_only=warn)


def _oracle_warp(a: Plant4D, b: Plant4D, settings: EvalSettings) -> Tensor:
    """The temporal registration of ``b`` onto ``a`` in the ground-truth (organ label) layout."""
    from ..settings import TIME_WEIGHT
    from ..temporal.registration import register_trajectories
    from .oracle import label_features, pca_trajectories

    seqs = [a.sequence.to(torch.float64), b.sequence.to(torch.float64)]
    # a label may name several branches of a frame (spurs, organs the rule split): label_features writes them
    # into one slot by an indexed assignment whose winner varies from run to run on several threads; the
    # deterministic kernels make it the same every time
    with _deterministic():
        feats = label_features(seqs, seqs[0].frames.T)
    k = min(ORACLE_COMPONENTS, sum(len(s) for s in seqs) - 1)
    ta, tb = pca_trajectories(feats, [s.times for s in seqs], k, settings.n_t)
    return register_trajectories(ta, tb, time_weight=TIME_WEIGHT).warp  # register4d's temporal step


def _growth_warp(a: Plant4D, b: Plant4D, al_a: Any, al_b: Any, settings: EvalSettings, rotation: str
                 ) -> dict[str, Any]:
    """Recover ``b``'s clock relative to ``a``'s (``b`` at ``xi(t)`` is as developed as ``a`` at ``t``)."""
    from ..temporal.spatiotemporal import register4d

    reg = register4d(al_a, al_b, settings.lambdas, rotation, n_t=settings.n_t, cross=settings.cross_settings())
    grid = reg.times.double()
    true = true_warp(a, b, grid)
    # the slot correspondence the 4D registration kept (matches are (B slot, A slot)) against the organs
    slots = identity_scores(reg.matches, _slot_labels(b, al_b), _slot_labels(a, al_a))
    return {"slot_identity": slots, "spatial_candidate": reg.spatial_candidate,
            "reference": a.name, "moving": b.name, "warp_mae": warp_mae(reg.warp, true),
            "oracle_mae": warp_mae(_oracle_warp(a, b, settings), true), "identity_mae": warp_mae(grid, true),
            "distance_before": reg.distance_before, "distance_spatial": reg.distance_after_spatial,
            "distance_temporal": reg.distance_after_temporal, "kept_index_order": bool(reg.kept_index_order)}


def _kind(plants: list[Plant4D], settings: EvalSettings, progress: bool, timings: dict[str, float]
          ) -> dict[str, Any]:
    rotation = "so3" if settings.rotation == "so3" else "vertical"
    pairs = plant_pairs(len(plants), settings.quick)
    used = plants[:2] if settings.quick else plants  # quick: the one pair's plants
    t0 = time.perf_counter()
    aligned, within = _within_rows(used, settings.lambdas, progress)
    default_lam = default_within_lambdas(settings.lambdas)
    # the within-sequence default lp, beside the evaluation's (identities only: cheap, and telling when they differ)
    within_default = _within_rows(used, default_lam, progress)[1] if default_lam != tuple(settings.lambdas) else None
    timings["within"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    at = (1.0,) if settings.quick else CROSS_AT
    cross_rows = [(plants[i].name, plants[k].name, t, ja, jb, sc) for i, k in pairs
                  for t, ja, jb, sc in _cross(plants[i], plants[k], at, settings, rotation)]
    timings["cross"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    warps = [_growth_warp(plants[i], plants[k], aligned[i], aligned[k], settings, rotation) for i, k in pairs
             if i in aligned and k in aligned]
    timings["growth_warp"] += time.perf_counter() - t0
    return {
        "plants": len(used), "within": within, "within_default_lp": within_default,
        "cross": {**pooled(sc for *_, sc in cross_rows), "rotation": rotation, "at": list(at),
                  "per_time": {f"{t:.3g}": pooled(row[-1] for row in cross_rows if row[2] == t) for t in at},
                  "rows": [{"moving": m, "reference": r, "time": t, "frame_moving": ja, "frame_reference": jb,
                            "precision": sc.precision, "recall": sc.recall} for m, r, t, ja, jb, sc in cross_rows]},
        # the pipeline's cross-sequence correspondence (register4d's representatives) against the organs
        "cross_4d": pooled(w.pop("slot_identity") for w in warps),
        "growth_warp": {"warp_mae": summary(w["warp_mae"] for w in warps),
                        "oracle_mae": summary(w["oracle_mae"] for w in warps),
                        "identity_mae": summary(w["identity_mae"] for w in warps), "pairs": warps},
    }


def run(datas: dict[str, EvalData], settings: EvalSettings, progress: bool = False) -> dict[str, Any]:
    """The synthetic ground-truth section (module doc): ``{"synthetic": {"kinds": {kind: ...}, ...}}``."""
    data = datas.get("synthetic")
    if data is None or not data.has_truth:
        return {}
    timings = {"within": 0.0, "cross": 0.0, "growth_warp": 0.0}
    kinds = {kind: _kind(data.by_kind(kind), settings, progress, timings) for kind in data.kinds}
    what = {"within": "within-sequence registrations of the synthetic plants (register_sequence)",
            "cross": "cross-plant registrations of synthetic frames (vertical rotation)",
            "growth_warp": "spatiotemporal registrations of synthetic plant pairs (register4d) and oracle warps"}
    return {"synthetic": {"kinds": kinds, "lambdas": list(settings.lambdas), "n_t": settings.n_t,
                          "cross_registration": settings.cross_settings().to_dict()},
            "timings": {f"synthetic_{k}": {"seconds": v, "paper_seconds": None, "what": what[k]}
                        for k, v in timings.items()}}


def _pr(d: dict[str, Any]) -> str:
    return f"{fmt(d['precision'], percent=True)} / {fmt(d['recall'], percent=True)} ({d['pairs']})"


def _chained(w: dict[str, Any]) -> str:
    return f"{fmt(w['chained_sequence']['mean'], percent=True)}, {fmt(w['chained_sequence']['min'], percent=True)}"


def _within_table_rows(kind: str, v: dict[str, Any]) -> list[list[Any]]:
    """The evaluation's lambdas (with the cross-plant scores), then the within-sequence default lp if it differs."""
    w, wd = v["within"], v.get("within_default_lp")
    rows = [[kind, v["plants"], ", ".join(f"{x:g}" for x in w["lambdas"]), _pr(w), _chained(w), _pr(v["cross"])]]
    if wd:
        rows.append([kind, v["plants"], ", ".join(f"{x:g}" for x in wd["lambdas"]) + " (register_sequence default)",
                     _pr(wd), _chained(wd), "-"])
    return rows


def markdown(report: dict[str, Any]) -> list[str]:
    """The section's lines: branch-correspondence accuracy and growth-warp recovery per kind."""
    res = report.get("synthetic")
    if not res:
        return []
    kinds = res["kinds"]
    lines = ["## Synthetic ground truth", "",
             "Branch correspondences scored against the organ labels (spurs left out): precision = share of matched "
             "branch pairs holding the same organ, recall = share of the organs present in both trees whose "
             "branches were matched together, pooled over pairs (pairs in brackets). *Within*: consecutive frames "
             "of each plant (within-sequence registration, frame j onto j + 1, with the evaluation's lambdas "
             "(lm, ls, lp; lp relative to the plant's size) and with register_sequence's default lp); *chained*: "
             "share of all branches of a plant sitting in their organ's slot after chaining; *across*: two plants "
             "at the same normalised time (about 1/3, 2/3 and the end), rotation about the vertical, the "
             "cross-sequence registration's settings (positions, lp).", "",
             *md_table(["kind", "plants", "lambdas", "within P / R", "chained (mean, min)", "across P / R"],
                       [row for k, v in kinds.items() for row in _within_table_rows(k, v)]), "",
             "Growth-warp recovery: the spatiotemporal registration of pairs of plants (register4d) against the "
             "true relative clock h_b^-1(h_a(t)), mean absolute error on the normalised grid (mean over pairs, "
             "max in brackets); *oracle*: trajectories in a layout by ground-truth organ (temporal step alone); "
             "*identity*: no temporal registration. *Slots P / R*: the slot correspondence register4d kept "
             "(representatives' slots, labelled by their latest branch) against the organs.", "",
             *md_table(["kind", "pairs", "registered", "oracle layout", "identity warp", "slots P / R"],
                       [[k, len(v["growth_warp"]["pairs"])]
                        + [f"{fmt(v['growth_warp'][m]['mean'])} ({fmt(v['growth_warp'][m]['max'])})"
                           for m in ("warp_mae", "oracle_mae", "identity_mae")]
                        + [_pr(v["cross_4d"]) if "cross_4d" in v else "-"] for k, v in kinds.items()])]
    return lines

