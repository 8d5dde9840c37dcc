"""The generative model's quality (beyond the paper, which only shows pictures): held-out plants, baselines.

Per kind of plant, the plants are split into folds; each fold is held out once and a :class:`FourDTreeModel` (the
paper's model; ``settings``: ``lambdas``, ``rotation``, ``n_t``) and an :class:`OrganModel` are fit on the others.
Everything is measured in that fold's paper model's layout.

**Ground metric.** Every 4D plant is a trajectory of coordinates in which Euclidean distances are the tree
distances of the fold's slot layout, on the normalised time grid (``n_t``): the model's tree-PCA coefficients,
extended by an orthonormal basis of what the tree PCA cannot express of the held-out frames. The extension matters:
fit on 2-4 plants, the tree PCA spans few directions, and the held-out frames' projections on it alone sit much
closer to the 4D mean than the plants are (5 synthetic tomatoes, 3 fit: held-out plants 7.4 from the mean
projected, 12.7 in the layout, training plants 12.8; Pheno4D tomato: 77 % of the held-out frames' spread is off the
tree PCA), which would reward generators that stay near the mean. Held-out plants are
written in the layout by ``model.population.transform`` (their frames resampled on the grid, as the population
does); samples are ``model.trajectories(z)`` and training plants the population's trajectories, both with zeros in
the extension (the model cannot leave its tree PCA; training frames keep ``tree_variance`` of theirs). The distance
of two trajectories is the **4D distance after temporal registration**, the smaller of both directions
(:func:`~torch4dtree.evaluate.generative_metrics.distance4d`). Branches of a held-out plant that match
no slot of the layout cannot be written in it and are dropped: their cost is reported (``outside``, the root mean
square over frames of the tree distance they carry, as ``FourDTreeModel.score().outside``; ``outside_share``, their
share of the frames' squared norm), as is the part off the tree PCA (``off_tree_space``, ``off_tree_space_share`` of
the frames' squared spread about the tree mean).

**Split** (:mod:`~torch4dtree.evaluate.generative_split`; settings ``heldout``, ``folds``, ``morpho_draws`` of
:class:`~torch4dtree.evaluate.data.EvalSettings`): per kind, a seeded permutation
(``settings.generator``) of the plants is cut into ``min(N // 2, folds)`` near-equal folds (``folds`` 3 by default,
2 for the fit-on-20 / 20-held-out protocol on 40 plants), so every plant is held out exactly once and every held-out
set has at least 2 plants (COV and 1-NNA are meaningless with one); or, with ``heldout`` (a folder), the data
folder's plants are fit and the held-out folder's plants held out, one fold. ``quick``: only the fold with the
largest training set. Kinds with fewer than 4 plants (2 a side) are skipped. Pheno4D ``mat``: tomato 5 plants ->
folds of 3 and 2 held out (training on 2 and 3), maize 4 -> 2 and 2 (training on 2: one mode). With so few plants
the numbers are a coarse sanity check: they can show a generator that collapses (the 4D mean), one that memorises,
or samples that are far from every real plant; they cannot rank close generators (a held-out set of 2 gives COV in
{0, 1/2, 1} per draw) and say nothing about plants unlike the 5 tomatoes / 4 maize. Only one source is evaluated:
``mat`` if present, else ``synthetic``, else ``swc`` (a second source would at least double the section's time, and
the raw SWC skeletons are larger).

**The organ model** (:class:`~torch4dtree.model.OrganModel`, the default of ``fit``; fit on the same training
plants) has no tree space of its own: its samples are written in the fold's layout as the held-out plants are
(``population.transform``; :mod:`~torch4dtree.evaluate.generative_organs`), and so are the training plants for its
reference row ``memorise_encoded`` ("a training plant at random" through the same encoding). The extension's basis
spans what the tree PCA misses of all these frames. Its pool is ``max(h, MORPHO_SAMPLES)`` samples per fold, each
draw ``h`` of them without replacement; its novelty is measured against the encoded training plants. Beside it:
the share of held-out squared SRVF norm at botanical keys no training plant had (``outside_keys_share``), organs
shrinking / vanishing between frames (its samples, the paper model's, training and held-out plants) and its
forecast of the second half (:func:`~torch4dtree.model.organ_forecast.forecast_organs`; its point
:func:`~torch4dtree.model.organ_forecast.forecast_point` of ``FORECAST_DRAWS`` continuations in the layout with the
encoded training plants' average as the prior, their plain mean and one continuation's error beside it) against "the
last observed frame stays" and the 4D mean.

**Generators** (each draw: as many samples as held-out plants, the usual equal-size protocol; ``DRAWS = 50`` draws
per fold, 4 when ``quick``; metrics per draw, summarised over all draws of all folds):

* ``organs``, ``memorise_encoded``: above;
* ``model``: the paper model's sampler (independent truncated standard normal coefficients, ``c = 3``);
* ``memorise``: a training plant at random, each sample drawn independently (with replacement, as every
  generator's samples are independent: :func:`training_draws`) - the memorising generator;
* ``paper_scalar``: the authors' synthesis script: one scalar uniform in ``[-0.5, 0.5]`` shared by the first three
  modes (standardised), the others at 0;
* ``mean``: the 4D mean alone (a collapsed generator).

**Metrics** (:mod:`~torch4dtree.evaluate.generative_metrics`): MMD, COV and 1-NNA of each draw against the
held-out plants, with 1-NNA's accuracy on each set (the report's verdicts rank 1-NNA by how far both accuracies are
from 50 %). ``sanity``: the memorising generator evaluated against the training set itself must give MMD 0, COV 1,
1-NNA 0. ``novelty``: the share of samples closer to a training plant than the median nearest-neighbour distance
between training plants divided by 4.

**Morphometrics** (:mod:`~torch4dtree.evaluate.morphometrics`, independent of the ground metric): each generator's
samples decoded to skeletons against the held-out plants, on ``settings.morpho_draws`` independent draws per fold of
as many samples as held-out plants (the organ model's drawn apart from its pool above; the paper model's the first
trajectories of its pool; the 4D mean one draw of one plant); ``memorise``'s one draw is the training plants
themselves, the scale a perfect generator would reach. Real plants are read from their frame files, as the
independent yardstick reads them (the same numbers on the same folders). Summarised over all draws of all folds:
the median and the worst draw of the worst median ratio (overall and at each age after the first) and of the
morphometric 1-NNA.
Organs shrinking / vanishing between frames are counted on the first ``len(train)`` samples of each model, beside
the training and the held-out plants.

**Reconstruction.** A held-out plant's tree-PCA trajectory, registered onto the 4D mean and projected on the modes,
back to a trajectory (``encode -> decode`` in the tree space): its ground distance to the plant (so it includes the
part off the tree PCA), beside the distance to the 4D mean (no modes) and to the nearest training plant
(memorisation); the same for the training plants (fit error).

**Forecast.** The first half (``n // 2`` frames) of each held-out plant is observed and the rest forecast at its
frames' times (``model.forecast``). Error: the mean over forecast frames of the tree distance in the layout (the
extended coordinates; not re-registered decoded skeletons, which would cost a tree registration per frame) between
the forecast and the plant's frames as encoded from its whole sequence. Baselines: the last observed frame stays
(in the same whole-sequence encoding as the truth, off-PCA part included, so the baseline pays no encoding noise)
and the population's 4D mean at the same age (time since the first frame over the training plants' mean duration).
The same errors in tree-PCA coordinates only (as ``tests/model/test_model.py``) are reported beside them.

**Timings**: fit, the 4D mean (paper: 0.0006 s for averaging plants already co-registered; ours with its
temporal registrations, timed warm as refits of the fold's mean), samples per second from coefficients to
trajectories (paper: 0.0001 s a generated 4D plant, the authors' script times only that linear combination),
decoding to skeletons.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import Executor
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ..model import FourDTreeModel, OrganModel, TrajectoryMean
from ..space.pca import principal_axes
from ..temporal.registration import time_warp_trajectory
from ..temporal.trajectory import resample_trajectory
from ..trees.structures import TreeSequence
from .data import EvalData, EvalSettings, Plant4D, primary_source
from .generative_metrics import distance4d, distance_matrix, novelty, set_metrics, within_draw
from .generative_organs import POINT_RULE, encode_plants, event_rates, organ_forecasts, outside_keys_share
from .generative_report import markdown
from .generative_split import heldout_by_kind, load_heldout, splits
from .morphometrics import AGES, compare_populations, files_curve, population_curves
from .paper import SECONDS
from .stats import summary

__all__ = ["GENERATORS", "markdown", "run", "training_draws"]

# generator streams of this section (settings.generator(offset)): split, then samples per fold
SEED_OFFSET = 300
DRAWS, QUICK_DRAWS = 50, 4
QUICK_N_T = 12
# the authors' synthesis script: one uniform scalar in [-0.5, 0.5] on the first three standardised modes
PAPER_SCALAR_MODES, PAPER_SCALAR_HALF_RANGE = 3, 0.5
GENERATORS = ("model", "memorise", "paper_scalar", "mean")
METRICS = ("mmd", "cov", "nna")
PER_DRAW = (*METRICS, "nna_samples", "nna_real")
# the organ model (the default of ``fit``) and "a training plant at random" written in the layout as its samples are
ORGAN_GENERATORS = ("organs", "memorise_encoded")
ALL_GENERATORS = (*ORGAN_GENERATORS, *GENERATORS)
GENERATOR_WHAT = {
    "organs": "the organ model (OrganModel, default settings), its samples written in the layout",
    "memorise_encoded": "a training plant at random, written in the layout as the organ model's samples",
    "model": "the paper's model: its sampler (truncated normal, c = 3)",
    "memorise": "a training plant at random (its tree-PCA trajectory)",
    "paper_scalar": "the authors' script: one uniform scalar in [-0.5, 0.5] on the first 3 modes",
    "mean": "the 4D mean alone",
}
NOVELTY_SAMPLES = 100  # per fold and generator: distances to every training plant
RATE_BATCH, QUICK_RATE_BATCH = 10_000, 1_000
DECODE_BATCH, QUICK_DECODE_BATCH = 8, 2
PAPER_SECONDS = {"sample": SECONDS["sample"], "mean": SECONDS["mean_4d"]}
MEAN_REPEATS = 3  # warm refits of the 4D mean timed per fold (median): the fit's own first call loads kernels
# the organ model's samples in the ground metric per fold: at least as many as held-out plants
MORPHO_SAMPLES, QUICK_MORPHO_SAMPLES = 10, 2
MORPHO_KEYS = ("worst_ratio", "ks_max", "one_nna")
MORPHO_AGES = tuple(f"{u}" for u in AGES if u > 0)
MORPHO_GENERATORS = ("organs", *GENERATORS)
# organs shrinking / vanishing between frames: both models' samples, the training and the held-out plants
EVENT_ROWS = ("organs", "model", "training", "held_out")


# ----------------------------------------------------------------------------- one fold
def _subsets(n: int, h: int, draws: int, gen: torch.Generator) -> Tensor:
    """``(draws, h)`` indices into ``n`` items: each draw without replacement when ``n >= h``."""
    return torch.stack([torch.randperm(n, generator=gen)[:h] if n >= h else torch.randint(n, (h,), generator=gen)
                        for _ in range(draws)])


def training_draws(n: int, h: int, draws: int, gen: torch.Generator) -> Tensor:
    """``(draws, h)`` indices into ``n`` training plants, each drawn independently and uniformly (with replacement):
    "a training plant at random" as a generator's samples are drawn, independently. Without replacement, ``h = n``
    would make every draw the whole training set, a stratified set that no generator of independent samples
    matches in expectation (its MMD is lower and its COV higher than any independent draw's).

    Example:
        >>> idx = training_draws(20, 20, 3, torch.Generator().manual_seed(0))
        >>> idx.shape, bool((idx >= 0).all() and (idx < 20).all())
        (torch.Size([3, 20]), True)
    """
    return torch.randint(n, (draws, h), generator=gen)


def _pool(name: str, model: FourDTreeModel, train: Tensor, h: int, draws: int, gen: torch.Generator
          ) -> tuple[Tensor, Tensor]:
    """A generator's candidate trajectories ``(P, n_t, k)`` and each draw's indices into them ``(draws, h)``."""
    if name == "memorise":
        return train, training_draws(train.shape[0], h, draws, gen)
    if name == "mean":
        return model.mean.trajectory[None], torch.zeros(draws, h, dtype=torch.long)
    P = draws * h
    if name == "model":
        z = model.sample_coefficients(P, gen)
    elif name == "paper_scalar":
        z = torch.zeros(P, model.n_modes, dtype=torch.float64)
        u = (2 * torch.rand(P, 1, generator=gen, dtype=torch.float64) - 1) * PAPER_SCALAR_HALF_RANGE
        z[:, :PAPER_SCALAR_MODES] = u
    else:
        raise ValueError(f"unknown generator {name!r}")
    return model.trajectories(z).detach(), torch.arange(P).reshape(draws, h)


def _fit(train: list[Plant4D], settings: EvalSettings, executor: Executor | None = None
         ) -> tuple[FourDTreeModel, float]:
    n_t = min(settings.n_t, QUICK_N_T) if settings.quick else settings.n_t
    model = FourDTreeModel(settings.model_settings(n_t))
    t0 = time.perf_counter()
    model.fit([p.sequence for p in train], executor=executor)
    return model, time.perf_counter() - t0


def _mean_seconds(model: FourDTreeModel) -> float:
    """Median seconds of refitting the fold's 4D mean (same settings, same trajectories) once it is warm: inside
    ``fit`` it can be the process's first temporal registration, whose numba kernels load then (0.5-2 s)."""
    m = model.mean
    times = []
    for _ in range(MEAN_REPEATS):
        t0 = time.perf_counter()
        TrajectoryMean(m.max_iters, m.tol, m.registration).fit(model.population.trajectories.detach())
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2]


