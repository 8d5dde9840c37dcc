"""The generative model of 4D trees (docs/method.md §5, paper §4.2 / §5.3): tree space, 4D mean and modes, sampler.

``FourDTreeModel`` bundles the fitted pipeline:

    4D trees -> Population (one layout, tree PCA, trajectories in R^k) -> TrajectoryMean (temporal Karcher mean)
      -> TrajectoryPCA (modes of the registered SRVFs) ;  TruncatedNormalSampler -> z -> trajectories -> trees

Coefficients ``z (B, m)`` are standardised mode coordinates. ``model(z)`` is differentiable (dense tensors);
:meth:`decode` turns them into :class:`TreeSequence` s (a separate, slower step: skeleton integration per frame).
Times of generated 4D trees are in the data's units: the training trees' mean first time plus the normalised
grid times the mean duration.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from concurrent.futures import Executor
from typing import Any, NamedTuple

import torch
from torch import Tensor, nn

from ..parallel import move, run_tasks
from ..settings import ModelSettings
from ..space.fitted import NotFittedError
from ..space.pca import principal_axes, variance_components
from ..temporal.population import Population
from ..temporal.registration import time_warp_trajectory
from ..trees.structures import Trees, TreeSequence
from .sampler import TruncatedNormalSampler
from .trajectory import TrajectoryMean, TrajectoryPCA, flatten_srvf

__all__ = ["ENCODE_CHUNK", "FourDTreeModel", "Forecast", "ModelOutput", "Score", "encode_sequences",
           "persistence_betas", "persistence_gains"]

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
# forecast analogue term: widths of the kernel on the registered distance from the plant's last observed frame to each
# training plant at that age, in units of the median squared distance between training plants (1e6: equal weights);
# narrower widths put all weight on one plant (docs/experiments.md)
FORECAST_WIDTHS = (0.2, 0.5, 1.0, 2.0, 1e6)
# plants a task of encode_many: an executor without scatter ships the fitted model with each task, so a few plants
# amortise it
ENCODE_CHUNK = 8


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
        settings: the tree space (:class:`~torch4dtree.temporal.population.Population`: ``lambdas``, ``rotation``,
            ``n_t``, ``tree_components`` / ``tree_variance``, ``medoid_candidates``, ``registration``, ``cross``,
            ``max_slots``),
            the 4D Karcher mean (``mean_iters``, ``temporal``), the trajectory PCA (``modes`` / ``mode_variance``)
            and the sampler's bound ``c``; default :class:`~torch4dtree.settings.ModelSettings`'s.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> from torch4dtree.settings import ModelSettings
        >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(3)]
        >>> model = FourDTreeModel(ModelSettings(n_t=4, medoid_candidates=1)).fit(plants)
        >>> z = model.encode(plants[0])
        >>> z.shape == (model.n_modes,)
        True
        >>> out = model(z[None])
        >>> len(model.decode(z[None])), len(model.sample(2, torch.Generator().manual_seed(0)))
        (1, 2)
    """

    def __init__(self, settings: ModelSettings | None = None) -> None:
        super().__init__()
        if settings is not None and not isinstance(settings, ModelSettings):
            raise TypeError(f"settings must be a ModelSettings, got {type(settings).__name__}")
        self.settings = s = settings or ModelSettings()
        self.population = Population(s.lambdas, s.rotation, s.n_t, s.tree_components, s.tree_variance,
                                     s.medoid_candidates, s.registration, s.cross, s.max_slots)
        self.mean = TrajectoryMean(s.mean_iters, registration=s.temporal)
        self.pca = TrajectoryPCA(s.modes, s.mode_variance)
        self.sampler = TruncatedNormalSampler(1, s.c)
        self.register_buffer("time_start", torch.tensor(0.0, dtype=torch.float64))
        self.register_buffer("duration", torch.tensor(1.0, dtype=torch.float64))
        self.register_buffer("obs_noise", torch.tensor(1.0, dtype=torch.float64))
        self.register_buffer("forecast_gain", torch.tensor(0.0, dtype=torch.float64))  # (k,) once fitted
        # the analogue term's (kernel width, weight, squared distance of the 4D mean's pseudo-plant): weight 0 leaves
        # it out
        self.register_buffer("forecast_analogue", torch.zeros(3, dtype=torch.float64))
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
        if "forecast_analogue" not in state_dict:  # checkpoints written before the analogue term: without it
            state_dict = {**state_dict, "forecast_analogue": torch.zeros(3, dtype=torch.float64)}
        # the gain is one scalar (checkpoints before the per-component gain) or (k,): a shape, taken from the state
        self.forecast_gain = torch.zeros_like(state_dict["forecast_gain"], dtype=torch.float64)
        out = super().load_state_dict(state_dict, strict, assign)
        # the population's saved cross settings win (a state without them was fitted with warped positions, the
        # space's lp, children in any order)
        cross = dataclasses.replace(self.settings.cross, positions=self.population.cross.positions,
                                    lp=self.population.cross.lp, order_tol=self.population.cross.order_tol)
        self.settings = dataclasses.replace(self.settings, cross=cross)
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
    def fit(self, sequences: Sequence[TreeSequence], progress: bool = False, executor: Executor | None = None
            ) -> FourDTreeModel:
        """Fit every stage on ``N >= 2`` 4D trees (CPU). Returns ``self``; diagnostics in ``report_``.
        ``executor``: where the population's registrations run (:meth:`Population.fit`); the result does not
        depend on it."""
        import time

        sequences = list(sequences)
        self.population.fit(sequences, progress, executor)
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
        self.forecast_analogue = torch.tensor([calibration["width"], calibration["analogue"], calibration["null"]],
                                              dtype=torch.float64)
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

    def _training_at_age(self, ages: Tensor) -> Tensor:
        """``(N, len(ages), k)``: every training plant's trajectory at the ages (time since its first frame)."""
        traj = self.population.trajectories.to(torch.float64)
        spans = self.population.time_spans.to(traj)
        u = (ages.to(traj)[None] / (spans[:, 1:] - spans[:, :1]).clamp_min(1e-12)).clamp(0, 1)
        return time_warp_trajectory(traj, u)

    def _analogue_distances(self, frame: Trees, age: float, exclude: int | None = None) -> Tensor:
        """``(N,)``: the registered tree distance of one frame to each training plant at the frame's age (decoded
        from its trajectory; ``inf`` at ``exclude``). A registration needs no slot assignment of the young frame,
        which is what makes its encoding noisy (:meth:`_calibrate_forecast`)."""
        pop = self.population
        refs = pop.pca.decode(self._training_at_age(torch.tensor([age], dtype=torch.float64))[:, 0])
        out = torch.full((refs.num_trees,), math.inf, dtype=torch.float64)
        for j in range(refs.num_trees):
            if j != exclude:
                reg = pop.registration.register(frame.to(dtype=torch.float64), refs[j], pop.cross_lambdas_,
                                                pop.rotation, positions=pop.cross.positions, order_tol=None,
                                                lp_relative=False, symmetric=False)[0]
                out[j] = float(reg.distance)
        return out

    def _analogue(self, distances: Tensor, ages: Tensor, width: float, null: float) -> Tensor:
        """``(len(ages), k)``: the training plants' own deviations from the 4D mean at the ages, averaged with weights
        ``exp(-distance^2 / width)`` beside a pseudo-plant at squared distance ``null`` that keeps the 4D mean
        (deviation 0; normalised; ``inf`` distances weigh 0). The pseudo-plant shrinks the term where no training
        plant is near (a kernel regression with a prior at the mean)."""
        d2 = torch.cat([distances.to(torch.float64).square(), distances.new_tensor([null], dtype=torch.float64)])
        w = torch.softmax((-d2 / max(width, 1e-300)).masked_fill(~torch.isfinite(d2), -math.inf), 0)[:-1]
        ages = ages.to(torch.float64)
        dev = self._training_at_age(ages) - self._mean_at_age(ages, 0.0)  # (N, len(ages), k)
        return (w[:, None, None] * dev).sum(0)

    def _calibrate_forecast(self, sequences: Sequence[TreeSequence]) -> dict[str, Any]:
        """The forecast's two terms (:meth:`forecast`), chosen by leave-one-out over training plants observed over
        their first half: the gains ``beta (k,)`` of the plant's own last observed deviation from the 4D mean, and
        the width and weight of the analogue term.

        **Each left-out plant is written as a new plant would be.** A training plant's frames lie in the span of the
        tree PCA, which it helped fit; a new plant's are projected onto it and lose what no training plant had, so a new
        plant's later frames sit closer to the 4D mean and in-sample deviations over-promise. Plant ``i``'s features
        (its first half encoded alone, and its later frames as its whole sequence wrote them) are therefore projected
        onto the principal subspace of the *other* plants' frames (the same variance share or number of components as
        the fit) before they are written in the model's coordinates.

        * Gains: per component ``beta_c = sum f_c d_c / sum d_c^2`` clipped to ``[0, 1]`` (:func:`persistence_betas`:
          ``d`` the observed deviation at the last observed frame, ``f`` the later ones; plant ``i`` forecast with
          the others' ``beta``). A prefix's encoding differs from the same frames in the whole sequence (each slot
          is parameterised by the latest frame that holds it, and half of a young tomato's branches land in other
          slots) by about as much as plants differ from the mean, so the gains stay small there.
        * Analogue: the other plants' own later deviations, weighted by the registered distance of plant ``i``'s
          last observed frame to each of them at that age (:meth:`_analogue`), widths ``FORECAST_WIDTHS``, beside
          the 4D mean's pseudo-plant at the median distance between training plants (``null``, squared).

        The shrink factors ``b`` (of the gains) and ``a`` (of the analogue) from ``FORECAST_SHRINK`` and the width
        minimise the summed left-out error ``mean_j |f_ij - a K_ij - b beta_(-i) d_i|``, ties to the smaller
        factors (0, 0 is the 4D mean). Cost: one encoding per plant and ``N - 1`` tree registrations. Keys:
        ``gain`` (``b beta``, k values), ``shrink`` (``b``), ``analogue`` (``a``), ``width`` (absolute), ``null``,
        ``loo_error`` (of the chosen width, per ``a`` then ``b``, relative to the 4D mean's), ``plants``.
        """
        layout = self.population.layout_
        if layout is None:
            raise NotFittedError("the forecast is calibrated right after Population.fit (its training frames are "
                                 "not saved)")
        pca = self.population.pca
        feats = layout.features().detach().to(torch.float64)
        counts = [len(s) for s in self.population.sequences_]
        owner = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
        first = [sum(counts[:i]) for i in range(len(counts))]

        def coords(x: Tensor) -> Tensor:
            return (x - pca.mean.to(x)) @ pca.components.to(x).T

        d_rows, f_rows, dist_rows, ages_rows = [], [], [], []
        for i, seq in enumerate(sequences):
            half = len(seq) // 2
            seq = seq.to(torch.float64)
            prefix = self.population.transform(seq[list(range(half))]).aligned.features().to(feats)
            project = _subspace_projector(feats[owner != i], pca.n_components, pca.variance)
            t = seq.times.to(torch.float64)
            mu = self._mean_at_age(t, t[0]).to(feats)  # (n, k)
            d_rows.append(coords(project(prefix[-1])) - mu[half - 1])
            f_rows.append(coords(project(feats[first[i] + half:first[i] + counts[i]])) - mu[half:])
            age = float(t[half - 1] - t[0])
            dist_rows.append(self._analogue_distances(seq.frames[half - 1], age, exclude=i))
            ages_rows.append(t[half:] - t[0])
        n = len(d_rows)
        d = torch.stack(d_rows)
        beta, held = persistence_betas(d, f_rows)
        finite = torch.cat([x[torch.isfinite(x)] for x in dist_rows])
        scale = float(finite.square().median()) if len(finite) else 1.0
        zero = sum(float(f.norm(dim=-1).mean()) for f in f_rows)
        G = [held[i] * d[i] for i in range(len(held))]
        candidates = []  # (left-out error, a + b, a, width, b, error table of the width)
        for rel in FORECAST_WIDTHS:
            width = rel * scale
            K = [self._analogue(dist_rows[i], ages_rows[i], width, scale).to(feats) for i in range(len(held))]
            table = [[sum(float((f_rows[i] - a * K[i] - b * G[i]).norm(dim=-1).mean()) for i in range(len(held)))
                      for b in FORECAST_SHRINK] for a in FORECAST_SHRINK]
            candidates += [(table[ia][ib], a + b, a, width, b, table) for ia, a in enumerate(FORECAST_SHRINK)
                           for ib, b in enumerate(FORECAST_SHRINK)]
        # ties go to the smaller factors, then the narrower width: the 4D mean unless the plants show better
        _, _, a, width, b, table = min(candidates, key=lambda c: c[:4]) if held else (0, 0, 0.0, 0.0, 0.0, [])
        return {"gain": [float(x) for x in b * beta], "shrink": b, "analogue": a, "width": width, "null": scale,
                "loo_error": [[e / zero if zero > 0 else 1.0 for e in row] for row in table], "plants": n}

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
            raise NotFittedError("FourDTreeModel is not fitted: call fit() or torch4dtree.load()")

    def encode(self, sequence: TreeSequence) -> Tensor:
        """A 4D tree's standardised mode coefficients ``(m,)`` (tree space, time warp onto the mean, projection)."""
        return self.score(sequence).coefficients

    def portable(self) -> FourDTreeModel:
        """A copy on the CPU holding only the fitted state (what a checkpoint holds, not the training layout):
        what is shipped to workers (:meth:`encode_many`)."""
        self._check_fitted()
        copy = FourDTreeModel(self.settings)
        copy.load_state_dict(move(self.state_dict(), "cpu"))
        return copy

    def encode_many(self, sequences: Sequence[TreeSequence], executor: Executor | None = None) -> Tensor:
        """``(N, m)``: :meth:`encode` of every 4D tree of ``sequences``; on ``executor`` in tasks of
        ``ENCODE_CHUNK`` plants, :meth:`portable` packed once and unpacked once per worker (sent once to each
        worker on Dask; :func:`~torch4dtree.parallel.run_tasks`' ``shared``); the same numbers as :meth:`encode`.

        Example:
            >>> from torch4dtree.data import synthetic_plant
            >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(3)]
            >>> model = FourDTreeModel(ModelSettings(n_t=4, medoid_candidates=1)).fit(plants)
            >>> model.encode_many(plants).shape[0]
            3
        """
        self._check_fitted()
        seqs = list(sequences)
        if executor is None:
            rows = [self.encode(s) for s in seqs]
        else:
            chunks = [(seqs[i:i + ENCODE_CHUNK],) for i in range(0, len(seqs), ENCODE_CHUNK)]
            rows = [z for part in run_tasks(encode_sequences, chunks, executor, self.duration.device,
                                            shared=self.portable()) for z in part]
        return torch.stack(rows) if rows else self.duration.new_zeros(0, self.pca.n_modes)

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
        one ``y_L``). The forecast (``trajectory``, ``mean``) is the 4D mean at the plant's age plus two terms
        calibrated at :meth:`fit` (:meth:`_calibrate_forecast`)::

            x(t) = mu(t - t_0) + beta * (y_L - mu(t_L - t_0)) + a * sum_i w_i (alpha_i(t - t_0) - mu(t - t_0))

        (``mu`` the 4D mean at an age over the training trees' mean duration ``D``, ``t_0`` the first observed
        time, ``alpha_i`` training plant ``i``'s trajectory at an age):

        * the share ``beta (k,)`` (``forecast_gain``, per tree-PCA component) of the plant's own deviation at its
          last observed frame: what of it persisted in the training plants, where it did;
        * the *analogue* term (``forecast_analogue`` = width, ``a``, ``null``): the training plants' own later
          deviations, weighted ``w_i ~ exp(-d_i^2 / width)`` by the registered tree distance ``d_i`` of the last
          observed frame to plant ``i`` at that age, beside a pseudo-plant at squared distance ``null`` that keeps
          the 4D mean. A registration needs no slot assignment, which is what makes a young plant's encoding ``y_L``
          noisy (a young plant's branches can land in other slots than in its whole sequence). Costs ``N`` tree
          registrations per forecast (skipped where ``a = 0``).
        Both are shrunk by leave-one-out (0, the 4D mean alone, allowed). Conditioning the modes instead lost to the
        mean at the same age with 7 training plants (the modes of a few plants carry little of a new plant's future).

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
        fits = []
        for r in FORECAST_RATES:
            u = ((t_obs - t_obs[0]) * r / D).clamp(0, 1)
            z, cov, energy = self._condition(y, u)
            fits.append((energy + (math.log(r) / FORECAST_RATE_SPREAD) ** 2, r, z, cov))
        _, r, z, cov = min(fits, key=lambda x: x[0])
        u_out = ((t_out - t_obs[0]) * r / D).clamp(0, 1)
        beta = self.forecast_gain.to(y)  # (k,), or () from a checkpoint before the per-component gain
        gain = float(beta.mean())
        traj = self._mean_at_age(t_out, t_obs[0]).to(y)
        traj = traj + beta * (y[-1] - self._mean_at_age(t_obs[-1:], t_obs[0]).to(y))  # (len(times), k)
        width, weight, null = (float(x) for x in self.forecast_analogue)
        if weight > 0:
            last = partial.to(torch.float64).frames[len(partial) - 1]
            dist = self._analogue_distances(last, float(t_obs[-1] - t_obs[0]))
            traj = traj + weight * self._analogue(dist, t_out - t_obs[0], width, null).to(y)
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
        # forward mode: m input columns against n_obs * k output rows (a maize forecast, 10-plant fold: 42.9 -> 3.6 s)
        for _ in range(FORECAST_STEPS):
            J = torch.autograd.functional.jacobian(predict, z, vectorize=True, strategy="forward-mode")  # (n_obs k, m)
            res = target - predict(z)
            H = J.T @ J / s2 + eye
            z = z + torch.linalg.solve(H, J.T @ res / s2 - z)
        J = torch.autograd.functional.jacobian(predict, z, vectorize=True, strategy="forward-mode")
        H = J.T @ J / s2 + eye
        energy = float((target - predict(z)).square().sum() / s2 + z.square().sum())
        return z.detach(), torch.linalg.inv(H), energy

    # ------------------------------------------------------------------------ checkpoints
    def save(self, path: str, config: dict[str, Any] | None = None, overwrite: bool = False) -> str:
        """Write a checkpoint (:func:`torch4dtree.model.save_model`)."""
        from .checkpoint import save_model

        return str(save_model(self, path, config, overwrite=overwrite))


def encode_sequences(model: FourDTreeModel, sequences: Sequence[TreeSequence]) -> list[Tensor]:
    """``[model.encode(s) for s in sequences]`` (a task of :meth:`FourDTreeModel.encode_many`: top-level)."""
    return [model.encode(s) for s in sequences]


def persistence_betas(d: Tensor, f: Sequence[Tensor]) -> tuple[Tensor, list[Tensor]]:
    """Per-component gains of deviations that persist: ``beta_c = sum_i mean_j f_ijc d_ic / sum_i d_ic^2`` clipped
    to ``[0, 1]`` (``d (N, k)`` each plant's observed deviation, ``f`` ``N`` tensors ``(n_i, k)`` its later ones).
    Returns the gains of all plants and, for each plant (if ``N >= 2``), those of the others."""
    f_mean = torch.stack([x.mean(0) for x in f])  # (N, k)

    def beta(rows: list[int]) -> Tensor:
        return ((f_mean[rows] * d[rows]).sum(0) / d[rows].square().sum(0).clamp_min(1e-300)).clamp(0, 1)

    n = d.shape[0]
    held = [beta([j for j in range(n) if j != i]) for i in range(n)] if n >= 2 else []
    return beta(list(range(n))), held


def persistence_gains(d: Tensor, f: Sequence[Tensor], shrinks: Sequence[float] = FORECAST_SHRINK
                      ) -> tuple[Tensor, float, list[float]]:
    """:func:`persistence_betas` shrunk by leave-one-out (the gains alone, without the analogue term).

    Returns:
        ``gain (k,)`` = the factor times ``beta``; the factor, the one with the smallest leave-one-out error (plant
        ``i`` forecast by the others' ``beta``, error = mean over its later frames of the distance
        ``|f_ij - x beta d_i|``; ties to the smaller factor); and those errors per factor. With fewer than 2
        plants the factor is 0.
    """
    beta, held = persistence_betas(d, f)
    errors = [sum(float((f[i] - x * held[i] * d[i]).norm(dim=-1).mean()) for i in range(len(held)))
              for x in shrinks]
    # ties (one plant, or no deviation at all) go to the smaller factor: the 4D mean unless the plants show better
    best = min(range(len(shrinks)), key=lambda j: (errors[j], shrinks[j]))
    x = float(shrinks[best]) if held else 0.0
    return x * beta, x, errors


def _subspace_projector(x: Tensor, n_components: int | None, variance: float) -> Any:
    """The orthogonal projection onto the affine principal subspace of the rows of ``x`` (``n_components`` of them,
    or the fewest reaching ``variance`` of the variance, as :class:`TreePCA` keeps), as a function of ``(..., F)``."""
    mean = x.mean(0)
    sing, vh = principal_axes(x - mean)
    var = sing.square()
    k = min(n_components, len(var)) if n_components is not None else variance_components(var, variance)
    basis = vh[:k]
    return lambda y: mean + (y - mean) @ basis.T @ basis


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
