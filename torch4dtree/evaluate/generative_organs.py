"""The organ model's rows of the generative section (docs/method.md §5.8, §7): what it needs beyond the paper's model.

The organ model (:class:`~torch4dtree.model.OrganModel`) has no tree space of its own, so its samples are measured
in the **paper model's fitted space, as the held-out plants are**: every 4D tree it makes is written in the fold's
slot layout by ``population.transform`` (within-sequence registration, its representative registered onto the
union representative, the frames placed in the layout). The training plants are written the
same way for the reference row "a training plant at random" of this path (``memorise_encoded``): the organ model's
samples then meet real plants that went through the same encoding (its losses at the layout included), not the
training trajectories the paper's model was fit on.

Also here, measured on 4D trees whatever made them:

* :func:`outside_keys_share`: the share of a held-out plant's squared SRVF norm on organs at botanical keys the
  training plants never had (the organ model cannot write them). A curve's squared SRVF norm is its length
  (``|q|^2 = |c'|``), so the share is the summed length over frames of those organs (and their descendants, whose
  keys extend theirs) over the plant's summed length.
* :func:`organ_events`: organs shrinking or vanishing between consecutive frames, with organ identities from the
  within-sequence registration (the same path for samples, training and held-out plants). Plants the section also
  writes in the layout are registered once (:func:`encode_plants`): ``population.transform`` starts with the same
  within-sequence registration, and a registration is most of an encoding's cost.
* :func:`organ_forecast`: the organ model's forecast (:func:`~torch4dtree.model.organ_forecast.forecast_organs`)
  of a held-out plant's second half, beside "the last observed frame stays", both written in the layout as a
  whole sequence (observed frames, then the guess) and read at the plant's own frame times, and the 4D mean. The
  forecast's point (:data:`POINT_RULE`, :func:`~torch4dtree.model.organ_forecast.forecast_point`), since the
  baselines are points too: the mean of several continuations in the layout at the slots where the observed plant
  has an organ, averaged at every other slot with the training plants' average at the same ages (written in the
  layout as the held-out plants are).
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, fields
from functools import partial
from typing import Any

import torch
from torch import Tensor

from ..model import FourDTreeModel, OrganModel
from ..model.organ_forecast import NEW_SLOT_WEIGHT, forecast_organs, forecast_point, seen_slots
from ..model.organ_table import plant_organs
from ..parallel import run_tasks
from ..settings import RegistrationSettings
from ..temporal.population import Population, SequenceEncoding
from ..temporal.registration import time_warp_trajectory
from ..temporal.within import AlignedSequence, register_sequence
from ..trees.structures import Trees, TreeSequence

__all__ = ["FORECAST_DRAWS", "POINT_RULE", "SHRINK_TOL", "RepeatedPairs", "encode_plants", "event_rates",
           "organ_events", "organ_forecast", "organ_forecasts", "outside_keys_share", "training_average"]

# an organ shrinks between two frames when it loses more than this share of its length (skeleton noise and the
# registration's splits move lengths by a few per cent)
SHRINK_TOL = 0.1
# times closer than this (data units) are one instant when a forecast is read at the plant's frame times
SAME_TIME = 1e-9
# continuations of the organ model averaged into its forecast point in the ground metric (organ_forecast)
FORECAST_DRAWS = 8
# the organ forecast's point (organ_forecast), as the report names it
POINT_RULE = (f"mean of {FORECAST_DRAWS} continuations at the plant's slots; elsewhere {NEW_SLOT_WEIGHT:g} of it, "
              f"{1 - NEW_SLOT_WEIGHT:g} the training plants' average")


def outside_keys_share(organs: OrganModel, plant: TreeSequence) -> float:
    """Share in ``[0, 1]`` of ``plant``'s squared SRVF norm (its summed length over frames) on organs at botanical
    keys absent from ``organs`` (module doc).

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> train = [synthetic_plant("maize", seed=i, n_frames=2, T=8).sequence for i in range(2)]
        >>> outside_keys_share(OrganModel().fit(train), train[0])
        0.0
    """
    known = set(organs.keys)
    total = outside = 0.0
    for o in plant_organs(plant, plant.normalized_times().to(torch.float64), organs.settings.registration):
        mass = o["length"] * float(o["growth"].sum())
        total += mass
        if o["key"] not in known:
            outside += mass
    return outside / total if total > 0 else 0.0


def organ_events(plant: TreeSequence, aligned: AlignedSequence | None = None) -> dict[str, int]:
    """Organs of a 4D tree between consecutive frames: ``present`` (organ-frames with a next frame), ``shrink``
    (present in both, the later more than :data:`SHRINK_TOL` shorter) and ``vanish`` (gone in the next frame);
    organ identities from the within-sequence registration, ``aligned`` if already computed (else
    :func:`~torch4dtree.temporal.register_sequence` with its defaults).

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> organ_events(synthetic_plant("maize", seed=0, n_frames=2, T=8).sequence)["present"] > 0
        True
    """
    if len(plant) < 2:
        return {"present": 0, "shrink": 0, "vanish": 0}
    seq = plant.to(torch.float64)
    ident = (aligned if aligned is not None else register_sequence(seq)).identity  # (n, S)
    ptr = seq.frames.ptr[:-1]
    lengths = seq.frames.branch_lengths()
    glob = ident + ptr[:, None]
    length = torch.where(ident >= 0, lengths[glob.clamp(min=0)], torch.zeros((), dtype=lengths.dtype))
    alive = length > 0
    now, nxt = alive[:-1], alive[1:]
    shrink = now & nxt & (length[1:] < (1 - SHRINK_TOL) * length[:-1])
    return {"present": int(now.sum()), "shrink": int(shrink.sum()), "vanish": int((now & ~nxt).sum())}


def event_rates(plants: Sequence[TreeSequence], aligned: Sequence[AlignedSequence | None] | None = None
                ) -> dict[str, float]:
    """Pooled :func:`organ_events` of several 4D trees (``aligned``: their within-sequence registrations where
    already computed, e.g. by :func:`encode_plants`): ``shrink`` and ``vanish`` per organ and frame step, and
    the ``organ_steps`` they are counted over.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> rates = event_rates([synthetic_plant("maize", seed=0, n_frames=2, T=8).sequence])
        >>> rates["shrink"], rates["organ_steps"] > 0
        (0.0, True)
    """
    tot = {"present": 0, "shrink": 0, "vanish": 0}
    for p, a in zip(plants, aligned if aligned is not None else [None] * len(plants)):
        for k, v in organ_events(p, a).items():
            tot[k] += v
    n = max(tot["present"], 1)
    return {"shrink": tot["shrink"] / n, "vanish": tot["vanish"] / n, "organ_steps": float(tot["present"])}


def _tree_key(trees: Trees) -> tuple:
    """Everything a registration reads of a plain :class:`Trees`, hashable."""
    return tuple((str(t.dtype), tuple(t.shape), t.detach().cpu().contiguous().numpy().tobytes())
                 for t in (trees.points, trees.parent, trees.s, trees.num_branches, trees.label))


@dataclass(frozen=True)
class RepeatedPairs(RegistrationSettings):
    """Registration settings that remember each registration of plain :class:`Trees` by its exact inputs.

    Why: the continuations of one forecast share the observed frames, so the within-sequence registration of each
    whole sequence (observed frames, then the continuation) would search the same consecutive pairs again; a
    registration is a function of its inputs, so the remembered result is the one a new search returns.

    Example:
        >>> pairs = RepeatedPairs.of(RegistrationSettings())
        >>> pairs.n_starts == RegistrationSettings().n_starts, pairs.memo
        (True, {})
    """

    memo: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def of(cls, settings: RegistrationSettings) -> RepeatedPairs:
        """``settings`` with an empty memory."""
        return cls(**{f.name: getattr(settings, f.name) for f in fields(RegistrationSettings)})

    def register(self, trees: Any, reference: Any, lambdas: Sequence[float], rotation: str, *,  # noqa: ANN401
                 positions: str, order_tol: float | None, lp_relative: bool, symmetric: bool) -> list[Any]:
        """:meth:`RegistrationSettings.register`, remembered for plain :class:`Trees` (module doc)."""
        args = {"positions": positions, "order_tol": order_tol, "lp_relative": lp_relative, "symmetric": symmetric}
        if type(trees) is not Trees or type(reference) is not Trees:
            return super().register(trees, reference, lambdas, rotation, **args)
        key = (_tree_key(trees), _tree_key(reference), tuple(float(x) for x in lambdas), rotation,
               *sorted(args.items()))
        if key not in self.memo:
            self.memo[key] = super().register(trees, reference, lambdas, rotation, **args)
        return self.memo[key]


def transform_registered(population: Population, sequence: TreeSequence, aligned: AlignedSequence | None
                         ) -> SequenceEncoding:
    """``population.transform(sequence, aligned)`` (a task: top-level, picklable)."""
    return population.transform(sequence, aligned)


def encode_plants(population: Population, plants: Sequence[TreeSequence], executor: Executor | None = None,
                  registration: RegistrationSettings | None = None
                  ) -> tuple[list[SequenceEncoding], list[AlignedSequence | None]]:
    """``population.transform_many(plants, executor)`` and each plant's within-sequence registration that it
    starts with (for :func:`event_rates`), each plant registered once; ``None`` for a plant read at another number
    of points per branch than the layout's (``transform`` resamples it first) or of one frame. ``registration``:
    the within-sequence registrations' settings if not the population's own (e.g. :class:`RepeatedPairs` of them).

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> plants = [synthetic_plant("maize", i, n_frames=3, T=8).sequence for i in range(2)]
        >>> pop = Population(n_t=4, medoid_candidates=1).fit(plants)
        >>> encs, aligned = encode_plants(pop, plants)
        >>> [e.trajectory.shape[0] for e in encs], [len(a) for a in aligned]
        ([4, 4], [3, 3])
    """
    device, T = population.ref_points.device, population.ref_points.shape[1]
    seqs = [s.to(device=device, dtype=torch.float64) for s in plants]
    mine = [i for i, s in enumerate(seqs) if s.frames.T == T and len(s) >= 2]
    within = partial(register_sequence, registration=registration or population.registration)
    done = run_tasks(within, [(seqs[i],) for i in mine], executor, device)
    aligned: list[AlignedSequence | None] = [None] * len(seqs)
    for i, a in zip(mine, done):
        aligned[i] = a
    if executor is None:
        encs = [population.transform(s, a) for s, a in zip(seqs, aligned)]
    else:
        encs = run_tasks(transform_registered, list(zip(seqs, aligned)), executor, device,
                         shared=population.portable())
    return encs, aligned


def _read_at(features: Tensor, times: Tensor, at: Tensor) -> Tensor:
    """``(m, F)`` features of frames at ``times (n,)`` (increasing) read at ``at (m,)``, linear between frames,
    the first / last frame outside their span."""
    t = times.to(features.dtype)
    a = at.to(features.dtype).clamp(float(t[0]), float(t[-1]))
    hi = torch.searchsorted(t, a).clamp(1, len(t) - 1) if len(t) > 1 else torch.zeros(len(a), dtype=torch.long)
    lo = (hi - 1).clamp(min=0)
    span = (t[hi] - t[lo]).clamp_min(SAME_TIME)
    w = ((a - t[lo]) / span).clamp(0, 1)[:, None]
    return (1 - w) * features[lo] + w * features[hi]


def _whole(observed: TreeSequence, future: TreeSequence) -> TreeSequence:
    """The observed frames followed by the future ones after the last observed time."""
    keep = [j for j in range(len(future)) if float(future.times[j]) > float(observed.times[-1]) + SAME_TIME]
    if not keep:
        return observed
    f = future[keep].to(torch.float64)
    o = observed.to(torch.float64)
    return TreeSequence(Trees.cat([o.frames, f.frames]), torch.cat([o.times, f.times]), observed.name)


def organ_forecast(paper: FourDTreeModel, organs: OrganModel, plant: TreeSequence, truth: Tensor, mean: Tensor,
                   prior: Tensor, generator: torch.Generator, draws: int = FORECAST_DRAWS) -> dict[str, Any] | None:
    """Forecast errors of one held-out plant's second half (``n // 2`` frames observed; module doc).

    The organ model's point (:data:`POINT_RULE`) is :func:`~torch4dtree.model.organ_forecast.forecast_point` of
    ``draws`` continuations' layout features: their mean (the conditional mean in the ground metric) at the slots
    where the observed plant has an organ (its last observed frame as written in the layout), averaged with
    ``prior`` at the other slots, where new organs go and a few continuations disagree (docs/method.md §5,
    forecasting). One continuation is a draw of the conditional distribution, whose expected squared distance to
    the truth is the point's plus the distribution's spread, so a single draw loses to any point guess of the same
    quality (``organs_draw``: the first continuation's error, for scale; ``organs_mean``: the continuations' mean
    at every slot).

    Args:
        paper: the fold's paper model (its layout is the ground metric).
        organs: the fold's organ model.
        plant: the held-out 4D tree.
        truth: ``(n - n // 2, F)`` its forecast frames' layout features in its whole-sequence encoding.
        mean: ``(n - n // 2, F)`` the 4D mean's features at the same ages (the mean baseline).
        prior: ``(n - n // 2, F)`` the population's expectation at the same ages (:func:`training_average`).
        generator: the forecast's random stream.
        draws: continuations in the point (at least 1).

    Returns:
        ``{"organs", "organs_mean", "organs_draw", "last", "mean"}``: mean tree distance in the layout over the
        forecast frames (``last``: the last observed frame kept, encoded as each continuation is); ``final_length``:
        the relative error of the last frame's total length of the continuations (median) and of the last observed
        frame; ``None`` below 2 frames.
    """
    n = len(plant)
    half = n // 2
    if half < 1 or n - half < 1:
        return None
    observed, at = plant[list(range(half))], plant.times[half:]
    last = TreeSequence(observed.frames[[half - 1] * (n - half)], at.to(observed.times.dtype), plant.name)
    true_final = float(plant.frames[n - 1].total_length()[0])
    pairs = RepeatedPairs.of(paper.population.registration)  # the observed frames' pairs: searched once

    def encoded(guess: TreeSequence) -> tuple[Tensor, float]:
        """The guess's layout features at the plant's forecast times, written with the observed frames, and the
        relative error of its total length at the plant's last time."""
        whole = _whole(observed, guess)
        enc = encode_plants(paper.population, [whole], registration=pairs)[0][0]
        feats = _read_at(enc.aligned.features().to(truth), whole.times, at)
        j = int(torch.searchsorted(whole.times.to(torch.float64).contiguous(),
                                   at[-1].to(torch.float64).reshape(1)).clamp(max=len(whole) - 1))
        return feats, abs(float(whole.frames[j].total_length()[0]) - true_final) / max(true_final, SAME_TIME)

    fcs = [encoded(f) for f in forecast_organs(organs, observed, n=draws, generator=generator)]
    last_feats, last_final = encoded(last)
    conts = torch.stack([f for f, _ in fcs])
    point = forecast_point(conts, seen_slots(last_feats, paper.population.ref_points.shape[0]), prior.to(truth))
    guesses = {"organs": point, "organs_mean": conts.mean(0), "organs_draw": fcs[0][0], "last": last_feats,
               "mean": mean.to(truth)}
    errs = {key: float((x - truth).norm(dim=-1).mean()) for key, x in guesses.items()}
    finals = torch.tensor([e for _, e in fcs], dtype=torch.float64)
    return {**errs, "final_length": {"organs": float(finals.median()), "last": last_final}}


def training_average(features: Sequence[Tensor], times: Sequence[Tensor], since: Tensor) -> Tensor:
    """``(m, F)`` the training plants' average layout features at ``since (m,)`` time after each one's first frame
    (as the held-out plant's ages are counted), each plant's ``features (n_i, F)`` read at its frame ``times (n_i,)``
    linearly between frames and held at its first / last frame outside them.

    Example:
        >>> f = [torch.tensor([[0.0], [2.0]]), torch.tensor([[4.0], [4.0]])]
        >>> training_average(f, [torch.tensor([0.0, 2.0]), torch.tensor([5.0, 6.0])], torch.tensor([1.0]))
        tensor([[2.5000]])
    """
    if not features or len(features) != len(times):
        raise ValueError(f"need features and times of the same training plants, got {len(features)} and {len(times)}")
    return torch.stack([_read_at(f, t, t[0] + since.to(t)) for f, t in zip(features, times)]).mean(0)


def organ_forecasts(paper: FourDTreeModel, organs: OrganModel, plants: Sequence[TreeSequence], encodings: Sequence[Any],
                    training: Sequence[TreeSequence], training_encodings: Sequence[Any], generator: torch.Generator
                    ) -> list[dict[str, Any] | None]:
    """:func:`organ_forecast` of every held-out plant, ``encodings`` their ``paper.population.transform``; the 4D
    mean baseline at each plant's ages (time since its first frame over the training plants' mean duration); the
    point's prior the ``training`` plants' layout features (``training_encodings``, their transforms) averaged at
    the same times since their first frame (:func:`training_average`)."""
    train_feats = [e.aligned.features() for e in training_encodings]
    train_times = [s.times for s in training]
    out: list[dict[str, Any] | None] = []
    for seq, e in zip(plants, encodings):
        half = len(seq) // 2
        if half < 1:
            out.append(None)
            continue
        u = ((seq.times[half:] - seq.times[0]).to(torch.float64) / float(paper.duration)).clamp(0, 1)
        mean = paper.population.pca.inverse_features(time_warp_trajectory(paper.mean.trajectory,
                                                                          u.to(paper.mean.trajectory)))
        truth = e.aligned.features()[half:]
        prior = training_average([f.to(truth) for f in train_feats], train_times, seq.times[half:] - seq.times[0])
        out.append(organ_forecast(paper, organs, seq, truth, mean, prior, generator))
    return out
