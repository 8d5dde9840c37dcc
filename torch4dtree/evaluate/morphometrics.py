"""Morphometrics of 4D plants, and the comparison of two populations by them (docs/method.md §7).

Independent of the package's own metric: a generator that shrinks plants, loses organs or makes hairballs shows
here even when its 4D distance looks fine (the neuron-generation protocol: morphometric distributions of generated
against real plants).

**Per frame** (a skeleton graph: an SWC file, or a tree written as one by
:func:`~torch4dtree.trees.skeleton.trees_to_skeleton`, as ``torch4dtree sample`` writes it), in the data's units:
``length`` the summed edge lengths; ``height`` the z extent; ``spread`` the largest horizontal (x, y) distance of a
node from the root; ``tips`` the nodes without children; ``branchpoints`` the nodes with two or more children.

**Per plant**: each feature at the normalised ages ``u`` in :data:`AGES` (``u = (t - t_0) / (t_last - t_0)``),
linear between frames: a curve ``(A, F)``. A population is ``(P, A, F)``.

**Two populations** (real ``R``, samples ``S``), per feature and age: the ratio of medians ``median(S) /
median(R)`` (1 when both are 0, ``inf`` when only the real one is) and the two-sample Kolmogorov-Smirnov
statistic. Summaries over ages ``u > 0`` (the first frame is where plants start, not what they become): the worst
ratio ``min(ratio, 1 / ratio)`` and the largest KS. And the 1-nearest-neighbour two-sample accuracy (1-NNA) of the
curves at ages ``u > 0`` as vectors, ``log1p`` of every feature, standardised by the real population's mean and
standard deviation: 0.5 when the populations are indistinguishable, 1 when separable.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..io.dataset import frame_times, read_tree, sequence_folders
from ..io.swc import read_swc_skeleton
from ..trees.skeleton import trees_to_skeleton
from ..trees.structures import Trees, TreeSequence

__all__ = ["AGES", "FEATURES", "compare_populations", "curve_from_frames", "file_features", "files_curve",
           "folder_curve", "ks_statistic",
           "one_nna", "population_curves", "sequence_curve", "skeleton_features", "summary_line", "tree_features"]

FEATURES = ("length", "height", "spread", "tips", "branchpoints")
AGES = (0.0, 0.25, 0.5, 0.75, 1.0)
# a plant observed at one instant has no age span: every age reads its only frame
MIN_SPAN = 1e-12
# added to the standard deviations of 1-NNA's standardisation: a feature constant over the real plants (tips of a
# plant that never branches) then weighs by its raw log difference instead of dividing by zero
STD_FLOOR = 1e-9


def skeleton_features(xyz: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """``(F,)`` features (module doc) of a skeleton graph: ``xyz (n, 3)``, ``parent (n,)`` node indices (``-1``
    at the root; the first such node is the root for ``spread``).

    Example:
        >>> import numpy as np
        >>> skeleton_features(np.array([[0., 0, 0], [0, 0, 2], [1, 0, 3], [-1, 0, 3]]), np.array([-1, 0, 1, 1]))
        array([4.82842712, 3.        , 1.        , 2.        , 1.        ])
    """
    xyz, parent = np.asarray(xyz, dtype=np.float64), np.asarray(parent, dtype=np.int64)
    has = parent >= 0
    length = float(np.linalg.norm(xyz[has] - xyz[parent[has]], axis=1).sum())
    roots = np.flatnonzero(~has)
    root = xyz[roots[0]] if len(roots) else xyz[0]
    children = np.bincount(parent[has], minlength=len(xyz))
    height = float(xyz[:, 2].max() - xyz[:, 2].min())
    spread = float(np.linalg.norm(xyz[:, :2] - root[:2], axis=1).max())
    return np.array([length, height, spread, float((children == 0).sum()), float((children >= 2).sum())])


def tree_features(tree: Trees) -> np.ndarray:
    """``(F,)`` features of one tree, as the skeleton :func:`~torch4dtree.io.swc.write_swc` writes for it.

    Example:
        >>> import torch
        >>> from torch4dtree.trees.structures import Trees
        >>> pts = torch.stack([torch.zeros(5), torch.zeros(5), torch.linspace(0, 4, 5)], -1)[None]
        >>> one = torch.ones(1, dtype=torch.long)
        >>> tree_features(Trees(pts, -one, torch.zeros(1), one, -one))[:2]
        array([4., 4.])
    """
    xyz, parent, _ = trees_to_skeleton(tree)
    return skeleton_features(xyz, parent)


def curve_from_frames(features: np.ndarray, times: Sequence[float]) -> np.ndarray:
    """``(A, F)``: per-frame ``features (n, F)`` at times ``(n,)`` (increasing) read at the normalised
    :data:`AGES`, linear between frames.

    Example:
        >>> curve_from_frames(np.array([[0.0], [4.0]]), [10.0, 20.0])[:, 0]
        array([0., 1., 2., 3., 4.])
    """
    f = np.asarray(features, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    u = (t - t[0]) / max(float(t[-1] - t[0]), MIN_SPAN)
    return np.stack([np.interp(AGES, u, f[:, j]) for j in range(f.shape[1])], 1)


def sequence_curve(sequence: TreeSequence) -> np.ndarray:
    """``(A, F)`` curve of a 4D tree (every frame written as its skeleton)."""
    feats = np.stack([tree_features(sequence.frames[[j]]) for j in range(len(sequence))])
    return curve_from_frames(feats, sequence.times.tolist())


def file_features(path: str | Path) -> np.ndarray | None:
    """``(F,)`` features of one frame file: an SWC frame as its raw skeleton, a ``.mat`` frame as its tree;
    ``None`` for an empty frame."""
    path = Path(path)
    if path.suffix.lower() == ".swc":
        sk = read_swc_skeleton(path)
        return skeleton_features(sk.xyz, sk.parent)
    tree = read_tree(path)
    return None if tree is None else tree_features(tree)


def files_curve(files: Sequence[str | Path], times: Sequence[float]) -> np.ndarray:
    """``(A, F)`` curve of a plant's frame files at their times (increasing; empty frames skipped): the files as
    the yardstick reads them, not the resampled trees.

    Example:
        >>> files_curve([], [])
        Traceback (most recent call last):
        ...
        ValueError: no non-empty frame
    """
    feats, kept = [], []
    for path, t in zip(files, times):
        f = file_features(path)
        if f is not None:
            feats.append(f)
            kept.append(float(t))
    if not feats:
        raise ValueError("no non-empty frame")
    return curve_from_frames(np.stack(feats), kept)


def folder_curve(folder: str | Path) -> np.ndarray:
    """``(A, F)`` curve of a sequence folder: frames and times as :func:`~torch4dtree.io.dataset.frame_times`
    finds them, read by :func:`files_curve`."""
    pairs = frame_times(Path(folder))
    try:
        return files_curve([p for p, _ in pairs], [t for _, t in pairs])
    except ValueError:
        raise ValueError(f"{folder}: no non-empty frame") from None


def population_curves(plants: str | Path | Iterable[TreeSequence]) -> np.ndarray:
    """``(P, A, F)`` curves of a dataset folder (its sequence folders, by name) or of 4D trees.

    Example:
        >>> import torch
        >>> from torch4dtree.trees.structures import Trees, TreeSequence
        >>> pts = torch.stack([torch.zeros(2, 5), torch.zeros(2, 5), torch.linspace(0, 4, 5).expand(2, 5)], -1)
        >>> two = torch.ones(2, dtype=torch.long)
        >>> frames = Trees(pts * torch.tensor([[[1.]], [[2.]]]), -two, torch.zeros(2), two, -two)
        >>> seq = TreeSequence(frames, torch.tensor([0., 1.]))
        >>> population_curves([seq])[0, :, 0]
        array([4., 5., 6., 7., 8.])
    """
    if isinstance(plants, (str, Path)):
        return np.stack([folder_curve(p) for p in sequence_folders(plants)])
    curves = [sequence_curve(s) for s in plants]
    if not curves:
        raise ValueError("no plants")
    return np.stack(curves)


def ks_statistic(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov statistic: the largest gap of the empirical distribution functions.

    Example:
        >>> ks_statistic(np.array([1.0, 2.0]), np.array([3.0, 4.0]))
        1.0
    """
    grid = np.concatenate([a, b])
    fa = np.searchsorted(np.sort(a), grid, side="right") / len(a)
    fb = np.searchsorted(np.sort(b), grid, side="right") / len(b)
    return float(np.abs(fa - fb).max())


