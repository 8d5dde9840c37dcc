"""The generative model of 4D trees (SPEC §5, paper §4.2 / §5.3): tree space, 4D mean and modes, sampler.

``FourDTreeModel`` bundles the fitted pipeline:

    4D trees -> Population (one layout, tree PCA, trajectories in R^k) -> TrajectoryMean (temporal Karcher mean)
      -> TrajectoryPCA (modes of the registered SRVFs) ;  TruncatedNormalSampler -> z -> trajectories -> trees

Coefficients ``z (B, m)`` are standardised mode coordinates. ``model(z)`` is differentiable (dense tensors);
:meth:`decode` turns them into :class:`TreeSequence` s (a separate, slower step: skeleton integration per frame).
Times of generated 4D trees are in the data's units: the training trees' mean first time plus the normalised
grid times the mean duration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor, nn

from ..temporal.population import Population
from ..temporal.registration import time_warp_trajectory
from ..temporal.spatiotemporal import CROSS_LP, CROSS_POSITIONS
from ..trees.structures import Trees, TreeSequence
from .sampler import TruncatedNormalSampler
from .trajectory import TrajectoryMean, TrajectoryPCA, flatten_srvf

__all__ = ["FourDTreeModel", "Forecast", "ModelOutput", "Score", "persistence_gains"]

# forecast: candidate time-rate factors of the observed part (its affine temporal alignment onto the model), with a
# log-normal prior of this spread on the rate (without it, the widest rates won on synthetic plants and forecasts lost
# to the population mean)
FORECAST_RATES = (0.8, 0.9, 1.0, 1.1, 1.25)
FORECAST_RATE_SPREAD = 0.15
# forecast: Gauss-Newton steps for the conditional mode
FORECAST_STEPS = 8
# forecast observation noise: at least this share of the training trajectories' mean squared spread about the mean,
# and at least what the modes leave unexplained of them per time sample
FORECAST_NOISE = 0.05
# forecast gain calibration (fit): at most this many training plants (each costs one encoding, :meth:`fit`)
FORECAST_CALIBRATION_PLANTS = 12
# forecast gain calibration: shrink factors of the per-component gains, chosen by leave-one-out over the training
# plants (0, the 4D mean alone, is among them: the forecast follows the plant only where that predicted held-out ones)
FORECAST_SHRINK = (0.0, 0.25, 0.5, 0.75, 1.0)


class ModelOutput(NamedTuple):
    """``model(z)``: ``trajectory (B, n_t, k)`` tree-PCA coordinates; ``features (B, n_t, F)`` the frames' weighted
    SRVFT features in the population layout (:meth:`AlignedTrees.features`); ``times (n_t,)`` in data units."""

    trajectory: Tensor
    features: Tensor
    times: Tensor


class Score(NamedTuple):
    """:meth:`FourDTreeModel.score`: ``mahalanobis`` = ``|z|`` over the modes; ``residual`` the 4D distance outside
    the modes; ``distance`` the registered 4D distance to the mean; ``outside`` the root mean square over frames of
    the tree distance carried by branches that match no slot of the layout (dropped by the encoding: a plant
    unlike the training ones shows up here); ``coefficients (m,)``."""

    mahalanobis: float
    residual: float
    distance: float
    outside: float
    coefficients: Tensor


class Forecast(NamedTuple):
    """:meth:`FourDTreeModel.forecast` (``m`` modes, ``n`` samples, ``len(times)`` requested times).

    * ``mean``: the 4D tree of the conditional mode at ``times`` (a :class:`TreeSequence`, data units).
    * ``samples``: ``n`` 4D trees drawn from the conditional Gaussian.
    * ``coefficients (m,)``, ``covariance (m, m)``: the conditional Gaussian of ``z``.
    * ``trajectory (len(times), k)``, ``sample_trajectories (n, len(times), k)``: tree-PCA coordinates at ``times``.
    * ``rate``: the observed part's time-rate factor found by the temporal alignment (of the conditional Gaussian).
    * ``gain``: the mean over the tree-PCA components of the share of the last observed frame's deviation from the
      4D mean carried into the forecast (``FourDTreeModel.forecast_gain``, per component).
    """

    mean: TreeSequence | None
    samples: list[TreeSequence]
    coefficients: Tensor
    covariance: Tensor
    trajectory: Tensor
    sample_trajectories: Tensor
    rate: float
    gain: float


class FourDTreeModel(nn.Module):
    """Generative model of 4D trees. Build with the settings, then :meth:`fit` (CPU), or :func:`torch4dtree.load`.

    Args:
        lambdas, rotation, n_t, tree_components, tree_variance, medoid_candidates, registration, positions,
            cross_lp: the tree space (:class:`~torch4dtree.temporal.population.Population`; ``positions`` and
            ``cross_lp`` are its cross-sequence registrations' settings).
        modes, mode_variance: the trajectory PCA (a fixed number of modes or the variance share kept).
        c: the sampler's truncation bound.
        mean_iters, temporal: the 4D Karcher mean's rounds and the temporal DP settings.
    """

    def __init__(self, lambdas: Sequence[float] = (1.0, 1.0, 1.0), rotation: str = "none", n_t: int = 32,
                 tree_components: int | None = None, tree_variance: float = 0.99, medoid_candidates: int = 3,
                 registration: dict[str, Any] | None = None, modes: int | None = None, mode_variance: float = 0.95,
                 c: float = 3.0, mean_iters: int = 10, temporal: dict[str, Any] | None = None,
                 positions: str = CROSS_POSITIONS, cross_lp: float | None = CROSS_LP) -> None:
        super().__init__()
        self.args = {"lambdas": [float(x) for x in lambdas], "rotation": rotation, "n_t": n_t,
                     "tree_components": tree_components, "tree_variance": tree_variance,
                     "medoid_candidates": medoid_candidates, "registration": dict(registration or {}),
                     "modes": modes, "mode_variance": mode_variance, "c": float(c), "mean_iters": mean_iters,
                     "temporal": dict(temporal or {}), "positions": positions, "cross_lp": cross_lp}
        self.population = Population(lambdas, rotation, n_t, tree_components, tree_variance, medoid_candidates,
                                     registration, positions, cross_lp)
        self.mean = TrajectoryMean(mean_iters, registration=temporal)
        self.pca = TrajectoryPCA(modes, mode_variance)
        self.sampler = TruncatedNormalSampler(1, c)
        self.register_buffer("time_start", torch.tensor(0.0, dtype=torch.float64))
        self.register_buffer("duration", torch.tensor(1.0, dtype=torch.float64))
        self.register_buffer("obs_noise", torch.tensor(1.0, dtype=torch.float64))
        self.register_buffer("forecast_gain", torch.tensor(0.0, dtype=torch.float64))  # (k,) once fitted
        self.report_: dict[str, Any] = {}

    # ------------------------------------------------------------------------ state
    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "report": self.report_}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise ValueError("not a FourDTreeModel state")
        self.report_ = dict(state["report"])

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        # the sampler's number of modes is a shape: take it from the saved state first
        extra = state_dict.get("sampler._extra_state")
        if isinstance(extra, dict) and "n_modes" in extra:
            self.sampler.n_modes = int(extra["n_modes"])
        if "forecast_gain" not in state_dict:  # checkpoints written before the gain existed: forecast the 4D mean
            state_dict = {**state_dict, "forecast_gain": torch.tensor(0.0, dtype=torch.float64)}
        # the gain is one scalar (checkpoints before the per-component gain) or (k,): a shape, taken from the state
        self.forecast_gain = torch.zeros_like(state_dict["forecast_gain"], dtype=torch.float64)
        out = super().load_state_dict(state_dict, strict, assign)
        # the population's saved settings win (a state saved before they existed was fitted with warped positions)
        self.args.update(positions=self.population.positions, cross_lp=self.population.cross_lp)
        return out

    @property
    def is_fitted(self) -> bool:
        return self.pca.n_modes > 0

    @property
    def n_modes(self) -> int:
        return self.pca.n_modes

    @property
    def n_t(self) -> int:
        return self.population.n_t

    def times(self) -> Tensor:
        """``(n_t,)`` the generated 4D trees' times in data units."""
        grid = torch.linspace(0, 1, self.n_t, dtype=torch.float64, device=self.duration.device)
        return self.time_start + grid * self.duration

    # ------------------------------------------------------------------------ fit
    def fit(self, sequences: Sequence[TreeSequence], progress: bool = False) -> FourDTreeModel:
        """Fit every stage on ``N >= 2`` 4D trees (CPU). Returns ``self``; diagnostics in ``report_``."""
        import time

        sequences = list(sequences)
        self.population.fit(sequences, progress)
        alpha = self.population.trajectories
        t0 = time.perf_counter()
        self.mean.fit(alpha)
        reg = self.mean.registered_
        t_mean = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.pca.fit(reg.registered[:, 0], reg.q_registered, center=flatten_srvf(self.mean.start, self.mean.q))
        t_pca = time.perf_counter() - t0
        self.sampler.n_modes = self.pca.n_modes
        spans = self.population.time_spans
        spread = float((alpha - self.mean.trajectory).square().sum(-1).mean())
        self.time_start.fill_(float(spans[:, 0].mean()))
        self.duration.fill_(float((spans[:, 1] - spans[:, 0]).mean()))
        z, residual = self.pca.project(reg.registered[:, 0], reg.q_registered)
        recon = self.pca.trajectories(z)
        unexplained = float((recon - reg.registered).square().sum(-1).mean())
        self.obs_noise.fill_(max(FORECAST_NOISE * spread, unexplained, 1e-12))
        t0 = time.perf_counter()
        calibration = self._calibrate_forecast(sequences[:FORECAST_CALIBRATION_PLANTS])
        self.forecast_gain = torch.tensor(calibration["gain"], dtype=torch.float64)
        t_forecast = time.perf_counter() - t0
        self.report_ = {
            "population": self.population.report_, "mean_energies": list(self.mean.energies_),
            "temporal_distance_before": [float(x) for x in reg.distance_before],
            "temporal_distance_after": [float(x) for x in reg.distance],
            "modes": self.pca.n_modes, "mode_variance": [float(x) for x in self.pca.explained_variance],
            "mode_variance_ratio": [float(x) for x in self.pca.explained_variance_ratio],
            "reconstruction_4d": [float(x) for x in residual],
            "reconstruction_trajectory_rms": [float(x) for x in (recon - reg.registered).square().sum(-1).mean(-1)
                                              .sqrt()],
            "forecast": calibration,
            "seconds": {**self.population.report_["seconds"], "mean": t_mean, "pca": t_pca,
                        "forecast_calibration": t_forecast},
        }
        return self

    def _mean_at_age(self, times: Tensor, first: Tensor | float) -> Tensor:
        """``(len(times), k)``: the 4D mean at the ages ``times - first`` (over the training plants' mean duration),
        the population's prediction for a plant first seen at ``first``."""
        u = ((times.to(torch.float64) - float(first)) / float(self.duration)).clamp(0, 1)
        return time_warp_trajectory(self.mean.trajectory, u.to(self.mean.trajectory))

    def _calibrate_forecast(self, sequences: Sequence[TreeSequence]) -> dict[str, Any]:
        """The forecast gains ``beta (k,)``, one per tree-PCA component, from training plants observed over their
        first half.

        Each plant gives its deviation from the 4D mean at the same age at its last observed frame as a forecast
        sees it, ``d`` (the first half encoded alone), and its later frames' deviations as the whole sequence
        encodes them (the fit's own frames), averaged over those frames, ``f``. Per component ``c``,
        ``beta_c = sum f_c d_c / sum d_c^2`` clipped to ``[0, 1]``: the least-squares share of the observed
        deviation that persists. One scalar gain did not work: a prefix's encoding differs from the same frame in
        its whole sequence (each slot is parameterised by the latest frame that holds it, and a young tree's layout
        matching differs: half of a young frame's branches land in other slots, synthetic tomato) by about as much
        as plants differ from the mean (issue 13), and that noise sits in other components than the part that
        persists.

        With a few training plants the per-component fit is itself noisy, so the gains are shrunk by the factor of
        ``FORECAST_SHRINK`` with the smallest leave-one-out error, 0 (the 4D mean) included
        (:func:`persistence_gains`).
        One encoding per plant (its first half). Keys: ``gain`` (k values), ``shrink``, ``loo_error`` (per factor,
        relative to the 4D mean's), ``plants``.
        """
        layout = self.population.layout_
        assert layout is not None, "called right after Population.fit (its training frames are not saved)"
        # the training frames as the fit wrote them (input order): the whole-sequence encodings, for free
        frames = self.population.pca.transform(layout).split([len(s) for s in self.population.sequences_])
        d_rows, f_rows = [], []
        for seq, whole in zip(sequences, frames):
            half = len(seq) // 2
            whole = whole.to(self.mean.trajectory)
            prefix = self.population.transform(seq[list(range(half))]).frame_coefficients.to(whole)
            mu = self._mean_at_age(seq.times, seq.times[0]).to(whole)  # (n, k)
            d_rows.append(prefix[-1] - mu[half - 1])
            f_rows.append(whole[half:] - mu[half:])
        gain, shrink, errors = persistence_gains(torch.stack(d_rows), f_rows)
        base = errors[FORECAST_SHRINK.index(0.0)]
        return {"gain": [float(x) for x in gain], "shrink": shrink,
                "loo_error": {str(x): e / base if base > 0 else 1.0 for x, e in zip(FORECAST_SHRINK, errors)},
                "plants": len(d_rows)}

    # ------------------------------------------------------------------------ generation
    def sample_coefficients(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """``(n, m)`` truncated standard normal coefficients."""
        self._check_fitted()
        return self.sampler(n, generator=generator, dtype=self.pca.mean.dtype)

    def trajectories(self, z: Tensor) -> Tensor:
        """``z (B, m) -> (B, n_t, k)`` tree-PCA trajectories (differentiable, batched)."""
        self._check_fitted()
        return self.pca.trajectories(z)

    def forward(self, z: Tensor) -> ModelOutput:
        """Dense, differentiable: ``z (B, m)`` -> :class:`ModelOutput` (trajectories and per-frame tree features)."""
        alpha = self.trajectories(z)
        feats = self.population.pca.inverse_features(alpha)
        return ModelOutput(alpha, feats, self.times().to(alpha.dtype))

    def decode_trajectories(self, alpha: Tensor, names: Sequence[str] | None = None) -> list[TreeSequence]:
        """``alpha (B, n_t, k)`` -> ``B`` :class:`TreeSequence` s at :meth:`times` (``label`` = layout slot)."""
        if alpha.dim() != 3:
            raise ValueError(f"alpha must be (B, n_t, k), got {tuple(alpha.shape)}")
        B, n_t, k = alpha.shape
        trees = self.population.pca.decode(alpha.detach().reshape(B * n_t, k))
        times = self.times().to(trees.dtype)
        names = [f"sample_{i:03d}" for i in range(B)] if names is None else list(names)
        return [TreeSequence(trees[list(range(i * n_t, (i + 1) * n_t))], times, names[i]) for i in range(B)]

    def decode(self, z: Tensor) -> list[TreeSequence]:
        """``z (B, m)`` (or ``(m,)``) -> ``B`` 4D trees."""
        zz = z[None] if z.dim() == 1 else z
        return self.decode_trajectories(self.trajectories(zz))

    def sample(self, n: int, generator: torch.Generator | None = None) -> list[TreeSequence]:
        """``n`` new 4D trees (times in data units): truncated normal coefficients, decoded."""
        return self.decode(self.sample_coefficients(n, generator))

    def modes(self, taus: Sequence[float] = (-2.0, -1.0, 0.0, 1.0, 2.0), modes: int = 3) -> list[list[TreeSequence]]:
        """The first ``modes`` modes at ``taus`` standard deviations, decoded: ``[mode][tau]``."""
        alpha = self.pca.modes(torch.tensor(list(taus), dtype=torch.float64), modes)
        return [self.decode_trajectories(a, [f"mode{i + 1}_{t:+.1f}sd" for t in taus]) for i, a in enumerate(alpha)]

    # ------------------------------------------------------------------------ analysis
    def _check_fitted(self) -> None:
        if not self.is_fitted:
            from ..space.fitted import NotFittedError

            raise NotFittedError("FourDTreeModel is not fitted: call fit() or torch4dtree.load()")

    def encode(self, sequence: TreeSequence) -> Tensor:
        """A 4D tree's standardised mode coefficients ``(m,)`` (tree space, time warp onto the mean, projection)."""
        return self.score(sequence).coefficients

    def score(self, sequence: TreeSequence) -> Score:
        """Typicality of a 4D tree (:class:`Score`): large ``mahalanobis`` or ``residual`` flag abnormal growth."""
        self._check_fitted()
        enc = self.population.transform(sequence)
        reg = self.mean.register(enc.trajectory[None])
        z, residual = self.pca.project(reg.registered[:, 0], reg.q_registered)
        outside = float(enc.dropped_sq_norm.mean().sqrt())
        return Score(float(z.norm()), float(residual[0]), float(reg.distance[0]), outside, z[0])

    def forecast(self, partial: TreeSequence, times: Sequence[float] | Tensor, n: int = 0,
                 generator: torch.Generator | None = None, decode: bool = True) -> Forecast:
        """Complete a 4D tree observed over its first frames at ``times`` (data units).

        The observed frames are written in the tree space (per-frame coordinates ``y_j`` at times ``t_j``, the last
        one ``y_L``). The forecast (``trajectory``, ``mean``) is the 4D mean at the plant's age plus the share
        ``beta (k,)`` (``forecast_gain``, per tree-PCA component, calibrated at :meth:`fit`) of the plant's deviation
        from it at its last observed frame::

            x(t) = mu(t - t_0) + beta * (y_L - mu(t_L - t_0))

        (``mu`` the 4D mean at an age over the training trees' mean duration ``D``, ``t_0`` the first observed
        time): what of the plants' own deviation persisted in the training plants, in the components where it did,
        shrunk by leave-one-out (:meth:`_calibrate_forecast`). Conditioning the modes instead lost to the mean at the
        same age with 7 training plants (issue 13: the modes of a few plants carry little of a new plant's future).

        Uncertainty: the conditional Gaussian of the mode coefficients given the observed part. The observed times
        are aligned onto the model's normalised time by ``u = r (t - t_0) / D`` (the rate ``r`` the best of
        ``FORECAST_RATES``); linearising the model's trajectory, ``y_j = alpha_z(u_j) + noise`` with
        ``z ~ N(0, I)`` gives a Gaussian posterior of ``z`` (Gauss-Newton for its mode ``z*``, its Laplace
        covariance). Each of the ``n`` samples ``z_s`` is the forecast plus ``alpha_{z_s} - alpha_{z*}``.
        """
        self._check_fitted()
        enc = self.population.transform(partial)
        y = enc.frame_coefficients.to(self.pca.mean)
        t_obs = enc.times.to(torch.float64)
        t_out = torch.as_tensor(times, dtype=torch.float64).reshape(-1)
        D = float(self.duration)
        best = None
        for r in FORECAST_RATES:
            u = ((t_obs - t_obs[0]) * r / D).clamp(0, 1)
            z, cov, energy = self._condition(y, u)
            energy += (math.log(r) / FORECAST_RATE_SPREAD) ** 2
            if best is None or energy < best[0]:
                best = (energy, r, z, cov)
        assert best is not None
        _, r, z, cov = best
        u_out = ((t_out - t_obs[0]) * r / D).clamp(0, 1)
        beta = self.forecast_gain.to(y)  # (k,), or () from a checkpoint before the per-component gain
        gain = float(beta.mean())
        traj = self._mean_at_age(t_out, t_obs[0]).to(y)
        traj = traj + beta * (y[-1] - self._mean_at_age(t_obs[-1:], t_obs[0]).to(y))  # (len(times), k)
        s_traj = z.new_zeros(0, len(t_out), traj.shape[-1])
        if n > 0:
            L = torch.linalg.cholesky(cov + 1e-12 * torch.eye(cov.shape[0], dtype=cov.dtype))
            eps = torch.randn(n, z.shape[0], generator=generator, dtype=torch.float64)
            samples_z = torch.cat([z[None], z + eps.to(z) @ L.T])
            spread = time_warp_trajectory(self.trajectories(samples_z), u_out.to(z))  # (1 + n, len(times), k)
            s_traj = traj + (spread[1:] - spread[:1])
        mean_seq, seqs = None, []
        if decode:
            pca = self.population.pca
            mean_seq = TreeSequence(pca.decode(traj.detach()), t_out.to(pca.mean.dtype), f"{partial.name}_forecast")
            seqs = [TreeSequence(pca.decode(a.detach()), t_out.to(pca.mean.dtype), f"{partial.name}_forecast_{i:03d}")
                    for i, a in enumerate(s_traj)]
        return Forecast(mean_seq, seqs, z.detach(), cov.detach(), traj.detach(), s_traj.detach(), r, gain)

    def _condition(self, y: Tensor, u: Tensor) -> tuple[Tensor, Tensor, float]:
        """Gaussian posterior of ``z`` given coordinates ``y (n_obs, k)`` at normalised times ``u (n_obs,)``."""
        m = self.n_modes
        s2 = float(self.obs_noise)
        uu = u.to(y)

        def predict(zz: Tensor) -> Tensor:
            return time_warp_trajectory(self.trajectories(zz[None])[0], uu).reshape(-1)

        z = y.new_zeros(m)
        eye = torch.eye(m, dtype=y.dtype, device=y.device)
        target = y.reshape(-1)
        for _ in range(FORECAST_STEPS):
            J = torch.autograd.functional.jacobian(predict, z, vectorize=True)  # (n_obs * k, m)
            res = target - predict(z)
            H = J.T @ J / s2 + eye
            z = z + torch.linalg.solve(H, J.T @ res / s2 - z)
        J = torch.autograd.functional.jacobian(predict, z, vectorize=True)
        H = J.T @ J / s2 + eye
        energy = float((target - predict(z)).square().sum() / s2 + z.square().sum())
        return z.detach(), torch.linalg.inv(H), energy

    # ------------------------------------------------------------------------ checkpoints
    def save(self, path: str, config: dict[str, Any] | None = None, overwrite: bool = False) -> str:
        """Write a checkpoint (:func:`torch4dtree.model.save_model`)."""
        from .checkpoint import save_model

        return str(save_model(self, path, config, overwrite=overwrite))


def persistence_gains(d: Tensor, f: Sequence[Tensor], shrinks: Sequence[float] = FORECAST_SHRINK
                      ) -> tuple[Tensor, float, list[float]]:
    """Per-component gains of deviations that persist, shrunk by leave-one-out (:meth:`FourDTreeModel.forecast`).

    Args:
        d: ``(N, k)`` each plant's observed deviation (from the 4D mean, at its last observed frame).
        f: ``N`` tensors ``(n_i, k)``: each plant's later deviations.
        shrinks: candidate factors (include 0: the gains can vanish where nothing persists).

    Returns:
        ``gain (k,)`` = the factor times ``beta_c = sum_i mean_j f_ijc d_ic / sum_i d_ic^2`` clipped to ``[0, 1]``;
        the factor, the one with the smallest leave-one-out error (plant ``i`` forecast by the others' ``beta``,
        error = mean over its later frames of the distance ``|f_ij - x beta d_i|``; ties to the smaller factor);
        and those errors per factor. With fewer than 2 plants the factor is 0.
    """
    f_mean = torch.stack([x.mean(0) for x in f])  # (N, k)

    def beta(rows: list[int]) -> Tensor:
        return ((f_mean[rows] * d[rows]).sum(0) / d[rows].square().sum(0).clamp_min(1e-300)).clamp(0, 1)

    n = d.shape[0]
    held = [beta([j for j in range(n) if j != i]) for i in range(n)] if n >= 2 else []
    errors = [sum(float((f[i] - x * held[i] * d[i]).norm(dim=-1).mean()) for i in range(len(held)))
              for x in shrinks]
    # ties (one plant, or no deviation at all) go to the smaller factor: the 4D mean unless the plants show better
    best = min(range(len(shrinks)), key=lambda j: (errors[j], shrinks[j]))
    x = float(shrinks[best]) if held else 0.0
    return x * beta(list(range(n))), x, errors


def sequence_validity(seq: TreeSequence | Trees, tol: float = 1e-6) -> list[str]:
    """Problems of decoded trees (empty if valid): non-finite points, a child off its parent, negative ``s``."""
    trees = seq.frames if isinstance(seq, TreeSequence) else seq
    out = []
    if not bool(torch.isfinite(trees.points).all()):
        out.append("non-finite points")
    if bool((trees.s < 0).any()) or bool((trees.s > 1).any()):
        out.append("s outside [0, 1]")
    gp = trees.global_parent
    child = gp >= 0
    if bool(child.any()):
        att = trees.attachment_points()[child]  # where each child should start on its parent (arc-length s)
        scale = float(trees.points.abs().max()) + 1.0
        gap = (att - trees.points[child, 0]).norm(dim=-1)
        if bool((gap > tol * scale).any()):
            out.append(f"{int((gap > tol * scale).sum())} children off their parent (max gap {float(gap.max()):.3g})")
    if not math.isfinite(float(trees.branch_lengths().sum())):
        out.append("non-finite lengths")
    return out
