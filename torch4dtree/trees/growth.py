"""Branch hierarchies that agree over the frames of a growing plant (docs/method.md §2, "a hierarchy chosen jointly with
registration").

A hierarchy rule (:mod:`.skeleton`) decides each frame alone, and near the apex of a young plant it can go either
way: the youngest maize leaf rides up along the stem and leaves the whorl almost straight, so the main branch runs
into the leaf on one day and up the stem the next. Every branch above that point then changes identity between
the two days. Older frames are less ambiguous (the stem has outgrown the leaves around it), so the choice is made
backwards in time: the last frame keeps the rule's hierarchy, and each earlier frame takes, among the rule's main
branch and its **alternatives** (at each of the main branch's topmost branch points, continue into another child
instead), the one that registers best onto its already chosen next frame, if it wins clearly (``margin``). Only
the main branch's continuation at the top is reconsidered: lower down, the stem is the straight, heavy
continuation on every day. The last frame is not compared with the one before it: that would follow a wrong
earlier frame as often as it mends the last one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ..settings import DEFAULT_HIERARCHY, DEFAULT_T
from .registration import effective_lambdas, register_to_reference
from .skeleton import follow_continuations, resolve_branch_points, skeleton_to_trees
from .structures import Trees

__all__ = ["alternative_main_paths", "consistent_frames"]

# how many of the main branch's topmost branch points may continue elsewhere
TOP_BRANCH_POINTS = 3
# points per branch of the candidate trees compared by registration
SCREEN_T = 16
# layers of the candidate trees compared: the main branch and what hangs on it directly decide it
SCREEN_LAYERS = 2
# an alternative main path must register this much closer (as a factor) than the rule's own to replace it
MARGIN = 0.9


def alternative_main_paths(xyz: np.ndarray, parent: np.ndarray, hierarchy: str = DEFAULT_HIERARCHY,
                           window: float | None = None, top: int = TOP_BRANCH_POINTS,
                           where: str = "skeleton", ids: np.ndarray | None = None) -> list[list[int]]:
    """The rule's main path (first) and its alternatives, as node indices from the root.

    An alternative leaves the rule's main path at one of its ``top`` topmost branch points into another child, and
    goes on from there by the rule. Short children count too: the stem's tip above a young apex leaf is often
    shorter than the rule's spur length (a spur never wins the comparison of :func:`consistent_frames`).

    Args:
        xyz: ``(n, d)`` node coordinates. parent: ``(n,)`` parent indices, ``-1`` at the root.
        hierarchy, window: the rule and its direction window (:func:`~.skeleton.continuation_children`).
        top: how many branch points, counted down from the top of the main path, may branch off.
        where, ids: a name and the node ids for error messages.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    order, children, _, best = resolve_branch_points(xyz, parent, hierarchy, where, ids, window)

    def follow(start: int) -> list[int]:
        return follow_continuations(best, start)

    main = follow(int(order[0]))
    forks = [i for i, v in enumerate(main[:-1]) if len(children[v]) > 1][-top:] if top > 0 else []
    paths = [main]
    for i in reversed(forks):  # the topmost fork first
        v = main[i]
        for c in children[v]:
            if c != main[i + 1]:
                paths.append(main[: i + 1] + follow(c))
    return paths


def consistent_frames(skeletons: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray | None]], T: int = DEFAULT_T,
                      hierarchy: str = DEFAULT_HIERARCHY, window: float | None = None,
                      lambdas: Sequence[float] = (1.0, 1.0, 9.0), rotation: str = "none",
                      top: int = TOP_BRANCH_POINTS, screen_T: int = SCREEN_T, margin: float = MARGIN,
                      names: Sequence[str] | None = None, ids: Sequence[np.ndarray] | None = None,
                      dtype: torch.dtype = torch.float32, **tree_kwargs: object) -> list[Trees]:
    """The frames of a 4D tree as single trees whose main branches agree over time (module doc).

    Args:
        skeletons: per frame, in time order, ``(xyz (n, d), parent (n,), node_labels (n,) or None)``.
        T, hierarchy, window, dtype, tree_kwargs: as :func:`~.skeleton.skeleton_to_trees`
            (``max_layers``, ``min_branch_length``).
        lambdas, rotation: the registration that compares a frame's candidates with its next frame
            (:func:`~.registration.register_to_reference`, position weight relative to the plant's size): the
            within-sequence registration's defaults.
        screen_T: points per branch of the candidates compared (a coarser sampling than ``T`` is enough to tell
            a stem from a leaf and much cheaper to register).
        margin: an alternative replaces the rule's main path only if it registers closer than ``margin`` times the
            rule's distance: where a young organ at the apex looks like the stem's continuation the two
            registrations differ by a few percent either way, while a frame that chose the wrong continuation
            registers much closer with the right one.
        top: branch points at the top of the main branch that may continue elsewhere (0: the rule alone).
        names, ids: per frame, a name and the node ids for error messages.

    Returns:
        one single-tree :class:`Trees` per frame.
    """
    n = len(skeletons)
    names = list(names) if names is not None else [f"frame {j}" for j in range(n)]

    def build(j: int, path: list[int], points: int, **kwargs: object) -> Trees:
        xyz, par, lab = skeletons[j]
        return skeleton_to_trees(xyz, par, T=points, main_path=path, node_labels=lab, where=names[j],
                                 ids=None if ids is None else ids[j], dtype=dtype, hierarchy=hierarchy, window=window,
                                 **kwargs)  # type: ignore[arg-type]

    chosen: list[list[int]] = [[] for _ in range(n)]
    coarse: Trees | None = None  # the chosen next frame at the screening resolution
    for j in range(n - 1, -1, -1):
        paths = alternative_main_paths(skeletons[j][0], skeletons[j][1], hierarchy, window,
                                       top=top if j < n - 1 else 0, where=names[j], ids=None if ids is None else ids[j])
        # compared with SCREEN_LAYERS layers whatever max_layers keeps: the main branch must not depend on it
        candidates = [build(j, p, screen_T, max_layers=SCREEN_LAYERS) for p in paths]
        pick = 0
        if len(candidates) > 1:
            # one metric for all candidates (lp relative to the reference alone): their main branches differ in length;
            # all solved one way (a symmetric solve would invert some of them: distances not comparable)
            regs = register_to_reference(Trees.cat(candidates), coarse, effective_lambdas(lambdas, coarse), rotation,
                                         lp_relative=False, symmetric=False, positions="warped")
            d = np.array([float(r.distance) for r in regs])
            best = int(np.argmin(d[1:])) + 1
            pick = best if d[best] < margin * d[0] else 0  # the rule's own path (first) unless clearly worse
        chosen[j], coarse = paths[pick], candidates[pick]
    return [build(j, chosen[j], T, **tree_kwargs) for j in range(n)]
