"""Which hierarchy rule keeps branch identities stable: measurements on Pheno4D and synthetic plants.

* :func:`main_branch_agreement`: on every Pheno4D day that has both a raw SWC skeleton and the
  authors' hand-corrected ``.mat`` tree, how well the automatic main branch of the SWC file agrees
  with the hand-corrected main branch (the stem): the F1 score of the two polylines' coverage of
  each other within a tolerance, after aligning the roots.
"""

from __future__ import annotations

import re
import statistics
from pathlib import Path

import numpy as np
import torch

from ..curves.srvf import resample_polylines
from ..io import LoadOptions, read_sequence, read_swc_skeleton, read_tree
from ..settings import CROSS_LP, CROSS_ORDER_TOL, CROSS_POSITIONS, HIERARCHIES
from ..trees.skeleton import skeleton_to_branches


def _dense(poly: np.ndarray, step: float = 0.5) -> np.ndarray:
    """Points every ``step`` along a polyline ``(n, 3)``."""
    p = torch.as_tensor(poly, dtype=torch.float64)
    length = float((p[1:] - p[:-1]).norm(dim=-1).sum())
    n = max(int(length / step) + 1, 2)
    return resample_polylines(p[None], torch.tensor([len(p)]), n)[0].numpy()


def _coverage(a: np.ndarray, b: np.ndarray, tol: float) -> float:
    """Share of the points of ``a`` within ``tol`` of some point of ``b`` (both dense)."""
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min(1)
    return float((d <= tol).mean())


def polyline_agreement(a: np.ndarray, b: np.ndarray, tol: float) -> tuple[float, float, float]:
    """``(precision, recall, F1)`` of polyline ``a`` against ``b``: the share of ``a`` within ``tol`` of ``b``, the
    share of ``b`` within ``tol`` of ``a``, and their harmonic mean (1 = the same curve)."""
    da, db = _dense(a), _dense(b)
    p, r = _coverage(da, db, tol), _coverage(db, da, tol)
    return p, r, (0.0 if p + r == 0 else 2 * p * r / (p + r))


def _mat_folder(swc_plant: str) -> str:
    m = re.match(r"(?i)(tomato|maize)_?0*(\d+)", swc_plant)
    if not m:
        raise ValueError(f"not a Pheno4D plant folder name: {swc_plant}")
    kind, num = m.group(1).lower(), int(m.group(2))
    return f"tom_{num}_seq" if kind == "tomato" else f"maize{num:02d}_seq"


def day_pairs(root: str | Path) -> list[tuple[str, Path, Path]]:
    """``(plant, swc file, mat file)`` for every day present in both forms."""
    root = Path(root)
    out = []
    for plant in sorted(p for p in (root / "swc").iterdir() if p.is_dir()):
        mat_dir = root / "mat" / _mat_folder(plant.name)
        for swc in sorted(plant.glob("*.swc")):
            mmdd = re.search(r"_(\d{2})(\d{2})_", swc.name)
            mat = mat_dir / f"{mmdd.group(1)}_{mmdd.group(2)}.mat" if mmdd else None
            if mat is not None and mat.is_file():
                out.append((plant.name, swc, mat))
    return out


JOINT = "straightest, joint over time"

# Cross-plant registrations in identity_accuracy use the cross-sequence settings (torch4dtree.settings): children
# compared by node rank, a strong relative position weight and order-preserving children's matching, because plants
# of a kind compared at one calendar frame are at different developmental stages and node k of one plant is node k
# of the other. Consecutive frames keep the within-sequence setting (warped, lp 9): their young organs move along
# the stem.


def registration_settings(lp: float | None = CROSS_LP, positions: str = CROSS_POSITIONS,
                          order_tol: float | None = CROSS_ORDER_TOL) -> dict:
    """Keyword arguments of :func:`~torch4dtree.trees.registration.register_trees` (default: the cross-plant
    pairs'); ``lp``: relative, ``None``: ``lp = 1`` in the data's units."""
    if lp is None:
        return {"lambdas": (1.0, 1.0, 1.0), "lp_relative": False, "positions": positions, "order_tol": order_tol}
    return {"lambdas": (1.0, 1.0, lp), "lp_relative": True, "positions": positions, "order_tol": order_tol}