def _reconstruct(model: FourDTreeModel, alpha: Tensor) -> Tensor:
    """Tree-space trajectories ``(B, n_t, k)`` through the model: registered onto the mean, projected on the modes,
    rebuilt."""
    reg = model.mean.register(alpha)
    z, _ = model.pca.project(reg.registered[:, 0], reg.q_registered)
    return model.trajectories(z).detach()


def _pad(alpha: Tensor, r: int) -> Tensor:
    """Tree-space coordinates ``(..., k)`` written in the extended coordinates ``(..., k + r)`` (zeros off the
    tree PCA: what the model and the training trajectories hold)."""
    return torch.cat([alpha, alpha.new_zeros(*alpha.shape[:-1], r)], -1)


def _extended_frames(model: FourDTreeModel, encs: list[Any]) -> tuple[list[Tensor], list[Tensor], int]:
    """Held-out frames in coordinates ``(n, k + r)`` where Euclidean distances are the layout's tree distances:
    the tree-PCA coefficients, then the part of the frames the tree PCA cannot express, in an orthonormal basis of
    all held-out frames' such parts (orthogonal to the components). Also the frames' squared distances off the tree
    PCA and to the tree mean."""
    pca = model.population.pca
    feats = [e.aligned.features().to(pca.mean) for e in encs]
    coefs = [e.frame_coefficients.to(pca.mean) for e in encs]
    offs = [f - pca.inverse_features(c) for f, c in zip(feats, coefs)]
    sing, vh = principal_axes(torch.cat(offs))
    basis = vh[sing > 1e-10 * float(sing.max().clamp_min(1e-300))]
    ext = [torch.cat([c, o @ basis.T], 1) for c, o in zip(coefs, offs)]
    sq = [torch.stack([o.square().sum(-1), (f - pca.mean).square().sum(-1)]) for o, f in zip(offs, feats)]
    return ext, sq, basis.shape[0]


