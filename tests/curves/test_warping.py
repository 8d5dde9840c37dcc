"""Properties of the elastic registration engine (torch4dtree.curves: DP warps, rotations, register_curves)."""

from __future__ import annotations

import math

import pytest
import torch
from samples import path_to_warp, rough_curves, smooth_curves

from torch4dtree import curves as W
from torch4dtree.curves import dp_numba, interpolate_curve, srvf, warp_curve, warp_srvf
from torch4dtree.curves.rotation import axis_rotation, optimal_rotation, random_rotation


def lattice_paths(M: int, n: int) -> list[list[tuple[int, int]]]:
    """Every monotone lattice path from (0,0) to (M,M) with coprime steps up to n (for tiny M)."""
    steps = W.neighbourhood_steps(n)
    out: list[list[tuple[int, int]]] = []

    def walk(path: list[tuple[int, int]]) -> None:
        i, j = path[-1]
        if (i, j) == (M, M):
            out.append(list(path))
            return
        for a, b in steps:
            if i + a <= M and j + b <= M:
                walk([*path, (i + a, j + b)])

    walk([(0, 0)])
    return out


# ------------------------------------------------------------------ the DP itself


def test_dp_is_the_exact_lattice_optimum() -> None:
    M, n = 6, 3
    beta1, beta2 = rough_curves(2, M + 1, seed=1), rough_curves(2, M + 1, seed=2)
    q1, q2 = srvf(beta1), srvf(beta2)
    paths = lattice_paths(M, n)
    warps = torch.stack([path_to_warp(p, M) for p in paths])  # (P, M+1)
    for backend in ("numba", "torch"):
        res = W.dp_warp(q1, q2, neighbourhood=n, band=None, backend=backend)
        for b in range(2):
            brute = W.warp_energy(q1[b].expand(len(paths), M, 3), q2[b].expand(len(paths), M, 3), warps)
            assert res.energy[b].item() == pytest.approx(brute.min().item(), abs=1e-12)
            # the reported energy is the discrete energy of the returned warp
            assert res.energy[b].item() == pytest.approx(W.warp_energy(q1[b:b + 1], q2[b:b + 1],
                                                                       res.gamma[b:b + 1]).item(), abs=1e-12)


def test_neighbourhood_steps() -> None:
    steps = W.neighbourhood_steps(6)
    assert len(steps) == 23 and steps[0] == (1, 1)
    assert all(math.gcd(a, b) == 1 and 1 <= a <= 6 and 1 <= b <= 6 for a, b in steps)


# (T, neighbourhood, band, coarse): several grid sizes, lattices and bands (band None = the full lattice)
BACKEND_CASES = [(5, 6, None, None), (9, 6, None, None), (17, 4, 2, 8), (33, 3, None, None), (33, 5, 4, 16),
                 (64, 1, None, None), (48, 3, 3, 12)]


@pytest.mark.parametrize(("T", "n", "band", "coarse"), BACKEND_CASES)
def test_torch_and_numba_dp_agree_on_rough_pairs(T: int, n: int, band: int | None, coarse: int | None) -> None:
    """The numba kernels and the torch twin: 100 rough (random-walk) pairs per case, the same warps and
    energies. Lattice warps are ratios of small integers, so two different choices differ by >= 1/(n M);
    agreement to 1e-15 is agreement of every discrete choice (the identity warp comes from np.linspace
    in one backend and torch.linspace in the other, which differ in the last bit)."""
    q1, q2 = srvf(rough_curves(100, T, seed=T + n)), srvf(rough_curves(100, T, seed=1000 + T + n))
    kw = {"neighbourhood": n, "band": band, "coarse": coarse, "band_neighbourhood": n}
    a = W.dp_warp(q1, q2, backend="numba", **kw)
    b = W.dp_warp(q1, q2, backend="torch", **kw)
    assert (a.gamma - b.gamma).abs().max() <= 1e-15
    assert torch.allclose(a.energy, b.energy, rtol=1e-13, atol=0)
    if n > 1:  # a real search: most pairs leave the identity
        assert (a.gamma != W.identity_warp(100, T)).any(1).float().mean() > 0.9