def one_nna(samples: np.ndarray, real: np.ndarray) -> float:
    """Leave-one-out accuracy of the 1-nearest-neighbour classifier of ``samples (S, D)`` and ``real (R, D)``
    (Euclidean; ties to the lower index, samples first).

    Example:
        >>> one_nna(np.array([[0.0], [0.1]]), np.array([[5.0], [5.1]]))
        1.0
    """
    z = np.concatenate([samples, real])
    is_real = np.r_[np.zeros(len(samples), bool), np.ones(len(real), bool)]
    d = np.linalg.norm(z[:, None] - z[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float((is_real[d.argmin(1)] == is_real).mean())


def _median_ratio(real: np.ndarray, samples: np.ndarray) -> tuple[float, float, float]:
    mr, ms = float(np.median(real)), float(np.median(samples))
    if mr > 0:
        return mr, ms, ms / mr
    return mr, ms, 1.0 if ms == 0 else math.inf


def compare_populations(real: np.ndarray, samples: np.ndarray) -> dict[str, Any]:
    """Compare curves ``real (R, A, F)`` and ``samples (S, A, F)`` (module doc).

    Returns ``{"real_plants", "samples", "features": {"<feature>@<u>": {"real_median", "sample_median", "ratio",
    "ks"}}, "one_nna", "worst_ratio", "worst", "worst_by_age", "ks_max"}``: ``worst_ratio`` is ``min(ratio, 1 /
    ratio)`` at the worst feature and age ``u > 0`` (named in ``worst``), ``worst_by_age`` the same at each age
    ``u > 0`` (keys ``"<u>"``), ``ks_max`` the largest KS at ``u > 0``.

    Example:
        >>> x = np.arange(24.0).reshape(4, 2, 3)[:, :1].repeat(5, 1)[..., [0, 1, 2, 0, 1]]
        >>> r = compare_populations(x, 2 * x)
        >>> r["features"]["length@1.0"]["ratio"], r["ks_max"] > 0, r["worst_by_age"]["0.5"]
        (2.0, True, 0.5)
    """
    out: dict[str, Any] = {"real_plants": len(real), "samples": len(samples), "features": {}}
    worst, worst_name, ks_max = 1.0, "", 0.0
    by_age = {f"{u}": 1.0 for u in AGES if u > 0}
    for j, f in enumerate(FEATURES):
        for i, u in enumerate(AGES):
            mr, ms, ratio = _median_ratio(real[:, i, j], samples[:, i, j])
            ks = ks_statistic(real[:, i, j], samples[:, i, j])
            out["features"][f"{f}@{u}"] = {"real_median": mr, "sample_median": ms, "ratio": ratio, "ks": ks}
            if u > 0:
                score = min(ratio, 1 / ratio) if ratio > 0 else 0.0
                by_age[f"{u}"] = min(by_age[f"{u}"], score)
                if score < worst:
                    worst, worst_name = score, f"{f}@{u}: {ratio:.2f}"
                ks_max = max(ks_max, ks)

    def vectors(x: np.ndarray) -> np.ndarray:
        return np.log1p(x[:, 1:].reshape(len(x), -1))  # ages u > 0, age-major

    mu, sd = vectors(real).mean(0), vectors(real).std(0) + STD_FLOOR
    out["one_nna"] = one_nna((vectors(samples) - mu) / sd, (vectors(real) - mu) / sd)
    out.update(worst_ratio=worst, worst=worst_name, worst_by_age=by_age, ks_max=ks_max)
    return out


def summary_line(result: dict[str, Any]) -> str:
    """One line: ``'worst median ratio X (feature@u: r); KS max Y; 1-NNA Z'``."""
    return (f"worst median ratio {result['worst_ratio']:.2f} ({result['worst']}); KS max {result['ks_max']:.2f}; "
            f"1-NNA {result['one_nna']:.2f}")
