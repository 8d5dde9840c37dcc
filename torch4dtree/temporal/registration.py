"""Temporal registration of trajectories in R^k and 4D geodesics (docs/method.md §5).

A 4D tree is ``(alpha(0), q)``: the start point of its trajectory ``alpha (n_t, k)`` and the trajectory's
SRVF ``q (n_t - 1, k)`` (:mod:`.trajectory`). The time warp ``xi`` of the moving trajectory acts on its
SRVF as ``(q o xi) sqrt(xi')`` (computed through the curve, as everywhere in the package), and leaves
the start point alone (``xi(0) = 0``). The distance between two 4D trees is

    d^2(alpha_1, alpha_2) = ||alpha_1(0) - alpha_2(0)||^2 + min_xi ||q_1 - (q_2 o xi) sqrt(xi')||^2,

with ``||q||^2 = sum_i |q_i|^2 / (n_t - 1)`` the L2 norm of the piecewise-constant SRVF on ``[0, 1]``. It is
the Euclidean distance between ``(alpha_1(0), q_1)`` and ``(alpha_2(0), q_2*)``, so the 4D geodesic is
the straight line between them (:func:`geodesic4d`). The second term is the rate-invariant distance of
the paper; the first keeps two trajectories that differ by a translation in shape space apart.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ..curves.refinement import refine_on_finer
from ..curves.register import dp_settings, dp_warp, pick_backend, register_numba
from ..curves.srvf import interpolate_curve, inverse_srvf, srvf, srvf_sq_distance, uniform_grid
from ..settings import TEMPORAL_NEIGHBOURHOOD, TEMPORAL_REFINE

__all__ = ["TemporalRegistration", "geodesic4d", "register_trajectories", "trajectory_distance", "time_warp_trajectory"]

# The DP defaults (settings.TEMPORAL_NEIGHBOURHOOD, TEMPORAL_REFINE), measured with bench/temporal.py (300 smooth random
# trajectories in R^10 at n_t = 32 against copies warped by random_warp, strength 1 / 1.5). The lattice alone is coarse
# at n_t = 32: slopes up to 4 leave a mean absolute warp error of 0.0095 / 0.018 (max 0.056 / 0.11), slopes up to 6
# 0.0064 / 0.0098 at twice the cost. Gauss-Newton refinement off the lattice brings every setting to 0.0005 / 0.0007
# (max 0.0018 / 0.0020 with slopes up to 4; 0.0057 with 3), at least as low a distance as the true warp's on 98.7 % of
# pairs. Stronger warps (strength 2-2.5) still had tails with 8 steps (max 0.03-0.065), none with 16 (max 0.008), which
# cost about the same (the DP dominates).
# A moving trajectory given finer than the n_t grid (trajectory.fine_size): its n_t samples' polyline cuts the corners
# its frames make between grid times, a time-warped copy of it cuts other corners, and no warp of the samples brings
# it back: on the Pheno4D warped copies (.mat, n_t = 32, Table 3 (b)) the best warp of the samples (converged
# L-BFGS) lowers the distance by 90.2 % (tomato) / 93.8 % (maize); the DP + refinement found 88.9 / 93.5 %. Gauss-Newton
# on the fine polyline (refinement.refine_on_finer, this many iterations per level, levels F / 4, F / 2, F) from the
# DP's warp: 99.9 / 100.0 %, the same with 16 iterations, at about half the cost. Between different plants the
# samples' chords sometimes match the reference (whose own samples cut its corners) more closely: the samples'
# reading is kept there (the lower distance wins), so no pair registers worse than on the samples alone.
FINE_REFINE = 8
BAND_NEIGHBOURHOOD = 5  # steps of the banded DPs (only with band=...): dp_warp's default
_UP = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # the kernel's vertical axis (unused without rotation)


class TemporalRegistration(NamedTuple):
    """Result of :func:`register_trajectories` (leading dims ``...``, ``n_t`` times, dimension ``k``).

    * ``warp (..., n_t)``: the time warp ``xi`` of the moving trajectory on ``linspace(0, 1, n_t)``, monotone,
      ``xi(0) = 0``, ``xi(1) = 1``: ``alpha_mov(xi(t))`` is matched to ``alpha_ref(t)``.
    * ``distance (...,)``: ``sqrt(||alpha_ref(0) - alpha_mov(0)||^2 + ||q_ref - q_registered||^2)``
      (module doc); differentiable in both trajectories given the warp.
    * ``distance_before (...,)``: the same with the identity warp.
    * ``registered (..., n_t, k)``: ``alpha_mov(xi(t))``; ``q_registered (..., n_t - 1, k)`` its SRVF.
    """

    warp: Tensor
    distance: Tensor
    distance_before: Tensor
    registered: Tensor
    q_registered: Tensor


def _check_trajectories(a: Tensor, b: Tensor) -> int:
    """Checks a pair of trajectories; returns how many times finer ``b`` is sampled than ``a`` (module doc)."""
    for name, x in (("alpha_ref", a), ("alpha_mov", b)):
        if not isinstance(x, Tensor) or not x.is_floating_point():
            raise TypeError(f"{name} must be a floating point tensor")
        if x.dim() < 2 or x.shape[-2] < 2:
            raise ValueError(f"{name} must be (..., n_t >= 2, k), got {tuple(x.shape)}")
        if not bool(torch.isfinite(x).all()):
            raise ValueError(f"{name} contains NaN or inf")
    n_t, m = a.shape[-2], b.shape[-2]
    if a.shape[:-2] != b.shape[:-2] or a.shape[-1] != b.shape[-1] or (m - 1) % (n_t - 1):
        raise ValueError(f"trajectories must have the same shape, or alpha_mov (m - 1) a multiple of (n_t - 1) "
                         f"samples (resample them on one grid first), got {tuple(a.shape)} and {tuple(b.shape)}")
    if a.device != b.device:
        raise ValueError(f"trajectories are on different devices: {a.device} vs {b.device}")
    return (m - 1) // (n_t - 1)


def _norm(sq: Tensor) -> Tensor:
    """``sqrt`` with a zero gradient at 0 instead of NaN."""
    return torch.where(sq > 0, sq.clamp_min(1e-300).sqrt(), torch.zeros_like(sq))


def _identity_parts(ref: Tensor, mov: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(B, n_t, k)`` pairs: their SRVFs, the squared SRVF distance and the squared start-point distance."""
    q_ref, q_mov = srvf(ref), srvf(mov)
    return q_ref, q_mov, srvf_sq_distance(q_ref, q_mov), (ref[:, 0] - mov[:, 0]).square().sum(-1)