def test_torch_and_numba_registration_agree() -> None:
    """Whole registrations (rotation starts, coarse-to-fine bands, Gauss-Newton refinement) agree too."""
    x = rough_curves(8, 24, seed=3)
    y = warp_curve(x + 0.3 * rough_curves(8, 24, seed=4),
                   W.random_warp(8, 24, generator=torch.Generator().manual_seed(0), strength=0.5))
    y = y @ random_rotation(8, generator=torch.Generator().manual_seed(1)).transpose(-1, -2)
    for rotation in ("none", "vertical", "so3"):
        a = W.register_curves(y, x, rotation=rotation, coarse=8, refine=2, backend="numba")
        b = W.register_curves(y, x, rotation=rotation, coarse=8, refine=2, backend="torch")
        assert torch.allclose(a.energy, b.energy, rtol=1e-9, atol=1e-12)
        assert torch.allclose(a.gamma, b.gamma, atol=1e-9)
        assert torch.allclose(a.rotation, b.rotation, atol=1e-7)


# ------------------------------------------------------------------ registration properties


def test_identity_pair_gives_identity_and_zero_distance() -> None:
    x = smooth_curves(3, 50, seed=6)
    for rotation in ("none", "vertical", "so3"):
        r = W.register_curves(x, x, rotation=rotation)
        assert torch.allclose(r.gamma, W.identity_warp(3, 50), atol=1e-12)
        assert torch.allclose(r.rotation, torch.eye(3, dtype=x.dtype).expand(3, 3, 3), atol=1e-7)
        assert r.distance.max() < 1e-6


@pytest.mark.parametrize("rotation", ["none", "vertical", "so3"])
def test_recovers_warp_and_rotation(rotation: str) -> None:
    B, T = 4, 100
    x = smooth_curves(B, T, seed=7)
    gam = W.random_warp(B, T, generator=torch.Generator().manual_seed(8), strength=0.4)
    g = torch.Generator().manual_seed(9)
    if rotation == "so3":
        R = random_rotation(B, generator=g)
    elif rotation == "vertical":
        R = axis_rotation(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                          torch.rand(B, generator=g, dtype=torch.float64) * 2 * math.pi)
    else:
        R = torch.eye(3, dtype=torch.float64).expand(B, 3, 3)
    y = warp_curve(x, gam) @ R.transpose(-1, -2) + torch.randn(B, 1, 3, generator=g, dtype=torch.float64)
    r = W.register_curves(y, x, rotation=rotation)
    assert (r.distance < 0.05).all(), r.distance
    assert (r.distance < 0.05 * r.energy_before.sqrt()).all() or rotation == "none"
    mae = (r.gamma - W.invert_warp(gam)).abs().mean(1)
    assert (mae < 0.01).all(), mae
    assert (r.rotation - R.transpose(-1, -2)).abs().amax((1, 2)).max() < 0.05
    # the registered curve starts where the reference does and sits on it
    assert torch.allclose(r.registered[:, 0], x[:, 0])
    assert (r.registered - x).norm(dim=-1).amax(1).max() < 0.05


def test_symmetry() -> None:
    # unrelated curves without rotation: the optimum is unique enough for both directions to find it
    x, y = smooth_curves(4, 60, seed=10), smooth_curves(4, 60, seed=11)
    d_xy, d_yx = W.elastic_distance(x, y), W.elastic_distance(y, x)
    assert torch.allclose(d_xy, d_yx, rtol=0.05), (d_xy, d_yx)
    # with so3: a deformed, warped and rotated copy (a far-from-trivial distance, a clear optimum)
    z = x + 0.3 * smooth_curves(4, 60, seed=12)
    z = warp_curve(z, W.random_warp(4, 60, generator=torch.Generator().manual_seed(1), strength=0.4))
    z = z @ random_rotation(4, generator=torch.Generator().manual_seed(2)).transpose(-1, -2)
    d_xz, d_zx = W.elastic_distance(x, z, rotation="so3"), W.elastic_distance(z, x, rotation="so3")
    assert (d_xz > 0.1).all()
    assert torch.allclose(d_xz, d_zx, rtol=0.05), (d_xz, d_zx)