def _forecast(model: FourDTreeModel, plant: Plant4D, frames: Tensor) -> dict[str, Any] | None:
    """Forecast errors of one held-out plant (module doc); ``frames (n, k + r)`` its whole-sequence encoding in
    the extended coordinates."""
    seq = plant.sequence
    n = len(seq)
    half = n // 2
    if half < 1 or n - half < 1:
        return None
    r = frames.shape[1] - model.population.k
    t0 = time.perf_counter()
    f = model.forecast(seq[:half], seq.times[half:], decode=False)
    seconds = time.perf_counter() - t0
    truth = frames[half:]
    u = ((seq.times[half:] - seq.times[0]).to(torch.float64) / float(model.duration)).clamp(0, 1)
    guesses = {"model": _pad(f.trajectory.to(truth), r), "last": frames[half - 1].expand_as(truth),
               "mean": _pad(time_warp_trajectory(model.mean.trajectory, u.to(model.mean.trajectory)).to(truth), r)}
    k = model.population.k
    errs = {key: float((x - truth).norm(dim=-1).mean()) for key, x in guesses.items()}
    pca_errs = {key: float((x[..., :k] - truth[..., :k]).norm(dim=-1).mean()) for key, x in guesses.items()}
    return {**errs, "tree_pca": pca_errs, "observed": half, "forecast": n - half, "rate": float(f.rate),
            "gain": float(f.gain), "seconds": seconds}


