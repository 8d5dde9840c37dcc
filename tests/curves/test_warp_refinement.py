"""The Gauss-Newton refinement of DP warps (torch4dtree.curves.refinement)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from samples import rough_curves, smooth_curves

from torch4dtree import curves as W
from torch4dtree.curves import refinement as R
from torch4dtree.curves import srvf, warp_curve


def _numba_refine(q1: torch.Tensor, beta2: torch.Tensor, gamma: torch.Tensor, iters: int) -> torch.Tensor:
    out = gamma.detach().double().numpy().copy()
    for b in range(len(out)):
        R.nb_gauss_newton(q1[b].double().numpy().copy(), beta2[b].double().numpy().copy(), out[b], iters)
    return torch.from_numpy(out)


def _energy(q1: torch.Tensor, beta2: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    return W.warp_energy(q1, srvf(beta2), gamma)


def test_residuals_are_the_discrete_energy() -> None:
    x, y = smooth_curves(3, 30, seed=1), smooth_curves(3, 30, seed=2)
    gamma = W.random_warp(3, 30, generator=torch.Generator().manual_seed(0))
    e, res, j0, j1 = R._residuals_torch(srvf(x), y, gamma)
    assert torch.allclose(e / 29, _energy(srvf(x), y, gamma), rtol=1e-12)
    assert res.shape == j0.shape == j1.shape == (3, 29, 3)


@pytest.mark.parametrize("refine", ["numba", "torch"])
def test_recovers_a_smooth_warp_from_a_perturbed_start(refine: str) -> None:
    """Moving = reference o gamma0: the optimum is gamma0^-1; GN from a perturbed start gets much closer."""
    T = 80
    x = smooth_curves(4, T, seed=3)
    g = torch.Generator().manual_seed(1)
    gamma0 = W.random_warp(4, T, generator=g, strength=0.5)
    y = warp_curve(x, gamma0)
    truth = W.invert_warp(gamma0)
    start = W.compose_warps(truth, W.random_warp(4, T, generator=g, strength=0.1))
    q1 = srvf(x)
    fn = _numba_refine if refine == "numba" else R.gauss_newton_torch
    out = fn(q1, y, start, 10)
    e0, e1 = _energy(q1, y, start), _energy(q1, y, out)
    assert (e1 < 0.1 * e0).all()
    err0 = (start - truth).abs().mean(1)
    err1 = (out - truth).abs().mean(1)
    assert (err1 < 0.3 * err0).all() and (err1 < 2e-3).all()
    assert torch.equal(out[:, 0], start[:, 0]) and torch.equal(out[:, -1], start[:, -1])
    assert (torch.diff(out, dim=1) > 0).all()


def test_numba_and_torch_agree_and_never_increase_the_energy() -> None:
    x, y = rough_curves(5, 40, seed=4), rough_curves(5, 40, seed=5)  # kinked polylines
    q1 = srvf(x)
    dp = W.dp_warp(q1, srvf(y), band=None)
    for iters in (1, 3, 8):
        a = _numba_refine(q1, y, dp.gamma, iters)
        b = R.gauss_newton_torch(q1, y, dp.gamma, iters)
        assert torch.allclose(a, b, atol=1e-9, rtol=0)
        e = _energy(q1, y, a)
        assert (e <= dp.energy * (1 + 1e-12)).all()
        assert (torch.diff(a, dim=1) > 0).all()
    assert (_energy(q1, y, a) < dp.energy).all()  # and it does lower it, off the lattice


def test_float32_follows_float64() -> None:
    x, y = smooth_curves(3, 50, seed=6), smooth_curves(3, 50, seed=7)
    q1 = srvf(x)
    dp = W.dp_warp(q1, srvf(y), band=None)
    g64 = R.gauss_newton_torch(q1, y, dp.gamma, 6)
    g32 = R.gauss_newton_torch(q1.float(), y.float(), dp.gamma.float(), 6)
    assert g32.dtype == torch.float32
    assert torch.allclose(g32.double(), g64, atol=1e-4)
    assert torch.allclose(_energy(q1, y, g32.double()), _energy(q1, y, g64), rtol=1e-4)


def test_degenerate_segments_stay_finite() -> None:
    """A moving curve with repeated points (zero-length segments) and a constant one: no NaN, no rise."""
    x = smooth_curves(2, 30, seed=8)
    y = smooth_curves(2, 30, seed=9)
    y[0, 10:14] = y[0, 10]
    y[1] = y[1, :1]
    q1 = srvf(x)
    start = W.random_warp(2, 30, generator=torch.Generator().manual_seed(2), strength=0.3)
    for out in (_numba_refine(q1, y, start, 5), R.gauss_newton_torch(q1, y, start, 5)):
        assert torch.isfinite(out).all()
        assert (torch.diff(out, dim=1) >= 0).all()
        assert (_energy(q1, y, out) <= _energy(q1, y, start) * (1 + 1e-12)).all()


def test_refinement_lowers_registration_energies() -> None:
    """In register_curves, Gauss-Newton iterations lower the energies found (on average: the rotation
    found after refining may differ, so single pairs can move either way)."""
    x = smooth_curves(6, 60, seed=10)
    y = smooth_curves(6, 60, seed=11) * 0.3 + x
    e = {k: W.register_curves(y, x, rotation="so3", refine=k).energy for k in (0, 4)}
    assert float(e[4].mean()) < 0.97 * float(e[0].mean())
    assert np.isfinite(e[4].numpy()).all()


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_more_refinement_iterations_lower_the_energy_further(backend: str) -> None:
    """``refine=k`` runs k iterations from the same DP warp (no rotation to confound it), so energies never rise
    with k and, on rough pairs, 8 iterations go clearly below 1 (a refinement stuck at one iteration fails)."""
    x, y = rough_curves(8, 40, seed=4), rough_curves(8, 40, seed=5)
    e = {k: W.register_curves(y, x, rotation="none", refine=k, backend=backend).energy for k in (0, 1, 2, 8)}
    for lo, hi in ((1, 0), (2, 1), (8, 2)):
        assert (e[lo] <= e[hi] * (1 + 1e-12)).all()
    assert float(e[8].mean()) < 0.98 * float(e[1].mean())


def test_refinement_strides() -> None:
    assert R.refinement_strides(1) == [1]
    assert R.refinement_strides(8) == [4, 2, 1]
    assert R.refinement_strides(6) == [3, 1]
    assert R.refinement_strides(5) == [1]
    with pytest.raises(ValueError):
        R.refinement_strides(0)


def test_refine_on_finer_backends_agree_and_never_raise_the_energy() -> None:
    """Moving curves given 8 times finer (rough: a kink at every fine point): both backends give the same warps and
    readings, and the reading kept is never farther than the start's on the samples."""
    T, F = 25, 8
    fine = rough_curves(6, F * (T - 1) + 1, seed=6)
    q1 = srvf(rough_curves(6, T, seed=7))
    start = W.dp_warp(q1, srvf(fine[:, ::F]), band=None, refine=4).gamma
    a, fa = R.refine_on_finer(q1, fine, start, 8, "numba")
    b, fb = R.refine_on_finer(q1, fine, start, 8, "torch")
    assert torch.equal(fa, fb) and bool(fa.any())
    assert torch.allclose(a, b, atol=1e-9, rtol=0)
    e_start = _energy(q1, fine[:, ::F], start)
    e_kept = torch.where(fa, _energy(q1, fine, a), _energy(q1, fine[:, ::F], a))
    assert bool((e_kept <= e_start * (1 + 1e-12)).all())
    assert bool((torch.diff(a, dim=1) > 0).all()) and bool((a[:, 0] == 0).all()) and bool((a[:, -1] == 1).all())
    assert torch.equal(a[~fa], start[~fa])
    with pytest.raises(ValueError, match="multiple"):
        R.refine_on_finer(q1, fine[:, :-1], start, 8)
