"""Point and branch correspondences from tree registrations; cycle consistency (docs/method.md §7, paper Table 2).

A registration of ``A`` (moving) onto ``B`` maps the point at parameter ``t`` of branch ``a`` to the
point at ``gamma_a^{-1}(t)`` of its matched branch ``b``: the registered branch is
``beta_a(gamma_a(u))``, aligned with ``beta_b(u)``. Branches matched to a null branch have no image.

**Cycle consistency**: points of ``A`` go to ``B`` through ``A -> B`` and back through ``B -> A``;
we report the share of points that land farther than ``eps * height(A)`` from where they started.
Points are sampled uniformly in arc length over the whole tree (every grid point of every branch,
weighted by its branch's length / T), so a share is a share of the tree's length.
How points without a full cycle count:

* points on branches of ``A`` matched to null by ``A -> B`` have no image at all: they are left out of
  ``error`` and reported as ``unmatched`` (``error_all`` counts them as failures instead);
* points whose image lies on a branch of ``B`` matched to null by ``B -> A`` started a cycle that
  did not return: they count as failures in ``error`` and are also reported as ``lost``.

``error_null_at_base`` follows the paper's model of a null branch instead (docs/method.md §3: a branch matched to
null is matched to a zero-length branch at its bifurcation point on the other tree): a point on a branch without an
image goes where its branch's null partner sits, the image of the point where the branch leaves its parent (up the
ancestors until one has an image), on either leg of the cycle, and its cycle error is its distance from where it
comes back. Points near the base of a null-matched branch then return within ``eps`` and points far out on it do not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..curves.srvf import interpolate_curve
from .registration import TreeRegistration, register_trees
from .structures import Trees

__all__ = ["CycleConsistency", "PAPER_CYCLE_ERRORS", "branch_accuracy", "cycle_consistency", "map_points"]

# the paper's Table 2 (mean share of points, ours): eps = 0.1, 0.05, 0.02, 0.01
PAPER_CYCLE_ERRORS = {0.1: 0.0094, 0.05: 0.0200, 0.02: 0.0287, 0.01: 0.0545}
DEFAULT_EPS = (0.1, 0.05, 0.02, 0.01)
# divisor floor of a total weight: a tree without (mapped) points gives shares of 0 instead of nan
MIN_WEIGHT = 1e-300


def map_points(registration: TreeRegistration, branch: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """Map points of the moving tree to the reference through a registration.

    Args:
        registration: result of ``register_trees(moving, reference)``.
        branch: ``(P,)`` long, moving branch of each point (index within the moving tree).
        t: ``(P,)`` parameters in ``[0, 1]`` on those branches.

    Returns:
        ``(branch (P,), t (P,))`` on the reference; branch ``-1`` (and ``t = nan``) where the moving
        branch is matched to null.

    Example:
        >>> import torch
        >>> from torch4dtree.data.examples import leaf_pair
        >>> tree, other = leaf_pair(T=8)  # a stem with a straight leaf, and with a bent one
        >>> branch, t_image = map_points(register_trees(other, tree), torch.tensor([1]), torch.tensor([0.5]).double())
        >>> branch.tolist(), t_image.tolist()
        ([1], [0.5])
    """
    match = dict(registration.matches)
    gamma = registration.gamma.detach().to("cpu", torch.float64).numpy()
    grid = np.linspace(0.0, 1.0, gamma.shape[1])
    b_out = torch.full_like(branch, -1)
    t_out = torch.full(t.shape, float("nan"), dtype=torch.float64)
    tt = t.detach().to("cpu", torch.float64).numpy()
    for a in torch.unique(branch).tolist():
        if a not in match:
            continue
        sel = (branch == a).nonzero()[:, 0]
        b_out[sel] = match[a]
        t_out[sel] = torch.from_numpy(np.interp(tt[sel.numpy()], gamma[a], grid))  # gamma_a^{-1}(t)
    return b_out, t_out


class CycleConsistency(NamedTuple):
    """Cycle-consistency of ``A -> B -> A`` (shares are fractions in [0, 1] of the tree's length).

    * ``eps``: thresholds, as fractions of ``height(A)``.
    * ``error``: ``(len(eps),)`` share of mapped points whose cycle error exceeds ``eps * height``
      (points lost on the way back count as errors).
    * ``error_all``: the same over all points, unmatched ones counted as errors.
    * ``unmatched``: share of points on branches of ``A`` matched to null (no image in ``B``).
    * ``lost``: share of mapped points whose image is matched to null in ``B -> A``.
    * ``error_null_at_base``: ``(len(eps),)`` the share of all points failing when a point on a null-matched
      branch maps to its null partner, at the image of its branch's base (module doc).
    * ``distance``: ``(P,)`` cycle distance of every sample point / height (``nan`` if no full cycle).
    * ``weight``: ``(P,)`` arc-length weight of every sample point.
    """

    eps: tuple[float, ...]
    error: Tensor
    error_all: Tensor
    unmatched: float
    lost: float
    distance: Tensor
    weight: Tensor
    error_null_at_base: Tensor


def _height(tree: Trees) -> float:
    h = float(tree.height()[0])
    if h > 0:
        return h
    span = tree.points.reshape(-1, tree.dim)
    return float((span.amax(0) - span.amin(0)).norm())  # no vertical extent: use the box diagonal


def _to_base_of_unmatched(tree: Trees, matched: set[int], branch: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """Points on branches outside ``matched`` moved to where their branch leaves its parent, up the ancestors until
    a matched branch (branch ``-1`` if even the main branch is unmatched); others unchanged."""
    parent, s = tree.parent.tolist(), tree.s.detach().to("cpu", torch.float64).tolist()
    base: dict[int, tuple[int, float | None]] = {}
    for k in range(len(parent)):  # parents come first: each branch's nearest matched ancestor from its parent's
        if k in matched:
            base[k] = (k, None)
        elif parent[k] < 0:
            base[k] = (-1, None)
        else:
            up, at = base[parent[k]]
            base[k] = (up, s[k] if at is None else at)
    b_out, t_out = branch.clone(), t.clone()
    for k in torch.unique(branch[branch >= 0]).tolist():
        up, at = base[k]
        if at is None and up == k:
            continue
        sel = branch == k
        b_out[sel] = up
        t_out[sel] = float("nan") if up < 0 else at
    return b_out, t_out


def _cycle(fwd: TreeRegistration, bwd: TreeRegistration, branch: Tensor, t: Tensor,
           collapse: tuple[Trees, Trees] | None) -> tuple[Tensor, Tensor, Tensor]:
    """``(b1, b2, t2)``: the points' image branch in B (``-1``: none) and where they come back in A; with ``collapse``
    (A, B) points without an image on a leg go to their branch's base first (:func:`_to_base_of_unmatched`)."""
    if collapse is not None:
        branch, t = _to_base_of_unmatched(collapse[0], {i for i, _ in fwd.matches}, branch, t)
    b1, t1 = map_points(fwd, branch.clamp(min=0), t.nan_to_num(0.0))
    b1 = torch.where(branch >= 0, b1, torch.full_like(b1, -1))
    if collapse is not None:
        b1, t1 = _to_base_of_unmatched(collapse[1], {i for i, _ in bwd.matches}, b1, t1)
    mapped = b1 >= 0
    b2 = torch.full_like(branch, -1)
    t2 = torch.full_like(t, float("nan"))
    if bool(mapped.any()):
        b2[mapped], t2[mapped] = map_points(bwd, b1[mapped], t1[mapped])
    return b1, b2, t2


def cycle_consistency(a: Trees, b: Trees, eps: Sequence[float] = DEFAULT_EPS,
                      forward: TreeRegistration | None = None, backward: TreeRegistration | None = None,
                      **kwargs: object) -> CycleConsistency:
    """Cycle consistency of the registrations ``a -> b`` and ``b -> a`` (computed unless given).

    ``kwargs`` go to :func:`register_trees`. See the module docstring for how unmatched points count.

    Example:
        >>> import torch
        >>> from torch4dtree.data.examples import leaf_pair
        >>> tree, other = leaf_pair(T=8)  # a stem with a straight leaf, and with a bent one
        >>> cc = cycle_consistency(other, tree)
        >>> cc.eps, cc.error.tolist(), cc.unmatched
        ((0.1, 0.05, 0.02, 0.01), [0.0, 0.0, 0.0, 0.0], 0.0)
    """
    fwd = forward if forward is not None else register_trees(a, b, **kwargs)  # type: ignore[arg-type]
    bwd = backward if backward is not None else register_trees(b, a, **kwargs)  # type: ignore[arg-type]
    pts = a.points.detach().to("cpu", torch.float64)  # point bookkeeping on the CPU, like map_points
    N, T, _ = pts.shape
    branch = torch.arange(N).repeat_interleave(T)
    t = torch.linspace(0, 1, T, dtype=torch.float64).repeat(N)
    weight = (a.branch_lengths().detach().to("cpu", torch.float64) / T).repeat_interleave(T)
    x = interpolate_curve(pts[branch], t[:, None])[:, 0]
    height = _height(a)

    def distances(b2: Tensor, t2: Tensor) -> Tensor:
        x2 = interpolate_curve(pts[b2.clamp(min=0)], t2.nan_to_num(0.0)[:, None])[:, 0]
        return torch.where(b2 >= 0, (x - x2).norm(dim=-1) / height, torch.full_like(t, float("nan")))

    b1, b2, t2 = _cycle(fwd, bwd, branch, t, None)
    mapped, back = b1 >= 0, b2 >= 0
    dist = distances(b2, t2)
    total = float(weight.sum())
    w_mapped = float(weight[mapped].sum())
    eps_t = torch.tensor(list(eps), dtype=torch.float64)

    def failing(d: Tensor) -> Tensor:  # (E, P): no way back, or back too far
        return d.nan_to_num(np.inf)[None, :] > eps_t[:, None]

    fail = failing(dist)
    err_mapped = (fail & mapped[None, :]).to(torch.float64) @ weight / max(w_mapped, MIN_WEIGHT)
    err_all = fail.to(torch.float64) @ weight / max(total, MIN_WEIGHT)
    _, b2n, t2n = _cycle(fwd, bwd, branch, t, (a, b))
    err_base = failing(distances(b2n, t2n)).to(torch.float64) @ weight / max(total, MIN_WEIGHT)
    return CycleConsistency(
        tuple(float(e) for e in eps), err_mapped, err_all, 1.0 - w_mapped / max(total, MIN_WEIGHT),
        float(weight[mapped & ~back].sum()) / max(w_mapped, MIN_WEIGHT), dist, weight, err_base,
    )


def branch_accuracy(registration: TreeRegistration, moving: Trees, reference: Trees) -> float:
    """Share of ground-truth branch identities the registration gets right.

    Over the union of labels (``>= 0``) of both trees: a label present in both is right when its two
    branches are matched to each other; a label present in one tree only is right when its branch is
    matched to null. Branches with label ``-1`` are ignored. ``nan`` if no branch is labelled.
    """
    lm, lr = moving.label.tolist(), reference.label.tolist()
    match = dict(registration.matches)
    by_label_m = {lab: i for i, lab in enumerate(lm) if lab >= 0}
    by_label_r = {lab: j for j, lab in enumerate(lr) if lab >= 0}
    matched_r = set(match.values())
    labels = set(by_label_m) | set(by_label_r)
    if not labels:
        return float("nan")
    good = 0
    for lab in labels:
        i, j = by_label_m.get(lab), by_label_r.get(lab)
        if i is not None and j is not None:
            good += match.get(i) == j
        elif i is not None:
            good += i not in match
        else:
            good += j not in matched_r
    return good / len(labels)
