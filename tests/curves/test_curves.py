import math

import pytest
import torch

from torch4dtree.curves import (
    curve_length,
    interpolate_curve,
    inverse_srvf,
    project_on_polyline,
    resample_polylines,
    srvf,
    srvf_inner,
    srvf_sq_distance,
    srvf_sq_norm,
    warp_curve,
    warp_srvf,
)


def random_curves(B: int, T: int, d: int, dtype=torch.float64, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    steps = torch.randn(B, T - 1, d, generator=g, dtype=dtype).cumsum(1) * 0.1 + torch.randn(B, 1, d, generator=g,
                                                                                              dtype=dtype)
    start = torch.randn(B, 1, d, generator=g, dtype=dtype)
    return torch.cat([start, start + steps.cumsum(1) / T], dim=1)


@pytest.mark.parametrize("d", [2, 3, 10])
def test_round_trip_and_norm_is_length(d):
    beta = random_curves(5, 30, d)
    q = srvf(beta)
    assert q.shape == (5, 29, d)
    back = inverse_srvf(q, beta[:, 0])
    torch.testing.assert_close(back, beta, rtol=0, atol=1e-12)
    torch.testing.assert_close(srvf_sq_norm(q), curve_length(beta))


def test_any_leading_dims_and_batch_equals_one_by_one():
    beta = random_curves(6, 20, 3).reshape(2, 3, 20, 3)
    q = srvf(beta)
    assert q.shape == (2, 3, 19, 3)
    for i in range(2):
        for j in range(3):
            torch.testing.assert_close(q[i, j], srvf(beta[i, j]))
            torch.testing.assert_close(inverse_srvf(q[i, j]), inverse_srvf(q)[i, j])


def test_zero_speed_is_safe_and_gives_zero():
    beta = torch.zeros(7, 3, dtype=torch.float64, requires_grad=True)
    q = srvf(beta)
    assert torch.equal(q, torch.zeros(6, 3, dtype=torch.float64))
    q.sum().backward()
    assert torch.isfinite(beta.grad).all()
    # a curve that pauses: the paused segment has q = 0 and the inverse still reproduces it
    b = torch.tensor([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 2, 0]], dtype=torch.float64)
    qb = srvf(b)
    assert torch.equal(qb[1], torch.zeros(3, dtype=torch.float64))
    torch.testing.assert_close(inverse_srvf(qb), b)


def test_gradcheck_float64():
    beta = random_curves(2, 8, 3).requires_grad_(True)
    assert torch.autograd.gradcheck(srvf, (beta,))
    q = srvf(beta).detach().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: inverse_srvf(x), (q,))
    other = q.detach().clone() * 0.5
    assert torch.autograd.gradcheck(lambda x: srvf_sq_distance(x, other), (q,))


def test_inner_product_and_distance_consistent():
    q1, q2 = srvf(random_curves(3, 16, 3, seed=1)), srvf(random_curves(3, 16, 3, seed=2))
    lhs = srvf_sq_distance(q1, q2)
    rhs = srvf_sq_norm(q1) + srvf_sq_norm(q2) - 2 * srvf_inner(q1, q2)
    torch.testing.assert_close(lhs, rhs)


def test_straight_line_srvf_is_constant():
    t = torch.linspace(0, 1, 11, dtype=torch.float64)[:, None]
    beta = t * torch.tensor([3.0, 4.0, 0.0], dtype=torch.float64)
    q = srvf(beta)
    torch.testing.assert_close(q, torch.tensor([3.0, 4.0, 0.0], dtype=torch.float64).expand(10, 3) / math.sqrt(5))


def test_identity_warp_is_identity_and_warps_keep_the_curve():
    beta = random_curves(2, 25, 3)
    ident = torch.linspace(0, 1, 25, dtype=torch.float64).expand(2, 25)
    torch.testing.assert_close(warp_curve(beta, ident), beta)
    torch.testing.assert_close(warp_srvf(srvf(beta), ident), srvf(beta))
    gamma = ident**2
    warped = warp_curve(beta, gamma)
    # same end points, and every warped point lies on the original polyline
    torch.testing.assert_close(warped[:, [0, -1]], beta[:, [0, -1]])
    for b in range(2):
        _, dist = project_on_polyline(beta[b : b + 1].expand(25, -1, -1), warped[b])
        assert dist.max() < 1e-12
    # the warped polyline is inscribed in the original: never longer
    assert (curve_length(warped) <= curve_length(beta) + 1e-12).all()