def _morphometrics(model: FourDTreeModel, pools: dict[str, Tensor], organ_samples: list[TreeSequence],
                   train: list[Plant4D], held: list[Plant4D], draws: int
                   ) -> tuple[dict[str, list[dict[str, Any]]], dict[str, list[TreeSequence]]]:
    """Each generator's samples against the held-out plants by :func:`~torch4dtree.evaluate.morphometrics.
    compare_populations`, one result per draw of ``len(held)`` samples (module doc): the organ model's
    ``organ_samples`` cut into ``draws`` draws; the first ``draws * len(held)`` trajectories of each paper pool
    ``(P, n_t, k)`` decoded to skeletons; the memorising generator's one draw the training plants as read. Also
    returns each generator's 4D trees."""
    h = len(held)
    real = _real_curves(held)
    seqs = {"organs": organ_samples}
    for name, pool in pools.items():
        if name in GENERATORS:
            seqs[name] = ([p.sequence for p in train] if name == "memorise"
                          else model.decode_trajectories(pool[:draws * h]))
    out: dict[str, list[dict[str, Any]]] = {}
    for name, s in seqs.items():
        if name == "memorise":  # one draw: the training plants
            out[name] = [_slim(compare_populations(real, _real_curves(train)))]
            continue
        curves = population_curves(s)
        out[name] = [_slim(compare_populations(real, curves[i:i + h])) for i in range(0, len(curves), h)]
    return out, seqs