def trajectory_distance(alpha_ref: Tensor, alpha_mov: Tensor) -> Tensor:
    """The 4D distance with the identity time warp, ``(...,)``: ``register_trajectories(...).distance_before``
    without the DP (same inputs, ``alpha_mov`` possibly finer)."""
    factor = _check_trajectories(alpha_ref, alpha_mov)
    lead, (n_t, k) = alpha_ref.shape[:-2], alpha_ref.shape[-2:]
    ref = alpha_ref.reshape(-1, n_t, k)
    mov = alpha_mov.reshape(-1, alpha_mov.shape[-2], k).to(ref.dtype)[:, ::factor]
    _, _, e, start_sq = _identity_parts(ref, mov)
    return _norm(start_sq + e).reshape(lead)


def _with_time(ref: Tensor, fine: Tensor, weight: Tensor) -> tuple[Tensor, Tensor]:
    """``(B, n_t, k)``, ``(B, m, k)`` -> both with a time coordinate ``c linspace(0, 1)`` appended, ``c = weight (B,)``
    x the mean of their polyline lengths (per pair; :data:`~torch4dtree.settings.TIME_WEIGHT`)."""
    def length(x: Tensor) -> Tensor:
        return torch.diff(x, dim=1).norm(dim=-1).sum(1)

    c = weight.to(ref.dtype) * 0.5 * (length(ref) + length(fine))  # (B,)
    out = []
    for x in (ref, fine):
        t = torch.linspace(0.0, 1.0, x.shape[1], dtype=x.dtype, device=x.device)
        out.append(torch.cat([x, (c[:, None] * t)[..., None]], -1))
    return out[0], out[1]