def main_branch_agreement(root: str | Path, rules: tuple[str, ...] = (*HIERARCHIES, JOINT),
                          tol_fraction: float = 0.02, max_root_gap: float = 5.0) -> dict:
    """Per rule and species: how the SWC main branch compares with the hand-corrected ``.mat`` main branch (the stem)
    of the same day: mean precision (share of the SWC main branch on the stem), recall (share of the stem covered),
    F1, and the share of days whose main branch covers the stem (recall >= 0.9) without running far beyond it
    (precision >= 0.6). ``tol = tol_fraction * plant height`` (at least 2 mm). Days whose roots lie more than
    ``max_root_gap`` mm apart in the two files (differently cropped scans) cannot be compared and are counted apart.
    Rule :data:`JOINT`: the main branch as :func:`~torch4dtree.io.read_sequence` chooses it over the plant's whole
    SWC sequence (:mod:`torch4dtree.trees.growth`), resampled at 64 points."""
    joint_mains: dict[Path, np.ndarray] = {}

    def joint_main(swc: Path) -> np.ndarray:
        if swc not in joint_mains:  # one read per plant folder
            loaded = read_sequence(swc.parent, LoadOptions(T=64, repair=True, dtype=torch.float64))
            for k, name in enumerate(loaded.files):
                joint_mains[swc.parent / name] = loaded.sequence.frames[k].points[0].numpy()
        return joint_mains[swc]

    rows: dict[str, dict[str, list[tuple[float, float, float]]]] = {r: {"tomato": [], "maize": []} for r in rules}
    skipped = {"tomato": 0, "maize": 0}
    for plant, swc, mat in day_pairs(root):
        kind = "tomato" if plant.lower().startswith("tom") else "maize"
        ref = read_tree(mat)
        if ref is None:
            continue
        stem = ref.points[0].double().numpy()
        sk = read_swc_skeleton(swc, repair=True)
        shift = stem[0] - sk.xyz[sk.parent == -1][0]
        if float(np.linalg.norm(shift)) > max_root_gap:
            skipped[kind] += 1
            continue
        height = float(sk.xyz[:, 2].max() - sk.xyz[:, 2].min())
        tol = max(tol_fraction * height, 2.0)
        for rule in rules:
            if rule == JOINT:
                main = joint_main(swc)
            else:
                main = skeleton_to_branches(sk.xyz, sk.parent, where=str(swc), hierarchy=rule)[0][0]
            rows[rule][kind].append(polyline_agreement(main + shift, stem, tol))
    out: dict = {"skipped_days": skipped}
    for rule, kinds in rows.items():
        out[rule] = {}
        for k, v in kinds.items():
            if not v:
                continue
            p, r, f = (statistics.fmean(x[i] for x in v) for i in range(3))
            out[rule][k] = {"days": len(v), "precision": p, "recall": r, "f1": f,
                            "agree_share": sum(x[1] >= 0.9 and x[0] >= 0.6 for x in v) / len(v)}
    return out


def identity_accuracy(kinds: tuple[str, ...] = ("tomato", "maize", "bean"), seeds: tuple[int, ...] = (0, 1, 2),
                      rules: tuple[str, ...] = HIERARCHIES, lp_per_length: tuple[float | None, ...] = (9.0,),
                      n_frames: int = 10, T: int = 32, cross_plant: bool = True,
                      joint_hierarchy: bool = True, positions: str = "warped",
                      cross_lp_per_length: float | None = CROSS_LP,
                      cross_positions: str | None = CROSS_POSITIONS,
                      cross_order_tol: float | None = CROSS_ORDER_TOL) -> list[dict]:
    """Identity precision / recall of registrations of realistic synthetic plants against their organ truth.

    For every kind, hierarchy rule and relative position weight (``lp_per_length``: the relative ``lp``,
    9 = within-sequence registration's default; ``None``: ``lp = 1`` in the data's units):
    consecutive frames of each plant (``seeds`` plants) and, with ``cross_plant``, the same frame of two
    different plants (frames 3, 6, 9; vertical rotation). ``joint_hierarchy``: main branches chosen jointly over
    time (:mod:`torch4dtree.trees.growth`, the default) or by the rule on each frame alone. ``positions``: how
    children's places are compared (:func:`~torch4dtree.trees.registration.register_to_reference`);
    ``cross_lp_per_length`` / ``cross_positions``: the cross-plant pairs' settings (default
    :data:`CROSS_LP`, :data:`CROSS_POSITIONS`; ``None``: the consecutive pairs' ones);
    ``cross_order_tol``: their children's matching (default ordered, :data:`CROSS_ORDER_TOL`; ``None``: any).
    Rows are ``{kind, rule, joint_hierarchy, lp_per_length, positions, consecutive: {precision, recall, pairs},
    cross: {..., lp_per_length, positions, order_tol}, seconds}``, micro-averaged (counts pooled).
    """
    import time

    from ..data import score_registration, synthetic_plant
    from ..trees.registration import register_trees

    rows = []
    for kind in kinds:
        for rule in rules:
            plants = [synthetic_plant(kind, seed, n_frames=n_frames, T=T, dtype=torch.float64,
                                      hierarchy_kwargs={"hierarchy": rule}, joint_hierarchy=joint_hierarchy)
                      for seed in seeds]
            for lpl in lp_per_length:
                t0 = time.perf_counter()

                kw = registration_settings(lpl, positions, None)
                cross_lp = lpl if cross_lp_per_length is None else cross_lp_per_length
                cross_kw = registration_settings(cross_lp, positions if cross_positions is None else cross_positions,
                                                 cross_order_tol)

                def pooled(pairs: list[tuple], kw: dict = kw) -> dict:
                    hit_p = tot_p = hit_r = tot_r = 0.0
                    for mov, ref, rotation in pairs:
                        sc = score_registration(register_trees(mov, ref, rotation=rotation, **kw), mov, ref)
                        hit_p += sc.precision * sc.n_matched
                        tot_p += sc.n_matched
                        hit_r += sc.recall * sc.n_common
                        tot_r += sc.n_common
                    return {"precision": hit_p / max(tot_p, 1), "recall": hit_r / max(tot_r, 1), "pairs": len(pairs)}

                frames = [p.sequence.frames for p in plants]
                row = {"kind": kind, "rule": rule, "joint_hierarchy": joint_hierarchy, "lp_per_length": lpl,
                       "positions": positions,
                       "consecutive": pooled([(f[j], f[j + 1], "none") for f in frames for j in range(len(f) - 1)])}
                if cross_plant and len(plants) > 1:
                    row["cross"] = pooled([(frames[a][j], frames[b][j], "vertical") for a in range(len(plants))
                                           for b in range(a + 1, len(plants)) for j in (3, 6, 9) if j < n_frames],
                                          cross_kw)
                    row["cross"].update(lp_per_length=cross_lp, positions=cross_kw["positions"],
                                        order_tol=cross_order_tol)
                row["seconds"] = time.perf_counter() - t0
                rows.append(row)
    return rows