def _real_curves(plants: list[Plant4D]) -> np.ndarray:
    """``(P, A, F)`` morphometric curves of real plants from their frame files (as the yardstick reads them: the
    trees read at ``T`` points per branch are up to 2 % shorter), from their trees when a plant has no files."""
    if all(len(p.files) == len(p.sequence) for p in plants):
        return np.stack([files_curve(p.files, p.sequence.times.tolist()) for p in plants])
    return population_curves([p.sequence for p in plants])


def _slim(c: dict[str, Any]) -> dict[str, Any]:
    """A morphometric comparison without its per-feature table (the summaries of one draw)."""
    return {k: c[k] for k in (*MORPHO_KEYS, "worst", "worst_by_age")}


def _trajectories(frames: list[Tensor], plants: list[TreeSequence], n_t: int) -> Tensor:
    """``(B, n_t, k + r)``: per-frame coordinates of 4D trees resampled on the normalised time grid."""
    return torch.stack([resample_trajectory(x, p.times.to(x), n_t) if len(x) > 1 else x.expand(n_t, -1)
                        for x, p in zip(frames, plants)])


def _fit_organs(train: list[Plant4D]) -> tuple[OrganModel, float]:
    t0 = time.perf_counter()
    organs = OrganModel().fit([p.sequence for p in train])
    return organs, time.perf_counter() - t0