def _search(ref: Tensor, fine: Tensor, factor: int, weight: Tensor | None, neighbourhood: int, refine: int,
            band: int | None, coarse: int | None, backend: str) -> tuple[Tensor, Tensor | None]:
    """The warp ``(B, n_t)`` of ``fine`` (every ``factor``-th sample on the grid) onto ``ref``: the DP on the samples,
    refined on the fine polyline when ``factor > 1``, searched with a time coordinate of ``weight (B,)``
    (:func:`_with_time`) unless ``None``. Also returns, per pair, whether the fine polyline's reading is kept
    (``None``: the samples' everywhere)."""
    n_t = ref.shape[1]
    if weight is not None:
        ref, fine = _with_time(ref, fine, weight)
    q_ref, q_mov = srvf(ref), srvf(fine[:, ::factor])
    be = pick_backend(backend, ref)
    if be == "numba":
        # dp_warp's kernel call without its input checks (done by the caller): for one pair the Python and torch
        # overhead around the DP costs more than the DP
        cfg = dp_settings(neighbourhood, band, coarse, BAND_NEIGHBOURHOOD, 1, 1, 0.0, refine, 1)  # as dp_warp's
        warp = register_numba(q_ref, q_mov, "none", _UP.to(ref.dtype), cfg)[2]
    else:
        warp = dp_warp(q_ref, q_mov, neighbourhood=neighbourhood, band=band, coarse=coarse,
                       band_neighbourhood=BAND_NEIGHBOURHOOD, refine=refine, backend=backend).gamma.to(ref.dtype)
    if factor > 1 and refine > 0 and n_t > 2:
        # the warp found on the samples, refined on the fine polyline; the samples' reading is kept where it is closer
        # (module constants)
        return refine_on_finer(q_ref, fine, warp, min(refine, FINE_REFINE), be)
    return warp, None


def _registered(fine: Tensor, mov: Tensor, warp: Tensor, finer: Tensor | None) -> Tensor:
    """``mov(warp)`` read on the fine polyline where ``finer``, on the samples' elsewhere (``None``: everywhere)."""
    if finer is None or not bool(finer.any()):
        return interpolate_curve(mov, warp)
    if bool(finer.all()):
        return interpolate_curve(fine, warp)
    return torch.where(finer[:, None, None], interpolate_curve(fine, warp), interpolate_curve(mov, warp))