def _pool(scores: list) -> dict:
    """Micro-averaged ``{precision, recall, pairs}`` of :class:`~torch4dtree.data.IdentityScores`."""
    matched = sum(s.n_matched for s in scores)
    common = sum(s.n_common for s in scores)
    return {"precision": sum(s.precision * s.n_matched for s in scores if s.n_matched) / max(matched, 1),
            "recall": sum(s.recall * s.n_common for s in scores if s.n_common) / max(common, 1), "pairs": len(scores)}


def library_identities(kinds: tuple[str, ...] = ("tomato", "maize", "bean", "almond"),
                       seeds: tuple[int, ...] = (0, 1, 2), rules: tuple[str, ...] = HIERARCHIES,
                       n_frames: int = 10, T: int = 32) -> list[dict]:
    """Identity precision / recall between consecutive frames of realistic synthetic plants, as a user gets them
    with the library's defaults: each frame read alone by the rule and ``register_trees(frame j, frame j + 1)``
    (``"pairs"``), and the frames read as one sequence (joint hierarchy) and chained by ``register_sequence``
    (``"sequence"``: the pairs of branches that share a slot in consecutive frames). Rows are ``{kind, rule, pairs:
    {precision, recall, pairs}, sequence: {...}, seconds}``, micro-averaged over ``seeds`` plants."""
    import time

    from ..data import identity_scores, score_registration, synthetic_plant
    from ..temporal.within import register_sequence
    from ..trees.registration import register_trees

    rows = []
    for kind in kinds:
        for rule in rules:
            t0 = time.perf_counter()
            alone, joint = [], []
            for seed in seeds:
                frames = synthetic_plant(kind, seed, n_frames=n_frames, T=T, dtype=torch.float64,
                                         hierarchy_kwargs={"hierarchy": rule}, joint_hierarchy=False).sequence.frames
                alone += [score_registration(register_trees(frames[j], frames[j + 1]), frames[j], frames[j + 1])
                          for j in range(len(frames) - 1)]
                seq = synthetic_plant(kind, seed, n_frames=n_frames, T=T, dtype=torch.float64,
                                      hierarchy_kwargs={"hierarchy": rule}).sequence
                identity = register_sequence(seq).identity.tolist()
                labels = [seq.frames[j].label.tolist() for j in range(len(seq))]
                for j in range(len(seq) - 1):
                    matches = [(a, b) for a, b in zip(identity[j], identity[j + 1]) if a >= 0 and b >= 0]
                    joint.append(identity_scores(matches, labels[j], labels[j + 1]))
            rows.append({"kind": kind, "rule": rule, "pairs": _pool(alone), "sequence": _pool(joint),
                         "seconds": time.perf_counter() - t0})
    return rows


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys

    print(json.dumps(main_branch_agreement(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/pheno4d"), indent=1))
