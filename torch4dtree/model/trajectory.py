"""4D statistics of trajectories (docs/method.md §5, paper §4.2): the 4D Karcher mean and the trajectory PCA.

A 4D tree is ``(alpha(0), q)``: its trajectory's start point and SRVF (:mod:`torch4dtree.temporal.trajectory`).
Flattened as ``x = [alpha(0), q / sqrt(n_t - 1)]`` the Euclidean norm of differences is the 4D distance of
:func:`~torch4dtree.temporal.register_trajectories`, so once every trajectory is time-warped onto the mean, the
mean is an average and the PCA an SVD.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from ..settings import TemporalSettings, check_at_least
from ..space.fitted import FittedModule, NotFittedError
from ..space.pca import check_components, principal_axes, variance_components
from ..temporal.registration import TemporalRegistration, time_warp_trajectory
from ..temporal.trajectory import trajectory_from_srvf, trajectory_srvf
from ..temporal.within import inverse_at

# trajectories decoded per chunk by TrajectoryPCA.trajectories (see there)
SAMPLE_CHUNK = 1024

__all__ = ["TrajectoryMean", "TrajectoryPCA", "centre_warps", "flatten_srvf", "unflatten_srvf"]


def _check_alpha(alpha: Tensor, name: str = "alpha") -> None:
    if not isinstance(alpha, Tensor) or not alpha.is_floating_point():
        raise TypeError(f"{name} must be a floating point tensor")
    if alpha.dim() != 3 or alpha.shape[1] < 2 or alpha.shape[2] < 1:
        raise ValueError(f"{name} must be (N, n_t >= 2, k), got {tuple(alpha.shape)}")
    if not bool(torch.isfinite(alpha).all()):
        raise ValueError(f"{name} contains NaN or inf")


def flatten_srvf(start: Tensor, q: Tensor) -> Tensor:
    """``start (..., k)``, ``q (..., n_t - 1, k) -> x (..., k * n_t)``: Euclidean norms are 4D distances."""
    return torch.cat([start, q.flatten(-2) / math.sqrt(q.shape[-2])], dim=-1)


def unflatten_srvf(x: Tensor, n_t: int, k: int) -> tuple[Tensor, Tensor]:
    """Inverse of :func:`flatten_srvf`: ``x (..., k * n_t) -> (start (..., k), q (..., n_t - 1, k))``."""
    if x.shape[-1] != k * n_t:
        raise ValueError(f"expected vectors of length k * n_t = {k * n_t}, got {tuple(x.shape)}")
    return x[..., :k], x[..., k:].unflatten(-1, (n_t - 1, k)) * math.sqrt(n_t - 1)


def centre_warps(warp: Tensor) -> Tensor:
    """``warp (N, n_t)`` composed with the inverse of their average: ``gamma_i o gamma_bar^{-1}``.

    The registered distances do not change when the mean and every registered trajectory are re-timed by one
    warp, so the Karcher iteration is free to drift along that direction; it did, to a mean whose warps all sat
    near 0 until one late time and then jumped to 1 (the mean collapsed onto a few time samples). Centering each
    round keeps the warps' average at the identity, as in the elastic Karcher means of Srivastava & Klassen
    (2016, ch. 8); the plain average of the warps stands in for their Karcher mean (close for mild warps).
    """
    N, n_t = warp.shape
    grid = torch.linspace(0, 1, n_t, dtype=warp.dtype, device=warp.device)
    mean = warp.mean(0)
    inverse = inverse_at(mean.expand(n_t, n_t), grid)  # gamma_bar^{-1} on the grid
    return time_warp_trajectory(warp[..., None], inverse.expand(N, n_t))[..., 0]


class TrajectoryMean(FittedModule):
    """The 4D Karcher mean: iterate {temporally register every trajectory onto the mean; centre the warps
    (:func:`centre_warps`); average SRVFs and start points} (the first mean is the plain average, identity warps).

    Args:
        max_iters: at most this many rounds of registration onto a mean.
        tol: stop when the energy (sum of squared 4D distances to the mean) decreases by less than ``tol``
            relatively.
        registration: the time-warp DP (:class:`~torch4dtree.settings.TemporalSettings`; no time weight: the
            4D mean is defined with the rate-invariant distance).

    Fitted buffers: ``start (k,)``, ``q (n_t - 1, k)``, ``trajectory (n_t, k)``. ``energies_`` (one per round,
    the energy of the registrations onto that round's mean) travels in the extra state; the mean kept is the
    round of lowest energy.

    Example:
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> alpha = torch.stack([torch.cat([t, t ** p], 1) for p in (1.0, 2.0, 3.0)])
        >>> mean = TrajectoryMean(max_iters=3).fit(alpha)
        >>> mean.trajectory.shape
        torch.Size([8, 2])
    """

    _fitted_buffers = ("start", "q", "trajectory")

    def __init__(self, max_iters: int = 10, tol: float = 1e-3, registration: TemporalSettings | None = None
                 ) -> None:
        super().__init__()
        self.max_iters, self.tol = check_at_least("max_iters", max_iters, 1), float(tol)
        if registration is not None and not isinstance(registration, TemporalSettings):
            raise TypeError(f"registration must be a TemporalSettings, got {type(registration).__name__}")
        self.registration = registration or TemporalSettings()
        self.energies_: list[float] = []
        for name, shape in (("start", (0,)), ("q", (0, 0)), ("trajectory", (0, 0))):
            self.register_buffer(name, torch.zeros(shape))

    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "max_iters": self.max_iters, "tol": self.tol, "registration": self.registration.to_dict(),
                "energies": list(self.energies_)}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a TrajectoryMean state")
        self.max_iters, self.tol = state["max_iters"], state["tol"]
        self.registration = TemporalSettings.from_dict(state["registration"])
        self.energies_ = list(state["energies"])

    @property
    def is_fitted(self) -> bool:
        return self.trajectory.shape[0] > 0

    def register(self, alpha: Tensor) -> TemporalRegistration:
        """Time-warp trajectories ``alpha (..., n_t, k)`` onto the mean (batched temporal registration)."""
        if not self.is_fitted:
            raise NotFittedError("TrajectoryMean is not fitted")
        if alpha.shape[-2:] != self.trajectory.shape:
            raise ValueError(f"trajectories must end with {tuple(self.trajectory.shape)}, got {tuple(alpha.shape)}")
        mov = alpha.to(self.trajectory)
        return self.registration.register(self.trajectory.expand_as(mov), mov)

    def fit(self, alpha: Tensor) -> TrajectoryMean:
        """Fit on ``alpha (N, n_t, k)``. Returns ``self``; ``registered_`` holds the registrations onto the result.

        Stops when a round lowers the energy by less than ``tol`` (relatively) or after ``max_iters`` rounds, and
        keeps the round of lowest energy (centering is exact only in the continuum, so a round can end a little
        higher than the one before; that round ends the iteration and is not kept).
        """
        _check_alpha(alpha)
        a = alpha.detach()
        start, q = trajectory_srvf(a)
        mean_start, mean_q = start.mean(0), q.mean(0)
        self.energies_ = []
        rounds: list[tuple[float, Tensor, TemporalRegistration]] = []
        for _ in range(self.max_iters):
            self._set_fitted(start=mean_start, q=mean_q, trajectory=trajectory_from_srvf(mean_start, mean_q))
            reg = self.register(a)
            energy = float(reg.distance.square().sum())
            self.energies_.append(energy)
            rounds.append((energy, mean_q, reg))
            if len(self.energies_) > 1 and self.energies_[-2] - energy <= self.tol * max(self.energies_[-2], 1e-300):
                break
            _, q_centred = trajectory_srvf(time_warp_trajectory(a, centre_warps(reg.warp)))
            mean_q = q_centred.mean(0)
        _, mean_q, self.registered_ = min(rounds, key=lambda x: x[0])
        self._set_fitted(start=mean_start, q=mean_q, trajectory=trajectory_from_srvf(mean_start, mean_q))
        return self


class TrajectoryPCA(FittedModule):
    """PCA of registered trajectories (SRVFs with their start points); modes ``mean + tau sqrt(u_i) delta_i``.

    Coefficients are **standardised**: ``z_i`` is the projection on component ``i`` divided by ``sqrt(u_i)``, so a
    standard normal ``z`` follows the fitted Gaussian. ``m`` components: ``n_components``, or the smallest number
    explaining ``variance`` of the total.

    Fitted buffers: ``mean (D,)`` (``D = k * n_t``, :func:`flatten_srvf`), ``components (m, D)`` orthonormal,
    ``explained_variance (m,)`` (``u_i``, with ``1/(N-1)``), ``explained_variance_ratio (m,)``. Copies of one
    trajectory give one component of zero variance.

    Example:
        >>> from torch4dtree.temporal import trajectory_srvf
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> start, q = trajectory_srvf(torch.stack([torch.cat([t, a * t ** 2], 1) for a in (0.5, 1.0, 2.0)]))
        >>> pca = TrajectoryPCA(n_components=1).fit(start, q)
        >>> pca.trajectories(torch.zeros(1, 1, dtype=torch.float64)).shape
        torch.Size([1, 8, 2])
    """

    _fitted_buffers = ("mean", "components", "explained_variance", "explained_variance_ratio")

    def __init__(self, n_components: int | None = None, variance: float = 0.95) -> None:
        super().__init__()
        self.n_components, self.variance = check_components(n_components, variance)
        self.n_t, self.k, self.total_variance_ = 0, 0, 0.0
        for name in ("mean", "explained_variance", "explained_variance_ratio"):
            self.register_buffer(name, torch.zeros(0))
        self.register_buffer("components", torch.zeros(0, 0))

    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "n_components": self.n_components, "variance": self.variance, "n_t": self.n_t,
                "k": self.k, "total_variance": self.total_variance_}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a TrajectoryPCA state")
        self.n_components, self.variance = state["n_components"], state["variance"]
        self.n_t, self.k, self.total_variance_ = state["n_t"], state["k"], state["total_variance"]

    @property
    def n_modes(self) -> int:
        return self.components.shape[0]

    def _check_fitted(self) -> None:
        if self.n_modes == 0:
            raise NotFittedError("TrajectoryPCA is not fitted")

    def fit(self, start: Tensor, q: Tensor, center: Tensor | None = None) -> TrajectoryPCA:
        """Fit on ``N >= 2`` registered trajectories: ``start (N, k)``, ``q (N, n_t - 1, k)``. Returns ``self``.

        ``center (k * n_t,)``: the flattened 4D mean to centre on (the Karcher mean, so that ``z = 0`` is exactly
        it: the PCA of the tangent space at the mean); default the average of the inputs.
        """
        if q.dim() != 3 or start.shape != (q.shape[0], q.shape[2]):
            raise ValueError(f"start must be (N, k) and q (N, n_t - 1, k), got {tuple(start.shape)}, {tuple(q.shape)}")
        N = q.shape[0]
        if N < 2:
            raise ValueError(f"PCA needs at least 2 trajectories, got {N}")
        X = flatten_srvf(start, q).detach()
        mean = X.mean(0) if center is None else center.detach().to(X)
        if mean.shape != X.shape[1:]:
            raise ValueError(f"center must be ({X.shape[1]},), got {tuple(mean.shape)}")
        sing, Vh = principal_axes(X - mean)
        var = sing.square() / (N - 1)
        total = float(var.sum())
        ratio = var / total if total > 0 else torch.zeros_like(var)
        m = min(self.n_components, len(var)) if self.n_components is not None else \
            variance_components(var, self.variance)
        comps = Vh[:m]
        big = comps.abs().argmax(1, keepdim=True)
        comps = comps * torch.sign(comps.gather(1, big))
        self.n_t, self.k, self.total_variance_ = q.shape[1] + 1, q.shape[2], total
        self._set_fitted(mean=mean, components=comps, explained_variance=var[:m].clamp_min(0),
                         explained_variance_ratio=ratio[:m])
        return self

    def scales(self) -> Tensor:
        """``(m,)`` standard deviations ``sqrt(u_i)``."""
        return self.explained_variance.sqrt()

    def vectors(self, z: Tensor) -> Tensor:
        """Flattened 4D trees ``x (..., D) = mean + (z sqrt(u)) @ components`` from ``z (..., m)`` (differentiable)."""
        self._check_fitted()
        if z.shape[-1] != self.n_modes:
            raise ValueError(f"coefficients must end with m={self.n_modes}, got {tuple(z.shape)}")
        return self.mean + (z.to(self.mean.dtype) * self.scales()) @ self.components

    def trajectories(self, z: Tensor) -> Tensor:
        """``z (..., m) -> alpha (..., n_t, k)`` (differentiable).

        Large batches run in chunks of ``SAMPLE_CHUNK``: the work is memory-bound, and a chunk's intermediates stay
        in cache (benchmarks/bench_model.py, 20 synthetic plants, k = 94: 4.5-7k trajectories/s in one batch of
        10,000, 18.5k/s in chunks of 1,000).
        """
        lead = z.shape[:-1]
        flat = z.reshape(-1, z.shape[-1])
        if flat.shape[0] > SAMPLE_CHUNK:
            alpha = torch.cat([self.trajectories(c) for c in flat.split(SAMPLE_CHUNK)])
            return alpha.reshape(*lead, *alpha.shape[-2:])
        start, q = unflatten_srvf(self.vectors(z), self.n_t, self.k)
        return trajectory_from_srvf(start, q)

    def project(self, start: Tensor, q: Tensor) -> tuple[Tensor, Tensor]:
        """Standardised coefficients ``z (..., m)`` of registered trajectories and the residual norm ``(...,)`` (the
        4D distance to their reconstruction). Modes of zero variance get ``z = 0``."""
        self._check_fitted()
        xc = flatten_srvf(start, q).to(self.mean) - self.mean
        proj = xc @ self.components.T
        s = self.scales()
        z = torch.where(s > 0, proj / torch.where(s > 0, s, 1), torch.zeros_like(proj))
        residual = (xc - proj @ self.components).norm(dim=-1)
        return z, residual

    def modes(self, taus: Tensor, modes: int | None = None) -> Tensor:
        """Trajectories along the first ``modes`` modes at ``taus`` sd: ``(modes, len(taus), n_t, k)``."""
        self._check_fitted()
        m = self.n_modes if modes is None else min(modes, self.n_modes)
        t = taus.to(self.mean)
        z = torch.zeros(m, len(t), self.n_modes, dtype=self.mean.dtype, device=self.mean.device)
        z[torch.arange(m), :, torch.arange(m)] = t
        return self.trajectories(z)