def _fold(train: list[Plant4D], held: list[Plant4D], settings: EvalSettings, gen: torch.Generator,
          executor: Executor | None = None) -> dict[str, Any]:
    model, fit_seconds = _fit(train, settings, executor)
    organs, organ_fit_seconds = _fit_organs(train)
    held_seqs, train_seqs = [p.sequence for p in held], [p.sequence for p in train]
    t0 = time.perf_counter()
    encs, held_within = encode_plants(model.population, held_seqs, executor)
    encode_seconds = (time.perf_counter() - t0) / len(held)
    h = len(held)
    n_morpho = QUICK_MORPHO_SAMPLES if settings.quick else MORPHO_SAMPLES
    morpho_draws = settings.generative_draws()
    t0 = time.perf_counter()
    organ_samples = organs.sample(max(h, n_morpho), generator=gen)
    organ_sample_seconds = (time.perf_counter() - t0) / len(organ_samples)
    organ_morpho = organs.sample(morpho_draws * h, generator=gen)
    t0 = time.perf_counter()
    enc_organs = model.population.transform_many(organ_samples, executor)
    enc_train, train_within = encode_plants(model.population, train_seqs, executor)
    organ_encode_seconds = (time.perf_counter() - t0) / (len(organ_samples) + len(train))
    frames_all, sq_all, r = _extended_frames(model, encs + enc_organs + enc_train)
    frames, sq = frames_all[:h], sq_all[:h]
    ns = len(organ_samples)
    s_alpha = _trajectories(frames_all[h:h + ns], organ_samples, model.n_t)
    te_alpha = _trajectories(frames_all[h + ns:], train_seqs, model.n_t)
    k = model.population.k
    t_alpha = _pad(model.population.trajectories.detach(), r)
    r_alpha = _trajectories(frames, held_seqs, model.n_t)
    draws = QUICK_DRAWS if settings.quick else DRAWS

    # the generators against the held-out plants
    d_rr = distance_matrix(r_alpha, executor=executor)
    d_tt = distance_matrix(t_alpha, executor=executor)
    d_rt = distance_matrix(r_alpha, t_alpha, executor=executor)
    d_tete = distance_matrix(te_alpha, executor=executor)
    per_draw: dict[str, list[dict[str, float]]] = {}
    novel: dict[str, dict[str, float]] = {}
    pools: dict[str, Tensor] = {}
    t0 = time.perf_counter()
    for name in ALL_GENERATORS:
        if name in ("organs", "memorise_encoded"):
            pool = s_alpha if name == "organs" else te_alpha
            # the organ model's pool is independent samples already; the training plants are drawn as samples are
            idx = (_subsets if name == "organs" else training_draws)(pool.shape[0], h, draws, gen)
        else:
            pool, idx = _pool(name, model, t_alpha[..., :k], h, draws, gen)
            pools[name] = pool
            pool = _pad(pool, r)
        d_pr = d_rt.T if name == "memorise" else distance_matrix(pool, r_alpha, executor=executor)
        # the training plants' distances are known (both layouts)
        d_ss = within_draw(pool, idx, {"memorise": d_tt, "memorise_encoded": d_tete}.get(name))
        per_draw[name] = [set_metrics(d_ss[j], d_pr[idx[j]], d_rr) for j in range(draws)]
        if name in ("model", "paper_scalar"):
            novel[name] = novelty(distance_matrix(pool[:NOVELTY_SAMPLES], t_alpha, executor=executor), d_tt)
        elif name == "organs":  # beside the training plants written in the layout as its samples are
            novel[name] = novelty(distance_matrix(pool, te_alpha, executor=executor), d_tete)
    metric_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    morpho, decoded = _morphometrics(model, pools, organ_morpho, train, held, morpho_draws)
    morpho_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    n_ev = len(train)  # as many samples as training plants
    events = {"organs": event_rates(decoded["organs"][:n_ev]), "model": event_rates(decoded["model"][:n_ev]),
              "training": event_rates(train_seqs, train_within), "held_out": event_rates(held_seqs, held_within)}
    event_seconds = time.perf_counter() - t0
    sanity = {m: v for m, v in set_metrics(d_tt, d_tt, d_tt).items() if m in METRICS}  # training set memorised

    # reconstruction through the model, beside the mean and the nearest training plant
    mean = _pad(model.mean.trajectory.detach(), r)
    recon_r = distance4d(r_alpha, _pad(_reconstruct(model, r_alpha[..., :k]), r))
    mean_r = distance4d(r_alpha, mean.expand_as(r_alpha))
    recon_t = distance4d(t_alpha, _pad(_reconstruct(model, t_alpha[..., :k]), r))
    mean_t = distance4d(t_alpha, mean.expand_as(t_alpha))
    t0 = time.perf_counter()
    organ_fc = organ_forecasts(model, organs, held_seqs, encs, train_seqs, enc_train, gen)
    organ_forecast_seconds = (time.perf_counter() - t0) / len(held)
    plants = []
    for i, (p, e) in enumerate(zip(held, encs)):
        dropped = float(e.dropped_sq_norm.sum())
        kept = float(e.aligned.sq_norm().sum())
        off, spread = sq[i]
        plants.append({
            "plant": p.name, "frames": len(p.sequence), "reconstruction": float(recon_r[i]),
            "to_mean": float(mean_r[i]), "nearest_training": float(d_rt[i].min()),
            "outside": float(e.dropped_sq_norm.mean().sqrt()),  # as FourDTreeModel.score().outside
            "outside_share": dropped / (dropped + kept) if dropped + kept > 0 else 0.0,
            "outside_keys_share": outside_keys_share(organs, p.sequence),
            "off_tree_space": float(off.mean().sqrt()),
            "off_tree_space_share": float(off.sum() / spread.sum()) if float(spread.sum()) > 0 else 0.0,
            "forecast": _forecast(model, p, frames[i]), "organ_forecast": organ_fc[i],
        })

    # speed: coefficients -> trajectories, and decoding to skeletons
    n_rate = QUICK_RATE_BATCH if settings.quick else RATE_BATCH
    z = model.sample_coefficients(n_rate, gen)
    with torch.no_grad():
        model.trajectories(z[:10])  # warm-up
        t0 = time.perf_counter()
        model.trajectories(z)
    sample_seconds = (time.perf_counter() - t0) / n_rate
    n_dec = QUICK_DECODE_BATCH if settings.quick else DECODE_BATCH
    t0 = time.perf_counter()
    model.decode(z[:n_dec])
    decode_seconds = (time.perf_counter() - t0) / n_dec
    nn_t = (d_tt + torch.diag(torch.full((len(train),), math.inf, dtype=d_tt.dtype))).min(1).values
    return {
        "train": [p.name for p in train], "held_out": [p.name for p in held], "modes": model.n_modes,
        "tree_components": k, "extra_dimensions": r, "n_t": model.n_t, "draws": draws,
        "mode_variance_ratio": [float(x) for x in model.pca.explained_variance_ratio],
        "per_draw": per_draw, "novelty": novel, "sanity": sanity, "plants": plants, "morphometrics": morpho,
        "organ_events": events,
        "training_reconstruction": [float(x) for x in recon_t], "training_to_mean": [float(x) for x in mean_t],
        "training_nn": [float(x) for x in nn_t],
        "held_out_pairs": [float(d_rr[i, j]) for i in range(h) for j in range(i + 1, h)],
        "seconds": {"fit": fit_seconds, "mean": _mean_seconds(model),
                    "mean_in_fit": float(model.report_["seconds"]["mean"]),
                    "encode_per_plant": encode_seconds, "metrics": metric_seconds,
                    "sample_per_plant": sample_seconds, "decode_per_plant": decode_seconds,
                    "morphometrics": morpho_seconds, "organ_fit": organ_fit_seconds,
                    "organ_sample_per_plant": organ_sample_seconds, "organ_encode_per_plant": organ_encode_seconds,
                    "organ_forecast_per_plant": organ_forecast_seconds, "organ_events": event_seconds},
    }


