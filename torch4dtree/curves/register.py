"""Elastic registration of curves: batched dynamic-programming warps and rotations.

All discrete choices minimise exactly the discrete energy of ``curves.py``::

    E(gamma, O) = || q1 - O warp_srvf(q2, gamma) ||^2

(``q1`` the reference SRVF, ``q2`` the moving one, both ``(B, M, d)`` piecewise constant on the
``T = M + 1`` grid points). The DP lattice has nodes ``(i, j)`` meaning ``gamma(s_i) = s_j``;
an edge ``(i - a, j - b) -> (i, j)`` uses a coprime step ``(a, b)`` and makes ``gamma`` linear
between its ends, so the warped curve's nodes inside the edge are ``beta2`` at the fractional
grid positions ``j - b + r b / a``. The identity warp is a lattice path (steps ``(1, 1)``), so a
full DP never does worse than the identity; banded / coarse-to-fine searches keep the best of
their result and the warp they started from, so they never do worse either.

Two interchangeable backends compute the same DP: a numba kernel (CPU default, parallel over
pairs) and a vectorised torch one (row by row over the lattice; any device).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .dp_numba import HAVE_NUMBA, banded_dp_numba, run_pairs, warp_energies_numba
from .dp_torch import banded_dp_torch
from .refinement import gauss_newton_torch
from .rotation import axis_rotation, check_rotation_mode, optimal_rotation
from .srvf import interpolate_curve, inverse_srvf, srvf, srvf_sq_distance, uniform_grid, warp_curve, warp_srvf
from .warps import band_around, identity_warp, reachable_band, step_arrays, warp_energy

__all__ = ["CurveRegistration", "DPSettings", "DPWarp", "dp_settings", "dp_warp", "elastic_distance", "pick_backend",
           "register_curves", "register_numba", "warp_energies"]

# floor under an energy before its square root: the gradient stays finite where the energy is 0 (0 is returned)
MIN_ENERGY = 1e-300


# ----------------------------------------------------------------------------- DP driver


class DPWarp(NamedTuple):
    """Result of :func:`dp_warp`: ``gamma (B, M+1)`` and ``energy (B,) = ||q1 - warp_srvf(q2, gamma)||^2``."""

    gamma: Tensor
    energy: Tensor


class CurveRegistration(NamedTuple):
    """Result of :func:`register_curves` (``B`` pairs, ``T`` points, dimension ``d``).

    * ``gamma (B, T)``: warp of the moving curve, ``registered = O moving(gamma(s))``.
    * ``rotation (B, d, d)``: ``O``, acting on row vectors as ``x @ O.T``.
    * ``distance (B,)``: ``sqrt(energy)``, differentiable in the inputs given ``gamma`` and ``O``.
    * ``energy (B,)``: ``||q_ref - O warp_srvf(q_mov, gamma)||^2`` (no scale normalisation).
    * ``energy_before (B,)``: the same with the identity warp and rotation.
    * ``registered (B, T, d)``: the moving curve rotated, reparameterised and translated to start at
      the reference's first point; ``q_registered (B, T-1, d)`` its SRVF.
    """

    gamma: Tensor
    rotation: Tensor
    distance: Tensor
    energy: Tensor
    energy_before: Tensor
    registered: Tensor
    q_registered: Tensor


def warp_energies(q1: Tensor, q2: Tensor, gammas: np.ndarray) -> np.ndarray:
    """:func:`~torch4dtree.curves.warps.warp_energy` of one pair ``q1, q2 (M, d)`` under every warp ``g`` of
    ``gammas (n, M+1)``, without gradients: ``(n,)``. The numba kernel on CPU float64 (small torch ops cost ~0.1 ms
    each, and the tree registration asks this of every parent pair several times); ``warp_energy`` otherwise."""
    if HAVE_NUMBA and q1.device.type == "cpu" and q1.dtype == torch.float64 and q2.dtype == torch.float64:
        return warp_energies_numba(q1.detach().numpy(), q2.detach().numpy(), gammas)
    g = torch.as_tensor(gammas, dtype=q2.dtype, device=q2.device)
    n = len(g)
    return warp_energy(q1.detach().expand(n, -1, -1), q2.detach().expand(n, -1, -1), g).cpu().numpy()


def _resample_srvf(q: Tensor, M: int) -> Tensor:
    """SRVF of the curve of ``q`` resampled (linearly in the parameter) to ``M`` segments."""
    if q.shape[-2] == M:
        return q
    return srvf(_resample_curve(inverse_srvf(q), M + 1))


def _resample_curve(beta: Tensor, T: int) -> Tensor:
    if beta.shape[-2] == T:
        return beta
    return interpolate_curve(beta, uniform_grid(T, beta).expand(*beta.shape[:-2], T))


def pick_backend(backend: str, x: Tensor) -> str:
    """``"numba"`` or ``"torch"`` for ``backend`` in ``("auto", "numba", "torch")``: ``"auto"`` takes numba for CPU
    tensors ``x`` when it is installed (the faster kernel), torch otherwise (any device)."""
    if backend not in ("auto", "numba", "torch"):
        raise ValueError(f"unknown backend {backend!r}; expected 'auto', 'numba' or 'torch'")
    if backend == "auto":
        return "numba" if HAVE_NUMBA and x.device.type == "cpu" else "torch"
    if backend == "numba" and not HAVE_NUMBA:
        raise ValueError("backend='numba' needs the numba package")
    return backend


def _run_dp(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray,
            backend: str) -> tuple[Tensor, Tensor]:
    """One DP over the lattice restricted to columns ``[lo, hi] (B, M+1)`` per row. ``-> energy, gamma``."""
    if backend == "numba":
        energy, gamma = banded_dp_numba(q1, q2, n, lo, hi)
        return energy.to(q1.device, q1.dtype), gamma.to(q1.device, q1.dtype)
    return banded_dp_torch(q1, q2, n, lo, hi)


def _dp_search(q1: Tensor, q2: Tensor, n: int, band: int | None, init: Tensor | None,
               backend: str) -> tuple[Tensor, Tensor]:
    """Full DP (``band=None`` or no ``init``) or DP in a band around ``init (B, M+1)``. ``-> gamma, E``."""
    B, M, _ = q1.shape
    if band is None or init is None:
        lo, hi = reachable_band(M, n)
        lo, hi = np.tile(lo, (B, 1)), np.tile(hi, (B, 1))
    else:
        lo, hi = band_around(init, M, n, band)
    energy, gamma = _run_dp(q1, q2, n, lo, hi, backend)
    return gamma, energy


def _grid_sizes(M: int, band: int | None, coarse: int | None) -> list[int]:
    """Grids of the coarse-to-fine search, finest first (as in ``_nb_register_one``)."""
    sizes = [M]
    if band is not None and coarse is not None:
        while sizes[-1] > coarse and len(sizes) < 64:
            cur = sizes[-1]
            sizes.append(min(max(coarse // 2, -(-cur // 3)), cur - 1))
    return sizes


class DPSettings(NamedTuple):
    """Search settings shared by both backends (see :func:`register_curves`)."""

    neighbourhood: int
    band: int | None
    coarse: int | None
    band_neighbourhood: int
    max_iters: int
    fine_iters: int
    tol: float
    refine: int
    starts: int


_MODES = {"none": 0, "vertical": 1, "so3": 2}


def _start_rotation(O: Tensor, rotation: str, up: Tensor, k: int, starts: int) -> Tensor:
    """Torch twin of ``_nb_start_rotation``."""
    d = O.shape[-1]
    if k == 0:
        return O.clone()
    if k == 1:
        return torch.eye(d, dtype=O.dtype, device=O.device).expand_as(O).clone()
    k, starts = k - 1, starts - 1
    if rotation == "vertical":
        th = torch.full(O.shape[:1], 2.0 * math.pi * k / starts, dtype=O.dtype, device=O.device)
        return O @ axis_rotation(up.to(O.dtype), th)
    F = torch.eye(d, dtype=O.dtype, device=O.device)
    i = (k - 1) % d
    F[i, i] = -1.0
    F[(i + 1) % d, (i + 1) % d] = -1.0
    return O @ F


def _alternate_torch(q1: Tensor, q2: Tensor, n: int, band: int | None, rotation: str, up: Tensor,
                     max_iters: int, tol: float, refine: int, O0: Tensor,
                     init: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
    """Batched torch twin of ``_nb_alternate``. ``-> energy (B,), gamma (B, M+1), O (B, d, d)``."""
    B, M, d = q1.shape
    beta2 = inverse_srvf(q2)
    best = torch.full((B,), float("inf"), dtype=q1.dtype, device=q1.device)
    gamma = identity_warp(B, M + 1, q1)
    O = O0.clone()
    Ocur, prev = O0, init
    last = torch.full_like(best, float("inf"))
    active = torch.ones(B, dtype=torch.bool, device=q1.device)

    def keep(e: Tensor, g: Tensor, R: Tensor) -> None:
        nonlocal best, gamma, O
        better = active & (e < best)
        best = torch.where(better, e, best)
        gamma = torch.where(better[:, None], g, gamma)
        O = torch.where(better[:, None, None], R, O)

    for _ in range(max(max_iters, 1)):
        q1r = q1 @ Ocur
        g, e = _dp_search(q1r, q2, n, band, prev, "torch")
        if refine > 0:
            if prev is not None:
                g = torch.where((warp_energy(q1r, q2, prev) < e)[:, None], prev, g)
            g = gauss_newton_torch(q1r, beta2, g, refine)
            e = warp_energy(q1r, q2, g)
        keep(e, g, Ocur)
        if rotation == "none":
            break
        Onew = optimal_rotation(q1, warp_srvf(q2, g), rotation, up)
        e2 = warp_energy(q1, q2, g, Onew)
        keep(e2, g, Onew)
        active = active & (last - e2 > tol * e2)
        if not bool(active.any()):
            break
        last = torch.where(active, e2, last)
        Ocur = torch.where(active[:, None, None], Onew, Ocur)
        prev = g if prev is None else torch.where(active[:, None], g, prev)
    return best, gamma, O


def _register_torch(q1: Tensor, q2: Tensor, rotation: str, up: Tensor,
                   cfg: DPSettings) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The numba registration of pairs ``q1, q2 (B, M, d)`` (reference, moving SRVFs) with settings ``cfg``
    (:func:`dp_settings`) and ``rotation`` about ``up (3,)``: ``(energy (B,), energy_before (B,), gamma (B, M+1),
    O (B, d, d))`` (see :func:`register_curves`)."""
    """Batched torch twin of ``_nb_register_one``. ``-> energy, energy_before, gamma, O``."""
    B, M, d = q1.shape
    ident = identity_warp(B, M + 1, q1)
    eye = torch.eye(d, dtype=q1.dtype, device=q1.device).expand(B, d, d).clone()
    before = warp_energy(q1, q2, ident)
    beta1, beta2 = inverse_srvf(q1), inverse_srvf(q2)
    Ocur = eye if rotation == "none" else optimal_rotation(q1, q2, rotation, up)
    gcur: Tensor | None = None
    sizes = _grid_sizes(M, cfg.band, cfg.coarse)
    eL = before
    for lev in range(len(sizes) - 1, -1, -1):
        ML = sizes[lev]
        q1L = q1 if ML == M else srvf(_resample_curve(beta1, ML + 1))
        q2L = q2 if ML == M else srvf(_resample_curve(beta2, ML + 1))
        init = None if gcur is None else _resample_curve(gcur.unsqueeze(-1), ML + 1)[..., 0]
        top = lev == len(sizes) - 1
        nst = cfg.starts if (top and rotation != "none") else 1
        eL = torch.full((B,), float("inf"), dtype=q1.dtype, device=q1.device)
        gL, OL = identity_warp(B, ML + 1, q1), eye.clone()
        for k in range(max(nst, 1)):
            O0 = _start_rotation(Ocur, rotation, up, k, nst)
            ek, gk, Ok = _alternate_torch(q1L, q2L, cfg.neighbourhood if top else cfg.band_neighbourhood,
                                          cfg.band, rotation, up, cfg.max_iters if top else cfg.fine_iters,
                                          cfg.tol, cfg.refine if lev == 0 else 0, O0, init)
            better = ek < eL
            eL = torch.where(better, ek, eL)
            gL = torch.where(better[:, None], gk, gL)
            OL = torch.where(better[:, None, None], Ok, OL)
        gcur, Ocur = gL, OL
    better = eL < before
    energy = torch.where(better, eL, before)
    gamma = torch.where(better[:, None], gcur, ident)
    O = torch.where(better[:, None, None], Ocur, eye)
    return energy, before, gamma, O