def register_trajectories(alpha_ref: Tensor, alpha_mov: Tensor, neighbourhood: int = TEMPORAL_NEIGHBOURHOOD,
                          refine: int = TEMPORAL_REFINE, band: int | None = None, coarse: int | None = None,
                          backend: str = "auto", time_weight: float = 0.0) -> TemporalRegistration:
    """Optimal time warps of ``alpha_mov`` onto ``alpha_ref``, batched over pairs.

    Args:
        alpha_ref: ``(..., n_t, k)`` reference trajectories on ``linspace(0, 1, n_t)``.
        alpha_mov: ``(..., n_t, k)`` moving trajectories (same shape), or sampled ``F`` times finer, ``(..., F (n_t -
            1) + 1, k)`` (:func:`~torch4dtree.temporal.trajectory.fine_size`; every ``F``-th sample is on the
            ``n_t`` grid). The DP runs on the ``n_t`` grid; the refinement then warps the fine polyline
            (:func:`~torch4dtree.curves.refinement.refine_on_finer`), and ``registered = alpha_mov(xi(t))`` is read
            on it, or on the ``n_t`` samples' polyline where that is closer to the reference. A trajectory through
            frames that fall between grid times has its corners cut by its ``n_t`` samples, differently from a
            time-warped copy of it: no warp of the samples brings the copy back (module constants), a warp of the
            fine polyline nearly does. ``distance_before`` is on the samples.
        neighbourhood, refine, band, coarse, backend: DP settings of :func:`torch4dtree.curves.dp_warp`. The
            defaults (whole lattice, slopes up to 4, 16 refinement steps) were the most accurate per unit
            of time at ``n_t <= 64`` (module constants); the refinement moves the warp off the lattice, so
            it is not limited to the lattice's slopes. For ``n_t`` in the hundreds, a band (e.g. ``band=4,
            coarse=16``) keeps the DP's cost linear.
        time_weight: ``0`` (default): the warp minimises the 4D distance (the rate-invariant distance of docs/method.md
            §5, what the 4D mean and PCA need). ``> 0``: after that search, the warp is searched again on both
            trajectories with a time coordinate ``c t`` appended, ``c = time_weight x rho x`` their mean length, ``rho``
            the share of the distance the first warp left (a penalty on warping for trajectories that are not time warps
            of each other, such as two plants' growth: :data:`~torch4dtree.settings.TIME_WEIGHT`, which
            :func:`~torch4dtree.temporal.register4d` uses). The distances returned are the plain 4D distance at the warp
            returned either way.

    Returns:
        :class:`TemporalRegistration`; ``distance <= distance_before`` always (the identity warp is kept
        when nothing better is found).

    Example:
        >>> t = torch.linspace(0, 1, 16, dtype=torch.float64)[:, None]
        >>> ref = torch.cat([t, torch.sin(3 * t)], 1)
        >>> mov = torch.cat([t ** 2, torch.sin(3 * t ** 2)], 1)  # ref at the warped times t^2
        >>> r = register_trajectories(ref, mov)
        >>> bool(r.distance < 0.1 * r.distance_before)
        True
    """
    factor = _check_trajectories(alpha_ref, alpha_mov)
    if not (isinstance(time_weight, (int, float)) and 0 <= time_weight < float("inf")):
        raise ValueError(f"time_weight must be a finite number >= 0, got {time_weight!r}")
    lead, (n_t, k) = alpha_ref.shape[:-2], alpha_ref.shape[-2:]
    ref = alpha_ref.reshape(-1, n_t, k)
    fine = alpha_mov.reshape(-1, alpha_mov.shape[-2], k).to(ref.dtype)
    mov = fine[:, ::factor]
    q_ref, q_mov, e_before, start_sq = _identity_parts(ref, mov)
    if ref.shape[0] == 0:
        warp, registered = ref.new_zeros(0, n_t), mov
    else:
        def search(weight: Tensor | None) -> tuple[Tensor, Tensor]:
            warp, finer = _search(ref.detach(), fine.detach(), factor, weight, neighbourhood, refine, band, coarse,
                                  backend)
            return warp, _registered(fine, mov, warp, finer)

        warp, registered = search(None)
        if time_weight > 0:
            # the time coordinate's weight scaled by the share of the distance no warp removes (module constants)
            rho = (srvf_sq_distance(q_ref, srvf(registered)) / e_before).clamp(0.0, 1.0).nan_to_num(0.0).sqrt()
            if bool((rho > 0).any()):
                warp, registered = search(time_weight * rho.detach())
    q_reg = srvf(registered)
    e_after = srvf_sq_distance(q_ref, q_reg)
    # the DP never returns worse than the identity; this guards the recomputed (float) energy too
    worse = e_after > e_before
    if bool(worse.any()):
        ident = uniform_grid(n_t, ref).expand_as(warp)
        warp = torch.where(worse[:, None], ident, warp)
        registered = torch.where(worse[:, None, None], mov, registered)
        q_reg = torch.where(worse[:, None, None], q_mov, q_reg)
        e_after = torch.where(worse, e_before, e_after)
    dist, dist_before = _norm(start_sq + torch.stack([e_after, e_before])).unbind(0)
    return TemporalRegistration(
        warp.reshape(*lead, n_t), dist.reshape(lead), dist_before.reshape(lead),
        registered.reshape(*lead, n_t, k), q_reg.reshape(*lead, n_t - 1, k),
    )