# ----------------------------------------------------------------------------- the section
def _kind(plants: list[Plant4D], settings: EvalSettings, offset: int, progress: bool,
          executor: Executor | None = None, heldout: list[Plant4D] | None = None) -> dict[str, Any]:
    folds = splits(plants, settings, settings.generator(SEED_OFFSET + offset), heldout)
    n = len(plants) + len(heldout or [])
    if not folds:
        return {"plants": n, "skipped": f"{len(plants)} plants" + (f" and {len(heldout)} held out" if heldout else "")
                + ": at least 2 to fit and 2 held out are needed"}
    gen = settings.generator(SEED_OFFSET + offset + 1)
    from tqdm.auto import tqdm

    done = [_fold(train, held, settings, gen, executor)
            for train, held in tqdm(folds, disable=not progress, desc="generative folds", unit="fold")]
    held_plants = [p for d in done for p in d["plants"]]
    fc = [p["forecast"] for p in held_plants if p["forecast"] is not None]
    ofc = [p["organ_forecast"] for p in held_plants if p["organ_forecast"] is not None]
    gens = {name: {m: summary(r[m] for d in done for r in d["per_draw"][name]) for m in PER_DRAW}
            for name in ALL_GENERATORS}
    return {
        "plants": n, "split": "held-out folder" if heldout is not None else f"{len(folds)} fold(s)",
        "folds": [{k: v for k, v in d.items() if k != "per_draw"} | {
            "generators": {name: {m: summary(r[m] for r in d["per_draw"][name])["mean"] for m in PER_DRAW}
                           for name in ALL_GENERATORS}} for d in done],
        "generators": gens,
        "novelty": {name: {k: summary(d["novelty"][name][k] for d in done)["mean"]
                           for k in ("threshold", "share_closer", "nearest_min", "nearest_median")}
                    for name in ("organs", "model", "paper_scalar")},
        "sanity": {m: max(d["sanity"][m] for d in done) if m != "cov" else min(d["sanity"][m] for d in done)
                   for m in METRICS},
        "morphometrics": {name: {**{m: summary(r[m] for d in done for r in d["morphometrics"][name])
                                    for m in MORPHO_KEYS},
                                 "worst_by_age": {u: summary(r["worst_by_age"][u] for d in done
                                                             for r in d["morphometrics"][name])
                                                  for u in MORPHO_AGES},
                                 "draws": sum(len(d["morphometrics"][name]) for d in done)}
                          for name in MORPHO_GENERATORS},
        "held_out_pairs": summary(x for d in done for x in d["held_out_pairs"]),
        "reconstruction": {
            "held_out": summary(p["reconstruction"] for p in held_plants),
            "held_out_to_mean": summary(p["to_mean"] for p in held_plants),
            "held_out_nearest_training": summary(p["nearest_training"] for p in held_plants),
            "training": summary(x for d in done for x in d["training_reconstruction"]),
            "training_to_mean": summary(x for d in done for x in d["training_to_mean"]),
            "outside": summary(p["outside"] for p in held_plants),
            "outside_share": summary(p["outside_share"] for p in held_plants),
            "off_tree_space": summary(p["off_tree_space"] for p in held_plants),
            "off_tree_space_share": summary(p["off_tree_space_share"] for p in held_plants),
            "outside_keys_share": summary(p["outside_keys_share"] for p in held_plants),
        },
        "organ_events": {who: {m: summary(d["organ_events"][who][m] for d in done)["mean"]
                               for m in ("shrink", "vanish", "organ_steps")} for who in EVENT_ROWS},
        "forecast": {**{k: summary(f[k] for f in fc) for k in ("model", "last", "mean")},
                     "tree_pca": {k: summary(f["tree_pca"][k] for f in fc) for k in ("model", "last", "mean")},
                     "plants": len(fc), "wins_vs_last": sum(f["model"] < f["last"] for f in fc),
                     "wins_vs_mean": sum(f["model"] < f["mean"] for f in fc)},
        "organ_forecast": {"point": POINT_RULE,
                           **{k: summary(f[k] for f in ofc) for k in ("organs", "organs_mean", "organs_draw", "last",
                                                                      "mean")},
                           "final_length": {k: summary(f["final_length"][k] for f in ofc) for k in ("organs", "last")},
                           "plants": len(ofc), "wins_vs_last": sum(f["organs"] < f["last"] for f in ofc),
                           "wins_vs_mean": sum(f["organs"] < f["mean"] for f in ofc),
                           "wins_vs_both": sum(f["organs"] < min(f["last"], f["mean"]) for f in ofc),
                           "mean_wins_vs_both": sum(f["organs_mean"] < min(f["last"], f["mean"]) for f in ofc),
                           "draw_wins_vs_both": sum(f["organs_draw"] < min(f["last"], f["mean"]) for f in ofc)},
    }