def _assert_proper(O: torch.Tensor) -> None:
    """Every ``O (..., d, d)`` is a proper rotation: ``O O^T = I`` and ``det O = +1``."""
    d = O.shape[-1]
    eye = torch.eye(d, dtype=O.dtype).expand_as(O)
    assert torch.allclose(O @ O.transpose(-1, -2), eye, atol=1e-10)
    assert torch.allclose(torch.linalg.det(O), torch.ones(O.shape[:-2], dtype=O.dtype), atol=1e-10)


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("rotation", ["none", "vertical", "so3"])
def test_every_rotation_is_proper(backend: str, rotation: str) -> None:
    """det = +1 and O O^T = I for every output in d = 3, every mode, both backends, including mirror
    images (where the best orthogonal matrix is a reflection, which must be excluded)."""
    B = 12 if backend == "numba" else 4
    x = rough_curves(B, 16, seed=50)
    mirror = x * torch.tensor([1.0, 1.0, -1.0], dtype=x.dtype)
    y = torch.cat([rough_curves(B // 2, 16, seed=51), mirror[: B // 2]])
    r = W.register_curves(y, x, rotation=rotation, coarse=8, backend=backend)
    _assert_proper(r.rotation)
    if rotation == "vertical":  # about the vertical axis: it stays fixed
        assert torch.allclose(r.rotation[:, :, 2], torch.tensor([0.0, 0.0, 1.0], dtype=x.dtype).expand(B, 3))
    q1, q2 = srvf(x), srvf(y)
    _assert_proper(optimal_rotation(q1, q2, rotation))
    for d in (2, 4):  # the SVD path (numba kernel and torch) outside d = 3
        xd = rough_curves(2, 16, d=d, seed=52)
        md = xd.clone()
        md[..., -1] = -md[..., -1]
        _assert_proper(W.register_curves(md, xd, rotation="so3", coarse=8, backend=backend).rotation)
        _assert_proper(optimal_rotation(srvf(xd), srvf(md), "so3"))
    _assert_proper(random_rotation(50, 3, generator=torch.Generator().manual_seed(3)))


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("rotation", ["vertical", "so3"])
def test_distance_invariant_to_random_rotations_of_the_moving_curve(rotation: str, backend: str) -> None:
    """Random angles (not one fixed angle): rotating the moving curve leaves the distance unchanged. Both
    backends: each has its own closed-form rotations."""
    B, T = (6, 50) if backend == "numba" else (2, 20)  # the torch twin is slow on the CPU
    kw = {"rotation": rotation, "backend": backend, "coarse": 16 if backend == "numba" else 8}
    x = smooth_curves(B, T, seed=40)
    y = 0.5 * smooth_curves(B, T, seed=41) + x
    d0 = W.register_curves(y, x, **kw).distance
    g = torch.Generator().manual_seed(0)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for _ in range(3 if backend == "numba" else 2):
        if rotation == "vertical":
            R = axis_rotation(up, torch.rand(B, generator=g, dtype=torch.float64) * 2 * math.pi)
        else:
            R = random_rotation(B, generator=g)
        d = W.register_curves(y @ R.transpose(-1, -2), x, **kw).distance
        assert torch.allclose(d, d0, rtol=1e-9), (d, d0)
    assert (d0 > 0.1).all()  # a real residual, so the invariance is not that of zeros


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_never_increases_energy_over_identity(backend: str) -> None:
    x, y = rough_curves(6, 30, seed=12), rough_curves(6, 30, seed=13)
    for rotation in ("none", "vertical", "so3"):
        r = W.register_curves(y, x, rotation=rotation, coarse=12, backend=backend)
        assert (r.energy <= r.energy_before).all()
        # energy_before is the identity warp and rotation
        assert torch.allclose(r.energy_before, W.warp_energy(srvf(x), srvf(y), W.identity_warp(6, 30)))
    q1, q2 = srvf(x), srvf(y)
    d = W.dp_warp(q1, q2, band=2, coarse=8, backend=backend)
    assert (d.energy <= W.warp_energy(q1, q2, W.identity_warp(6, 30))).all()


def test_batch_equals_one_by_one(monkeypatch: pytest.MonkeyPatch) -> None:
    x, y = smooth_curves(4, 40, seed=14), smooth_curves(4, 40, seed=15)
    for min_pairs in (10**9, 2):  # serial kernel, then the parallel one
        monkeypatch.setattr(dp_numba, "PARALLEL_MIN_PAIRS", min_pairs)
        monkeypatch.setattr(dp_numba, "idle_cores", lambda: 64)  # threads whatever the machine's load
        batch = W.register_curves(y, x, rotation="so3", coarse=16)
        for b in range(4):
            one = W.register_curves(y[b], x[b], rotation="so3", coarse=16)
            assert one.gamma.shape == (40,) and one.rotation.shape == (3, 3)
            assert torch.equal(one.gamma, batch.gamma[b])
            assert torch.allclose(one.distance, batch.distance[b], rtol=1e-12, atol=0)
    dp_batch = W.dp_warp(srvf(x), srvf(y))
    for b in range(4):  # dp_warp on one unbatched pair too
        dp_one = W.dp_warp(srvf(x[b]), srvf(y[b]))
        assert dp_one.gamma.shape == (40,) and dp_one.energy.shape == ()
        assert torch.equal(dp_one.gamma, dp_batch.gamma[b]) and float(dp_one.energy) == float(dp_batch.energy[b])


def test_float32_and_float64() -> None:
    x64, y64 = smooth_curves(2, 50, seed=16), smooth_curves(2, 50, seed=17)
    r64 = W.register_curves(y64, x64, rotation="so3")
    for backend in ("numba", "torch"):
        r32 = W.register_curves(y64.float(), x64.float(), rotation="so3", backend=backend)
        assert r32.gamma.dtype == r32.distance.dtype == r32.registered.dtype == torch.float32
        assert torch.allclose(r32.distance.double(), r64.distance, rtol=1e-3, atol=1e-4)


def test_differentiable_distance() -> None:
    x = smooth_curves(2, 30, seed=18).requires_grad_(True)
    y = smooth_curves(2, 30, seed=19)
    r = W.register_curves(y, x, rotation="so3")
    r.distance.sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    # the gradient is that of the energy at the fixed (gamma, O)
    eps = 1e-6
    dx = torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    q2w = warp_srvf(srvf(y), r.gamma) @ r.rotation.transpose(-1, -2)

    def dist(z: torch.Tensor) -> torch.Tensor:
        return ((srvf(z) - q2w) ** 2).sum((-1, -2)).div(29).sqrt().sum()

    with torch.no_grad():
        fd = (dist(x + eps * dx) - dist(x - eps * dx)) / (2 * eps)
    assert (x.grad * dx).sum().item() == pytest.approx(fd.item(), rel=1e-5)


def test_dimension_10_and_srvf_input_and_resampling() -> None:
    x = smooth_curves(3, 40, d=10, seed=20)
    gam = W.random_warp(3, 40, generator=torch.Generator().manual_seed(1), strength=0.3)
    R = random_rotation(3, d=10, generator=torch.Generator().manual_seed(2))
    y = warp_curve(x, gam) @ R.transpose(-1, -2)
    r = W.register_curves(y, x, rotation="so3")
    assert r.rotation.shape == (3, 10, 10)
    eye = torch.eye(10, dtype=x.dtype).expand(3, 10, 10)
    assert torch.allclose(r.rotation @ r.rotation.transpose(-1, -2), eye, atol=1e-10)
    assert (torch.linalg.det(r.rotation) > 0).all()
    assert (r.distance < 0.1 * r.energy_before.sqrt()).all()
    rq = W.register_curves(srvf(y), srvf(x), rotation="so3", srvf_input=True)
    assert torch.allclose(rq.distance, r.distance, atol=1e-10)
    # moving given with another number of points: resampled onto the reference grid
    rr = W.register_curves(warp_curve(y, W.identity_warp(3, 57)), x, rotation="none")
    assert rr.gamma.shape == (3, 40) and rr.registered.shape == (3, 40, 10)


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_moving_curve_with_another_number_of_points(backend: str) -> None:
    """The resampling path does the right thing, not only the right shapes: a warped copy given at 57
    points is registered onto the 40-point original, and the warp found is the true inverse warp. Both
    paths: the numba one resamples inside its kernel, the torch one (any device, or with gradients) in torch."""
    B = 6
    x40 = smooth_curves(B, 40, seed=30)
    gam = W.random_warp(B, 57, generator=torch.Generator().manual_seed(31), strength=0.4)
    y57 = warp_curve(smooth_curves(B, 57, seed=30), gam)  # the same curves, sampled at 57 points
    r = W.register_curves(y57, x40, backend=backend, coarse=8 if backend == "torch" else 16)
    assert r.gamma.shape == (B, 40) and r.registered.shape == (B, 40, 3)
    grid40 = torch.linspace(0, 1, 40, dtype=torch.float64).expand(B, 40)
    truth = interpolate_curve(W.invert_warp(gam).unsqueeze(-1), grid40)[..., 0]
    assert (r.gamma - truth).abs().mean(1).max() < 3e-3  # reading only the first 40 points: ~0.13
    assert (r.distance < 0.06).all()  # reading only the first 40 points: 0.18-0.58


def test_optimal_rotation_is_optimal() -> None:
    q1, q2 = srvf(rough_curves(5, 20, seed=21)), srvf(rough_curves(5, 20, seed=22))
    up = torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    for mode in ("so3", "vertical"):
        O = optimal_rotation(q1, q2, mode, up)
        best = W.srvf_sq_distance(q1, q2 @ O.transpose(-1, -2))
        g = torch.Generator().manual_seed(3)
        for _ in range(20):
            if mode == "so3":
                P = random_rotation(5, generator=g)
            else:
                P = axis_rotation(up, torch.rand(5, generator=g, dtype=torch.float64) * 2 * math.pi)
            assert (best <= W.srvf_sq_distance(q1, q2 @ P.transpose(-1, -2)) + 1e-12).all()
        if mode == "vertical":  # a rotation about up keeps up fixed
            assert torch.allclose(O @ (up / up.norm()), (up / up.norm()).expand(5, 3))


# ------------------------------------------------------------------ warp utilities


def test_warp_utilities() -> None:
    T = 200
    g = W.random_warp(5, T, generator=torch.Generator().manual_seed(4), strength=1.0)
    assert (g.diff(dim=1) > 0).all() and (g[:, 0] == 0).all() and (g[:, -1] == 1).all()
    ident = W.identity_warp(5, T)
    inv = W.invert_warp(g)
    assert (inv.diff(dim=1) >= 0).all() and (inv[:, 0] == 0).all() and (inv[:, -1] == 1).all()
    # linear interpolation errors are O(1/T^2)
    assert (W.compose_warps(g, inv) - ident).abs().max() < 5e-3
    assert (W.compose_warps(inv, g) - ident).abs().max() < 5e-3
    assert (W.invert_warp(W.compose_warps(g, inv)) - ident).abs().max() < 5e-3
    assert (W.invert_warp(inv) - g).abs().max() < 5e-3
    g0 = W.random_warp(3, T, generator=torch.Generator().manual_seed(5), strength=0.0)
    assert torch.allclose(g0, W.identity_warp(3, T))
    # warping a curve twice = warping by the composition
    x = smooth_curves(5, T, seed=23)
    assert (warp_curve(warp_curve(x, g), inv) - x).norm(dim=-1).max() < 5e-3


# ------------------------------------------------------------------ bad input


def test_bad_input_raises() -> None:
    x, y = smooth_curves(2, 20, seed=24), smooth_curves(3, 20, seed=25)
    with pytest.raises(ValueError, match="batch"):
        W.register_curves(y, x)
    with pytest.raises(ValueError, match="NaN"):
        z = x.clone()
        z[0, 3, 1] = float("nan")
        W.register_curves(z, x)
    with pytest.raises(ValueError, match="at least 2"):
        W.register_curves(x[:, :1], x[:, :1])
    with pytest.raises(ValueError, match="rotation"):
        W.register_curves(x, x, rotation="affine")
    with pytest.raises(ValueError, match="vertical"):
        W.register_curves(smooth_curves(2, 20, d=4), smooth_curves(2, 20, d=4), rotation="vertical")
    with pytest.raises(ValueError, match="dimension"):
        W.register_curves(smooth_curves(2, 20, d=4), x)
    with pytest.raises(ValueError, match="backend"):
        W.dp_warp(srvf(x), srvf(x), backend="cuda")
    with pytest.raises(ValueError, match="neighbourhood"):
        W.dp_warp(srvf(x), srvf(x), neighbourhood=0)
    with pytest.raises(ValueError, match="at least 2"):
        W.random_warp(2, 1)


def test_backend_choice_is_honoured(monkeypatch: pytest.MonkeyPatch) -> None:
    """``backend="torch"`` runs the torch twin and ``"numba"`` / ``"auto"`` (CPU) the kernels: the two agree
    so closely that a swapped choice would pass every comparison, so it is observed directly."""
    from torch4dtree.curves import register as R

    def boom(*args: object) -> None:
        raise RuntimeError("torch DP called")

    monkeypatch.setattr(R, "banded_dp_torch", boom)
    q1, q2 = srvf(rough_curves(2, 12, seed=60)), srvf(rough_curves(2, 12, seed=61))
    for backend in ("numba", "auto"):
        W.dp_warp(q1, q2, backend=backend)
    with pytest.raises(RuntimeError, match="torch DP called"):
        W.dp_warp(q1, q2, backend="torch")