def time_warp_trajectory(alpha: Tensor, xi: Tensor) -> Tensor:
    """``alpha(xi(t))``: trajectories ``(..., n_t, k)`` at times ``xi (..., m)`` in ``[0, 1]`` -> ``(..., m, k)``.

    Linear interpolation along the trajectory's grid ``linspace(0, 1, n_t)``; the leading dims broadcast.
    With a warp ``xi`` on the ``m = n_t`` grid this is the time-warp action on trajectories (the action on
    their SRVFs is the SRVF of the result).
    """
    if alpha.dim() < 2 or alpha.shape[-2] < 2:
        raise ValueError(f"alpha must be (..., n_t >= 2, k), got {tuple(alpha.shape)}")
    if xi.dim() < 1 or not xi.is_floating_point():
        raise ValueError(f"xi must be a floating point tensor (..., m), got {xi.dtype} {tuple(xi.shape)}")
    if bool((xi < -1e-9).any()) or bool((xi > 1 + 1e-9).any()):
        raise ValueError("warped times xi must lie in [0, 1]")
    lead = torch.broadcast_shapes(alpha.shape[:-2], xi.shape[:-1])
    a = alpha.expand(*lead, *alpha.shape[-2:])
    x = xi.to(alpha.dtype).expand(*lead, xi.shape[-1])
    return interpolate_curve(a, x)


def geodesic4d(start1: Tensor, q1: Tensor, start2: Tensor, q2: Tensor, steps: int = 10) -> Tensor:
    """Trajectories along the straight line from ``(start1, q1)`` to ``(start2, q2)`` (the 4D geodesic,
    docs/method.md §5).

    Args:
        start1, start2: ``(..., k)`` start points ``alpha(0)``.
        q1, q2: ``(..., n_t - 1, k)`` trajectory SRVFs; ``q2`` should be registered onto ``q1``
            (``trajectory_srvf(register_trajectories(alpha1, alpha2).registered)``) for a geodesic in the
            quotient space.
        steps: points along the geodesic, ``tau = linspace(0, 1, steps)`` (at least 2).

    Returns:
        ``(steps, ..., n_t, k)``: ``inverse_srvf((1 - tau) q1 + tau q2, (1 - tau) start1 + tau start2)``; the
        first is trajectory 1, the last trajectory 2 (as registered).

    Example:
        >>> from torch4dtree.temporal import trajectory_srvf
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> (s1, q1), (s2, q2) = trajectory_srvf(torch.cat([t, t], 1)), trajectory_srvf(torch.cat([t, 2 * t], 1))
        >>> geodesic4d(s1, q1, s2, q2, steps=3).shape
        torch.Size([3, 8, 2])
    """
    if not isinstance(steps, int) or steps < 2:
        raise ValueError(f"steps must be an integer >= 2, got {steps!r}")
    if q1.shape != q2.shape or q1.dim() < 2:
        raise ValueError(f"q1 and q2 must both be (..., n_t - 1, k), got {tuple(q1.shape)} and {tuple(q2.shape)}")
    expected = q1.shape[:-2] + q1.shape[-1:]
    if start1.shape != expected or start2.shape != expected:
        raise ValueError(f"start points must be {tuple(expected)} to match q, got {tuple(start1.shape)} and "
                         f"{tuple(start2.shape)}")
    tau = torch.linspace(0.0, 1.0, steps, dtype=q1.dtype, device=q1.device)
    tq = tau.reshape(steps, *([1] * q1.dim()))
    ts = tau.reshape(steps, *([1] * start1.dim()))
    q = (1 - tq) * q1 + tq * q2
    start = (1 - ts) * start1 + ts * start2
    return inverse_srvf(q, start)
