"""Point and branch correspondences from tree registrations; cycle consistency (SPEC §7, paper Table 2).

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


def map_points(registration: TreeRegistration, branch: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """Map points of the moving tree to the reference through a registration.

    Args:
        registration: result of ``register_trees(moving, reference)``.
        branch: ``(P,)`` long, moving branch of each point (index within the moving tree).
        t: ``(P,)`` parameters in ``[0, 1]`` on those branches.

    Returns:
        ``(branch (P,), t (P,))`` on the reference; branch ``-1`` (and ``t = nan``) where the moving
        branch is matched to null.
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


def _height(tree: Trees) -> float:
    h = float(tree.height()[0])
    if h > 0:
        return h
    span = tree.points.reshape(-1, tree.dim)
    return float((span.amax(0) - span.amin(0)).norm())  # no vertical extent: use the box diagonal


def cycle_consistency(a: Trees, b: Trees, eps: Sequence[float] = DEFAULT_EPS,
                      forward: TreeRegistration | None = None, backward: TreeRegistration | None = None,
                      **kwargs: object) -> CycleConsistency:
    """Cycle consistency of the registrations ``a -> b`` and ``b -> a`` (computed unless given).

    ``kwargs`` go to :func:`register_trees`. See the module docstring for how unmatched points count.
    """
    fwd = forward if forward is not None else register_trees(a, b, **kwargs)  # type: ignore[arg-type]
    bwd = backward if backward is not None else register_trees(b, a, **kwargs)  # type: ignore[arg-type]
    pts = a.points.detach().to("cpu", torch.float64)  # point bookkeeping on the CPU, like map_points
    N, T, _ = pts.shape
    branch = torch.arange(N).repeat_interleave(T)
    t = torch.linspace(0, 1, T, dtype=torch.float64).repeat(N)
    weight = (a.branch_lengths().detach().to("cpu", torch.float64) / T).repeat_interleave(T)
    b1, t1 = map_points(fwd, branch, t)
    mapped = b1 >= 0
    b2 = torch.full_like(branch, -1)
    t2 = torch.full_like(t, float("nan"))
    if bool(mapped.any()):
        b2[mapped], t2[mapped] = map_points(bwd, b1[mapped], t1[mapped])
    back = b2 >= 0
    x = interpolate_curve(pts[branch], t[:, None])[:, 0]
    x2 = interpolate_curve(pts[b2.clamp(min=0)], t2.nan_to_num(0.0)[:, None])[:, 0]
    dist = torch.where(back, (x - x2).norm(dim=-1) / _height(a), torch.full_like(t, float("nan")))
    total = float(weight.sum())
    w_mapped = float(weight[mapped].sum())
    eps_t = torch.tensor(list(eps), dtype=torch.float64)
    fail = (~back[None, :]) | (dist.nan_to_num(np.inf)[None, :] > eps_t[:, None])  # (E, P)
    err_mapped = (fail & mapped[None, :]).to(torch.float64) @ weight / max(w_mapped, 1e-300)
    err_all = fail.to(torch.float64) @ weight / max(total, 1e-300)
    return CycleConsistency(
        tuple(float(e) for e in eps), err_mapped, err_all, 1.0 - w_mapped / max(total, 1e-300),
        float(weight[mapped & ~back].sum()) / max(w_mapped, 1e-300), dist, weight,
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