def run(datas: dict[str, EvalData], settings: EvalSettings, progress: bool = False, executor: Executor | None = None,
        heldout: EvalData | None = None) -> dict[str, Any]:
    """The section (module doc): ``{"generative": {...}, "timings": {...}}``; ``executor``: where the fits'
    registrations, the encodings and the ground distances run (the same numbers as inline). ``settings``: with the
    split and the draws (``heldout``, ``folds``, ``morpho_draws``); ``heldout``: the held-out plants (else read from
    ``settings.heldout`` when set, else folds)."""
    if heldout is None and settings.heldout is not None:
        heldout = load_heldout(settings.heldout, settings.T)
    source = primary_source(datas)
    out: dict[str, Any] = {"source": source, "skipped_sources": [s for s in datas if s != source],
                           "generators": dict(GENERATOR_WHAT), "kinds": {}}
    if source is None:
        return {"generative": out, "timings": {}}
    data = datas[source]
    held = heldout_by_kind(data, heldout) if heldout is not None else None
    if heldout is not None:
        out["heldout"] = {"path": str(heldout.root), "source": heldout.source, "plants": len(heldout.plants)}
    for j, kind in enumerate(data.kinds):
        if held is not None and kind not in held:
            out["kinds"][kind] = {"plants": len(data.by_kind(kind)), "skipped": "no held-out plants of this kind"}
            continue
        out["kinds"][kind] = _kind(data.by_kind(kind), settings, 10 * j, progress, executor,
                                   None if held is None else held[kind])
    folds = [f for r in out["kinds"].values() for f in r.get("folds", [])]
    if not folds:
        return {"generative": out, "timings": {}}

    def mean_of(key: str) -> float:
        return sum(f["seconds"][key] for f in folds) / len(folds)

    timings = {
        "generative_fit": {"seconds": sum(f["seconds"]["fit"] for f in folds), "paper_seconds": None,
                           "what": f"fit the paper's 4D model, {len(folds)} fold(s) ({source})"},
        "generative_organ_fit": {"seconds": sum(f["seconds"]["organ_fit"] for f in folds), "paper_seconds": None,
                                 "what": f"fit the organ model, {len(folds)} fold(s) ({source})"},
        "generative_organ_sample": {"seconds": mean_of("organ_sample_per_plant"), "paper_seconds": None,
                                    "what": "one 4D plant of the organ model, sampled and assembled"},
        "generative_organ_encode": {"seconds": mean_of("organ_encode_per_plant"), "paper_seconds": None,
                                    "what": "one organ-model sample or training plant written in the layout"},
        "generative_organ_forecast": {"seconds": mean_of("organ_forecast_per_plant"), "paper_seconds": None,
                                      "what": "one held-out plant's organ forecast and its baseline, encoded"},
        "generative_mean": {"seconds": mean_of("mean"), "paper_seconds": PAPER_SECONDS["mean"],
                            "what": "the 4D Karcher mean of one fit, with its temporal registrations (warm: median of "
                                    f"{MEAN_REPEATS} refits, mean over folds; the paper's figure averages plants "
                                    "already co-registered, its mean-shape figure)"},
        "generative_sample": {"seconds": mean_of("sample_per_plant"), "paper_seconds": PAPER_SECONDS["sample"],
                              "what": "one generated 4D plant, coefficients -> trajectory (batched)"},
        "generative_decode": {"seconds": mean_of("decode_per_plant"), "paper_seconds": None,
                              "what": "one generated 4D plant decoded to skeletons"},
        "generative_encode": {"seconds": mean_of("encode_per_plant"), "paper_seconds": None,
                              "what": "one held-out 4D plant written in the model's tree space"},
        "generative_metrics": {"seconds": sum(f["seconds"]["metrics"] for f in folds), "paper_seconds": None,
                               "what": "ground distances of MMD / COV / 1-NNA, all folds and generators"},
    }
    out["samples_per_second"] = 1.0 / timings["generative_sample"]["seconds"]
    return {"generative": out, "timings": timings}