def test_warp_srvf_matches_srvf_of_warped_curve():
    beta = random_curves(3, 30, 4)
    gamma = torch.linspace(0, 1, 30, dtype=torch.float64).expand(3, 30) ** 1.5
    torch.testing.assert_close(warp_srvf(srvf(beta), gamma), srvf(warp_curve(beta - beta[:, :1], gamma)))


def test_resample_uniform_arclength_and_ragged():
    g = torch.Generator().manual_seed(3)
    raw = torch.randn(2, 12, 3, generator=g, dtype=torch.float64).cumsum(1)
    counts = torch.tensor([12, 7])
    out = resample_polylines(raw, counts, 50)
    assert out.shape == (2, 50, 3)
    for b, n in enumerate(counts.tolist()):
        torch.testing.assert_close(out[b, 0], raw[b, 0])
        torch.testing.assert_close(out[b, -1], raw[b, n - 1])
        # points at equal arc-length steps along the raw polyline: equal spacing along the raw curve
        seg = (raw[b, 1:n] - raw[b, : n - 1]).norm(dim=-1)
        cum = torch.cat([torch.zeros(1, dtype=torch.float64), seg.cumsum(0)])
        s, dist = project_on_polyline(raw[b : b + 1, :n].expand(50, -1, -1), out[b])
        assert dist.max() < 1e-9
        x = s * (n - 1)
        k = x.floor().long().clamp(max=n - 2)
        along = cum[k] + (x - k) * seg[k]
        torch.testing.assert_close(along / cum[-1], torch.linspace(0, 1, 50, dtype=torch.float64), atol=1e-9, rtol=0)


def test_resample_rejects_single_points():
    with pytest.raises(ValueError, match="at least 2"):
        resample_polylines(torch.zeros(1, 3, 3), torch.tensor([1]), 10)


def test_interpolate_and_project_are_inverse():
    beta = resample_polylines(random_curves(1, 20, 3), torch.tensor([20]), 40)
    s = torch.tensor([[0.0, 0.123, 0.5, 0.77, 1.0]], dtype=torch.float64)
    pts = interpolate_curve(beta, s)[0]
    s_back, dist = project_on_polyline(beta.expand(5, -1, -1), pts)
    assert dist.max() < 1e-9
    torch.testing.assert_close(s_back, s[0], atol=1e-6, rtol=0)


def test_two_point_curves_are_curves():
    """The shortest curve, one segment: its SRVF, inverse and norm (= length) are exact, no error."""
    beta = torch.tensor([[[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]]], dtype=torch.float64)
    q = srvf(beta)
    torch.testing.assert_close(q, torch.tensor([[[3.0, 4.0, 0.0]]], dtype=torch.float64) / math.sqrt(5))
    torch.testing.assert_close(inverse_srvf(q), beta)
    torch.testing.assert_close(srvf_sq_norm(q), torch.tensor([5.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="at least 2 points"):
        srvf(beta[:, :1])


@pytest.mark.parametrize("compiled", [True, False])
def test_warp_energies_of_one_pair(compiled: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """The tree registration's energies of several warps of one SRVF pair: ``||q1 - warp_srvf(q2, g)||^2`` per warp,
    by the numba kernel and by the torch ops alike; the identity warp gives the plain distance."""
    from torch4dtree.curves import register
    from torch4dtree.curves.srvf import srvf_sq_distance, warp_srvf
    from torch4dtree.curves.warps import random_warp

    if compiled and not register.HAVE_NUMBA:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(register, "HAVE_NUMBA", compiled)
    g = torch.Generator().manual_seed(3)
    q1, q2 = torch.randn(2, 20, 3, generator=g, dtype=torch.float64)
    gammas = torch.cat([torch.linspace(0, 1, 21, dtype=torch.float64)[None],
                        random_warp(4, 21, generator=g).to(torch.float64)])
    got = register.warp_energies(q1, q2, gammas.numpy())
    want = srvf_sq_distance(q1, warp_srvf(q2.expand(5, -1, -1), gammas))
    assert got.shape == (5,)
    torch.testing.assert_close(torch.from_numpy(got), want, rtol=1e-10, atol=1e-12)
    assert got[0] == pytest.approx(float(srvf_sq_distance(q1, q2)), rel=1e-12)
    assert len(set(got.round(6).tolist())) == 5  # the warps matter