def _kernel_settings(cfg: DPSettings, rotation: str) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """The numba entry kernel's lattice steps ``(A, Bs, Af, Bf)`` and integer settings for ``cfg``."""
    A, Bs = step_arrays(cfg.neighbourhood)
    Af, Bf = step_arrays(cfg.band_neighbourhood)
    ints = np.array([cfg.neighbourhood, -1 if cfg.band is None else cfg.band,
                     1 << 30 if cfg.coarse is None else cfg.coarse, _MODES[rotation], cfg.max_iters,
                     cfg.refine, cfg.starts, cfg.band_neighbourhood, cfg.fine_iters], np.int64)
    return (A, Bs, Af, Bf), ints


def register_numba(q1: Tensor, q2: Tensor, rotation: str, up: Tensor,
                   cfg: DPSettings) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The numba registration of pairs ``q1, q2 (B, M, d)`` (reference, moving SRVFs) with settings ``cfg``
    (:func:`dp_settings`) and ``rotation`` about ``up (3,)``: ``(energy (B,), energy_before (B,), gamma (B, M+1),
    O (B, d, d))`` (see :func:`register_curves`)."""
    steps, ints = _kernel_settings(cfg, rotation)
    q1n = q1.detach().to("cpu", torch.float64).contiguous().numpy()
    q2n = q2.detach().to("cpu", torch.float64).contiguous().numpy()
    upn = up.detach().to("cpu", torch.float64).contiguous().numpy()
    out = run_pairs(False, q2n, q1n, False, steps, ints, upn, cfg.tol)[:4]
    return tuple(torch.from_numpy(x).to(q1.device, q1.dtype) for x in out)  # type: ignore[return-value]


def _register_curves_numba(moving: Tensor, reference: Tensor, srvf_input: bool, rotation: str, up: Tensor,
                           cfg: DPSettings) -> CurveRegistration:
    """``register_curves`` without gradients in one numba call (input prep and outputs included)."""
    steps, ints = _kernel_settings(cfg, rotation)
    mov = moving.detach().to("cpu", torch.float64).contiguous().numpy()
    ref = reference.detach().to("cpu", torch.float64).contiguous().numpy()
    upn = up.detach().to("cpu", torch.float64).contiguous().numpy()
    energy, before, gamma, O, reg, q_reg = run_pairs(True, mov, ref, srvf_input, steps, ints, upn, cfg.tol)
    distance = np.sqrt(np.maximum(energy, 0.0))
    dt, dev = reference.dtype, reference.device
    return CurveRegistration(*(torch.from_numpy(x).to(dev, dt)
                               for x in (gamma, O, distance, energy, before, reg, q_reg)))


def all_finite(x: Tensor) -> bool:
    """Whether ``x`` holds no NaN or inf. CPU float32 / float64 tensors are checked by numpy on the calling thread:
    torch splits a check of more than 32,768 values between its threads, which on a busy machine wait for cores and
    made a batch of over 110 pairs (T = 100, d = 3) slower per pair than single calls (benchmarks/bench_batch.py)."""
    if x.device.type == "cpu" and x.dtype in (torch.float32, torch.float64):
        return bool(np.isfinite(x.detach().numpy()).all())
    return bool(torch.isfinite(x).all())


def _check_inputs(moving: Tensor, reference: Tensor, min_points: int,
                  what: str) -> tuple[Tensor, Tensor, bool]:
    """Validate a pair of batched (or single) inputs; returns them batched and whether they were single."""
    if not isinstance(moving, Tensor) or not isinstance(reference, Tensor):
        raise TypeError("moving and reference must be torch tensors")
    if moving.dim() != reference.dim() or moving.dim() not in (2, 3):
        raise ValueError(f"expected {what} of shape (B, T, d) or (T, d), got {tuple(moving.shape)} "
                         f"and {tuple(reference.shape)}")
    single = moving.dim() == 2
    if single:
        moving, reference = moving.unsqueeze(0), reference.unsqueeze(0)
    if moving.shape[0] != reference.shape[0]:
        raise ValueError(f"batch sizes differ: {moving.shape[0]} vs {reference.shape[0]}")
    if moving.shape[2] != reference.shape[2]:
        raise ValueError(f"dimensions differ: d={moving.shape[2]} vs d={reference.shape[2]}")
    if min(moving.shape[1], reference.shape[1]) < min_points:
        raise ValueError(f"{what} need at least {min_points} sample(s) along the curve, got "
                         f"{moving.shape[1]} and {reference.shape[1]}")
    if not moving.is_floating_point() or not reference.is_floating_point():
        raise ValueError("inputs must be floating point tensors")
    if not (all_finite(moving) and all_finite(reference)):
        raise ValueError(f"{what} contain NaN or inf")
    if moving.device != reference.device:
        raise ValueError(f"inputs are on different devices: {moving.device} vs {reference.device}")
    return moving, reference.to(moving.dtype), single


def dp_settings(neighbourhood: int, band: int | None, coarse: int | None, band_neighbourhood: int | None,
              max_iters: int, fine_iters: int, tol: float, refine: int, starts: int) -> DPSettings:
    """Checked :class:`DPSettings` (``ValueError`` on a bad value); ``band_neighbourhood=None`` takes
    ``neighbourhood``."""
    for name, v, low in (("neighbourhood", neighbourhood, 1), ("max_iters", max_iters, 1),
                         ("fine_iters", fine_iters, 1), ("refine", refine, 0), ("starts", starts, 1)):
        if not isinstance(v, int) or v < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    if band is not None and (not isinstance(band, int) or band < 1):
        raise ValueError(f"band must be None or an integer >= 1, got {band!r}")
    if coarse is not None and (not isinstance(coarse, int) or coarse < 2):
        raise ValueError(f"coarse must be None or an integer >= 2, got {coarse!r}")
    nf = neighbourhood if band_neighbourhood is None else band_neighbourhood
    if not isinstance(nf, int) or nf < 1:
        raise ValueError(f"band_neighbourhood must be None or an integer >= 1, got {band_neighbourhood!r}")
    return DPSettings(neighbourhood, band, coarse, nf, max_iters, fine_iters, float(tol), refine, starts)


def dp_warp(q1: Tensor, q2: Tensor, neighbourhood: int = 6, band: int | None = 4, coarse: int | None = 16,
            band_neighbourhood: int | None = 5, refine: int = 0, backend: str = "auto") -> DPWarp:
    """Optimal warps of ``q2`` onto ``q1`` by dynamic programming (no rotation).

    Args:
        q1: ``(B, M, d)`` reference SRVFs (or ``(M, d)`` for one pair).
        q2: ``(B, M2, d)`` moving SRVFs; resampled (through their curves) to ``M`` segments if ``M2 != M``.
        neighbourhood: allowed steps are the coprime ``(a, b)`` with ``1 <= a, b <= neighbourhood``.
        band: with ``M > coarse``, the DP first runs on a grid of about ``M / 3`` segments (recursively
            until at most ``coarse``), then on the fine grid only within ``band`` cells of the coarse
            warp. ``None``: one DP over the whole lattice (its exact optimum over all lattice warps).
        band_neighbourhood: steps of the banded (finer) DPs (``None``: ``neighbourhood``). The
            defaults (6 on the coarse grid, 5 in a band of 4 cells) trade a little accuracy for speed
            (docs/experiments.md); ``band=None`` gives the exact lattice optimum.
        refine: iterations of a damped Gauss-Newton refinement that moves the warp's nodes off the
            lattice (0 = pure DP; ``torch4dtree.curves.refinement``); it only accepts steps that lower
            the energy and keeps the warp strictly monotone.
        backend: ``"numba"`` (CPU), ``"torch"`` (any device) or ``"auto"`` (numba for CPU tensors).

    Returns:
        ``DPWarp(gamma (B, M+1), energy (B,))`` with ``energy = ||q1 - warp_srvf(q2, gamma)||^2``,
        never above the identity warp's energy.

    Example:
        >>> import torch
        >>> from torch4dtree.data.examples import helix_pair
        >>> x, y = helix_pair(16)  # a helix arc and the same curve reparameterised
        >>> res = dp_warp(srvf(x), srvf(y))
        >>> before = warp_energy(srvf(x)[None], srvf(y)[None], identity_warp(1, 16))[0]  # the identity warp's
        >>> res.gamma.shape, bool(res.energy < before)
        (torch.Size([16]), True)
    """
    q2, q1, single = _check_inputs(q2, q1, 1, "SRVFs")
    cfg = dp_settings(neighbourhood, band, coarse, band_neighbourhood, 1, 1, 0.0, refine, 1)
    q2 = _resample_srvf(q2, q1.shape[1])
    be = pick_backend(backend, q1)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=q1.dtype, device=q1.device)
    fn = register_numba if be == "numba" else _register_torch
    with torch.no_grad():
        energy, _, gamma, _ = fn(q1.detach(), q2.detach(), "none", up, cfg)
    if single:
        gamma, energy = gamma[0], energy[0]
    return DPWarp(gamma, energy)


def register_curves(moving: Tensor, reference: Tensor, rotation: str = "none", srvf_input: bool = False,
                    neighbourhood: int = 3, band: int | None = 4, coarse: int | None = 16,
                    band_neighbourhood: int | None = 4,
                    up: Tensor | tuple[float, float, float] | None = None, max_iters: int = 6,
                    fine_iters: int = 1, tol: float = 1e-6, refine: int = 4, starts: int | None = None,
                    backend: str = "auto") -> CurveRegistration:
    """Elastic registration of ``moving`` onto ``reference``: ``min_{gamma,O} ||q_ref - O (q_mov o gamma)||``.

    Args:
        moving: ``(B, T2, d)`` curves (``(B, T2-1, d)`` SRVFs if ``srvf_input``), or one pair unbatched.
        reference: ``(B, T, d)`` curves (or SRVFs). ``moving`` is resampled to ``T`` points if needed
            (linearly in its parameter).
        rotation: ``"none"``, ``"vertical"`` (about ``up``, default z; d = 3) or ``"so3"``.
        srvf_input: inputs are SRVFs (curves then start at the origin).
        neighbourhood, band, coarse, band_neighbourhood, refine, backend: DP settings, see :func:`dp_warp`.
            The defaults here (slopes up to 3 on the coarsest grid, where the rotation / warp alternation
            runs, and up to 4 in the bands of the finer grids) are faster than :func:`dp_warp`'s 6 / 5 and
            about as good (docs/experiments.md). Steep slopes on the coarse grid let the alternation settle
            on degenerate warps; the finer grids and the refinement then recover fine detail. With
            ``band=None`` (one grid) ``neighbourhood`` is the only lattice: raise it for strongly non-uniform
            warps.
        up: the vertical axis for ``rotation="vertical"``.
        max_iters: rounds of (DP warp, optimal rotation) on the coarsest grid (with a rotation, that
            grid has at least ``4 d`` segments); ``fine_iters`` on finer
            grids. Rounds stop early when the energy decreases by less than ``tol`` relatively.
        starts: initial rotations tried on the coarsest grid (the Kabsch rotation at the identity warp,
            the identity, then that Kabsch rotation turned by half-turns about the axes (so3) or by
            turns about ``up`` (vertical)); the best is kept. Default 5 with a rotation (a single start
            can get stuck in a wrong basin, e.g. 180 degrees off), 1 without.

    Returns:
        :class:`CurveRegistration`. Warps and rotations are found without gradients; ``distance``,
        ``registered`` and ``q_registered`` are differentiable in the inputs given them.

    Example:
        >>> import torch
        >>> from torch4dtree.data.examples import helix_pair
        >>> x, y = helix_pair(16)  # a helix arc and the same curve reparameterised
        >>> r = register_curves(y, x)
        >>> r.gamma.shape, bool(r.energy < 0.01 * r.energy_before)
        (torch.Size([16]), True)
    """
    if srvf_input:
        moving, reference, single = _check_inputs(moving, reference, 1, "SRVFs")
    else:
        moving, reference, single = _check_inputs(moving, reference, 2, "curves")
    check_rotation_mode(rotation, moving.shape[-1])
    if starts is None:
        starts = 1 if rotation == "none" else 5
    if coarse is not None and rotation != "none":
        # a rotation of R^d is poorly determined by a very coarse curve in high dimension
        coarse = max(coarse, 4 * moving.shape[-1])
    cfg = dp_settings(neighbourhood, band, coarse, band_neighbourhood, max_iters, fine_iters, tol, refine,
                    starts)
    up_t = torch.as_tensor((0.0, 0.0, 1.0) if up is None else up, dtype=reference.dtype, device=reference.device)
    if up_t.shape != (3,) or not bool(up_t.norm() > 0):
        raise ValueError(f"up must be a nonzero 3-vector, got {up}")
    be = pick_backend(backend, reference)
    if be == "numba" and not (torch.is_grad_enabled() and (moving.requires_grad or reference.requires_grad)):
        # no gradient wanted: the whole registration (input prep and outputs too) in one numba call
        out = _register_curves_numba(moving, reference, srvf_input, rotation, up_t, cfg)
        return CurveRegistration(*(x[0] for x in out)) if single else out
    beta_m, beta_r = (inverse_srvf(moving), inverse_srvf(reference)) if srvf_input else (moving, reference)
    T = beta_r.shape[1]
    beta_m = _resample_curve(beta_m, T)
    q_ref, q_mov = srvf(beta_r), srvf(beta_m)
    fn = register_numba if be == "numba" else _register_torch
    with torch.no_grad():
        _, before, gamma, O = fn(q_ref.detach(), q_mov.detach(), rotation, up_t, cfg)
    registered = warp_curve(beta_m, gamma) @ O.transpose(-1, -2)
    registered = registered - registered[:, :1] + beta_r[:, :1]
    q_reg = srvf(registered)
    energy = srvf_sq_distance(q_ref, q_reg)
    distance = torch.where(energy > 0, energy.clamp_min(MIN_ENERGY).sqrt(), torch.zeros_like(energy))
    out = CurveRegistration(gamma, O, distance, energy, before.to(energy.dtype), registered, q_reg)
    if single:
        out = CurveRegistration(*(x[0] for x in out))
    return out


def elastic_distance(moving: Tensor, reference: Tensor, **kwargs: object) -> Tensor:
    """Elastic distance ``(B,)`` (or a scalar for one pair): ``register_curves(...).distance``.

    Example:
        >>> import torch
        >>> from torch4dtree.data.examples import helix_pair
        >>> x, y = helix_pair(16)  # a helix arc and the same curve reparameterised
        >>> float(elastic_distance(x, x)) < 1e-6, float(elastic_distance(y, x)) < 0.1
        (True, True)
    """
    return register_curves(moving, reference, **kwargs).distance  # type: ignore[arg-type]

