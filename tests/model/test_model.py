"""The generative model (docs/method.md §5): sampler, 4D mean and modes, the bundled model, checkpoints, forecasting."""

from __future__ import annotations

import copy
import math

import pytest
import torch

from torch4dtree.model import (
    CheckpointError,
    FourDTreeModel,
    TrajectoryMean,
    TrajectoryPCA,
    TruncatedNormalSampler,
    load,
    sequence_validity,
    truncated_normal_variance,
)
from torch4dtree.settings import ModelSettings
from torch4dtree.temporal import geodesic4d, register_trajectories, time_warp_trajectory, trajectory_srvf

N_T = 12


def _trajectories(n: int, n_t: int = 24, k: int = 3, seed: int = 0) -> torch.Tensor:
    """Smooth random trajectories ``(n, n_t, k)``."""
    g = torch.Generator().manual_seed(seed)
    t = torch.linspace(0, 1, n_t, dtype=torch.float64)[:, None]
    a = torch.randn(n, 1, k, generator=g, dtype=torch.float64)
    b = torch.randn(n, 1, k, generator=g, dtype=torch.float64)
    c = torch.randn(n, 1, k, generator=g, dtype=torch.float64)
    return a + b * t + c * torch.sin(3 * t)


# ----------------------------------------------------------------------------- sampler


def test_sampler_exact_truncated_normal() -> None:
    s = TruncatedNormalSampler(4, c=1.5)
    z = s(100_000, generator=torch.Generator().manual_seed(0))
    assert z.shape == (100_000, 4) and z.dtype == torch.float64
    assert float(z.abs().max()) <= 1.5
    var = truncated_normal_variance(1.5)
    assert var == pytest.approx(0.5507, abs=1e-3)  # tabulated value for c = 1.5
    # per-mode variance within 4 standard errors (var of z^2 <= E z^4 <= c^2 var)
    se = math.sqrt(1.5 ** 2 * var / 100_000)
    assert torch.allclose(z.var(0), torch.full((4,), var, dtype=torch.float64), atol=4 * se)
    # not clamping: no probability mass piles up at the bounds
    assert float((z.abs() > 1.5 - 1e-3).double().mean()) < 1e-3
    assert torch.equal(z[:5], s(5, generator=torch.Generator().manual_seed(0)))


def test_sampler_rejects_bad_settings() -> None:
    with pytest.raises(ValueError, match="c must be"):
        TruncatedNormalSampler(3, c=0.0)
    with pytest.raises(ValueError, match="n_modes"):
        TruncatedNormalSampler(0)


# ----------------------------------------------------------------------------- 4D mean and PCA


def test_mean_of_copies_is_the_tree_with_zero_variance() -> None:
    a = _trajectories(1)
    mean = TrajectoryMean().fit(a.expand(3, -1, -1))
    assert torch.allclose(mean.trajectory, a[0], atol=1e-10)
    assert mean.energies_[-1] < 1e-18
    reg = mean.registered_
    pca = TrajectoryPCA().fit(reg.registered[:, 0], reg.q_registered)
    assert float(pca.explained_variance.abs().max()) < 1e-20
    z = torch.randn(5, pca.n_modes, dtype=torch.float64)
    assert torch.allclose(pca.trajectories(z), a[0].expand(5, -1, -1), atol=1e-10)


def test_mean_of_two_registered_trees_is_the_geodesic_midpoint() -> None:
    a, b = _trajectories(2, seed=1)
    b_star = register_trajectories(a, b).registered
    mean = TrajectoryMean(max_iters=5).fit(torch.stack([a, b_star]))
    mid = geodesic4d(*trajectory_srvf(a), *trajectory_srvf(b_star), steps=3)[1]
    # the mean is re-timed by the centering, so compare in the quotient by time warps: there the energy (sum of
    # squared distances) of two points is at least d^2 / 2, reached only at the midpoint; the mean must reach it
    d = float(register_trajectories(a, b_star).distance)
    assert min(mean.energies_) <= 1.002 * d**2 / 2
    assert float(register_trajectories(mid, mean.trajectory).distance) < 0.05 * d
    # energies decrease until the round that ends the iteration, and the mean kept is the lowest one's
    e = mean.energies_
    assert all(y <= x * (1 + 1e-9) for x, y in zip(e[:-1], e[1:-1]))
    assert abs(float(mean.registered_.distance.square().sum()) - min(e)) <= 1e-9 * min(e)


def test_mean_warps_stay_centred() -> None:
    """The registrations onto the 4D mean average to the identity warp: without centering the iteration drifted to
    a mean whose warps all sat near 0 until a late time and then jumped to 1 (the mean collapsed in time)."""
    from torch4dtree.data import synthetic_dataset
    from torch4dtree.model import FourDTreeModel

    seqs = [p.sequence for p in synthetic_dataset("tomato", plants=5, seed=0, n_frames=6, T=16)]
    m = FourDTreeModel(ModelSettings(n_t=12)).fit(seqs)
    warp = m.mean.registered_.warp
    grid = torch.linspace(0, 1, warp.shape[1], dtype=warp.dtype)
    assert float((warp.mean(0) - grid).abs().max()) < 0.1, warp
    # no warp spends more than half of the time on the first tenth of the mean's time
    assert bool((warp[:, warp.shape[1] // 2] > 0.1).all()), warp


def test_trajectory_pca_reconstructs_and_modes_follow_the_formula() -> None:
    a = _trajectories(6, seed=2)
    mean = TrajectoryMean().fit(a)
    reg = mean.registered_
    pca = TrajectoryPCA(variance=1.0).fit(reg.registered[:, 0], reg.q_registered)
    z, residual = pca.project(reg.registered[:, 0], reg.q_registered)
    assert float(residual.max()) < 1e-8  # all modes kept: exact
    assert torch.allclose(pca.trajectories(z), reg.registered, atol=1e-8)
    # standardised coefficients: unit sample variance along every mode
    assert torch.allclose(z.var(0), torch.ones(pca.n_modes, dtype=torch.float64), atol=1e-8)
    modes = pca.modes(torch.tensor([-2.0, 0.0, 2.0], dtype=torch.float64), modes=2)
    x = pca.mean + 2 * pca.scales()[1] * pca.components[1]
    from torch4dtree.model import unflatten_srvf
    from torch4dtree.temporal import trajectory_from_srvf

    assert torch.allclose(modes[1, 2], trajectory_from_srvf(*unflatten_srvf(x, a.shape[1], a.shape[2])), atol=1e-10)


# ----------------------------------------------------------------------------- the bundled model


@pytest.fixture(scope="module")
def plants() -> list:
    from torch4dtree.data import synthetic_dataset

    return [p.sequence for p in synthetic_dataset("tomato", plants=4, seed=0, n_frames=4, T=12)]


@pytest.fixture(scope="module")
def model(plants: list) -> FourDTreeModel:
    return FourDTreeModel(ModelSettings(n_t=N_T, medoid_candidates=2)).fit(plants[:3])


def test_model_fit_shapes_and_report(model: FourDTreeModel) -> None:
    k = model.population.k
    assert model.population.trajectories.shape == (3, N_T, k)
    out = model(torch.zeros(2, model.n_modes, dtype=torch.float64))
    assert out.trajectory.shape == (2, N_T, k)
    assert torch.allclose(out.trajectory[0], model.mean.trajectory, atol=1e-10)  # z = 0 is the mean
    assert out.features.shape[:2] == (2, N_T)
    spans = model.population.time_spans
    assert out.times[0] == pytest.approx(float(spans[:, 0].mean()))
    assert out.times[-1] == pytest.approx(float(spans[:, 1].mean()))
    r = model.report_
    assert len(r["temporal_distance_after"]) == 3
    assert all(a <= b + 1e-9 for a, b in zip(r["temporal_distance_after"], r["temporal_distance_before"]))


def test_copies_of_one_4d_tree(plants: list) -> None:
    m = FourDTreeModel(ModelSettings(n_t=N_T, medoid_candidates=1)).fit([plants[0], plants[0]])
    alpha = m.population.trajectories
    assert torch.allclose(alpha[0], alpha[1], atol=1e-9)
    assert torch.allclose(m.mean.trajectory, alpha[0], atol=1e-9)
    assert float(m.pca.explained_variance.max()) < 1e-16


def test_samples_are_valid_and_reproducible(model: FourDTreeModel, tmp_path) -> None:
    g = torch.Generator().manual_seed(7)
    z = model.sample_coefficients(3, g)
    assert float(z.abs().max()) <= float(model.sampler.c)
    seqs = model.decode(z[:2])
    S = model.population.pca.num_slots
    for s in seqs:
        assert len(s) == N_T and s.name.startswith("sample_")
        assert sequence_validity(s) == []
        counts = torch.bincount(s.frames.tree_index, minlength=N_T)
        assert int(counts.max()) <= S
        assert bool((s.frames.branch_lengths() >= 0).all())
        assert bool((s.frames.label >= 0).all()) and int(s.frames.label.max()) < S
    # the same seed: same samples after .to() and after save / load
    again = model.to("cpu").to(torch.float64).sample_coefficients(3, torch.Generator().manual_seed(7))
    assert torch.equal(z, again)
    path = tmp_path / "model.pt"
    model.save(str(path))
    loaded = load(path)
    z2 = loaded.sample_coefficients(3, torch.Generator().manual_seed(7))
    assert torch.equal(z, z2)
    assert torch.equal(loaded(z2).trajectory, model(z).trajectory)
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == "torch4dtree.FourDTreeModel" and raw["version"] == 1 and "args" in raw


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_model_on_gpu(model: FourDTreeModel) -> None:
    z = model.sample_coefficients(3, torch.Generator().manual_seed(1))
    g = model.to("cuda")
    try:
        zc = g.sample_coefficients(3, torch.Generator().manual_seed(1))
        assert zc.device.type == "cuda" and torch.equal(zc.cpu(), z)
        assert torch.allclose(g(zc).trajectory.cpu(), model.to("cpu")(z).trajectory, atol=1e-10)
    finally:
        model.to("cpu")


def test_forward_is_differentiable(model: FourDTreeModel) -> None:
    z = (0.3 * torch.randn(1, model.n_modes, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(model.trajectories, (z,), eps=1e-6, atol=1e-5)
    # optimise coefficients towards a target trajectory through the model
    target = model(torch.full((1, model.n_modes), 0.5, dtype=torch.float64)).trajectory.detach()
    x = torch.zeros(1, model.n_modes, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([x], max_iter=20)

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = (model(x).trajectory - target).square().sum()
        loss.backward()
        return loss

    opt.step(closure)
    assert torch.allclose(x.detach(), torch.full_like(x, 0.5), atol=1e-3)


def test_encode_and_score(model: FourDTreeModel, plants: list) -> None:
    z = model.encode(plants[1])
    assert z.shape == (model.n_modes,)
    typical = model.score(plants[1])
    big = plants[1]
    from torch4dtree.trees.structures import TreeSequence

    abnormal = TreeSequence(big.frames.with_points(big.frames.points * 3), big.times, "giant")
    odd = model.score(abnormal)
    # three times larger: lengths x3, so SRVF-based distances grow by about sqrt(3)
    assert odd.distance > 1.3 * typical.distance
    # its branches still find their slots (positions are relative): the abnormality is mostly outside the modes
    assert odd.residual > 3 * typical.residual and odd.mahalanobis > typical.mahalanobis


def test_forecast_shapes(model: FourDTreeModel, plants: list) -> None:
    seq = plants[3]
    f = model.forecast(seq[[0, 1]], seq.times[2:], n=2, generator=torch.Generator().manual_seed(0), decode=False)
    assert f.trajectory.shape == (2, model.population.k)
    assert f.sample_trajectories.shape == (2, 2, model.population.k)
    assert f.covariance.shape == (model.n_modes, model.n_modes)
    assert bool((torch.linalg.eigvalsh(f.covariance) > 0).all())
    # conditioning shrinks the uncertainty below the prior's
    assert float(torch.linalg.eigvalsh(f.covariance).max()) <= 1 + 1e-9


def _analogue_term(model: FourDTreeModel, seq, observed: int, times: torch.Tensor) -> torch.Tensor | float:
    """The forecast's analogue term of ``seq`` observed over its first ``observed`` frames (0 where it is off)."""
    width, weight, null = model.forecast_analogue.tolist()
    if weight == 0:
        return 0.0
    dist = model._analogue_distances(seq.frames[observed - 1], float(seq.times[observed - 1] - seq.times[0]))
    return weight * model._analogue(dist, times - seq.times[0], width, null)


def test_forecast_carries_the_plants_own_deviation(model: FourDTreeModel, plants: list) -> None:
    """The forecast is the 4D mean at the plant's age plus the fitted per-component share of the plant's deviation
    from it at its last observed frame (plus the analogue term, which depends on distances, not on that deviation):
    a plant seen 1.5 times larger is forecast larger, by that share of the difference."""
    from torch4dtree.trees.structures import TreeSequence

    seq = plants[3]
    big = TreeSequence(seq.frames.with_points(seq.frames.points * 1.5), seq.times, "big")
    gain = model.forecast_gain
    assert gain.shape == (model.population.k,) and gain.tolist() == model.report_["forecast"]["gain"]
    assert bool((gain >= 0).all() and (gain <= 1).all()) and float(gain.max()) > 0
    f = model.forecast(seq[[0, 1]], seq.times[2:], decode=False)
    g = model.forecast(big[[0, 1]], seq.times[2:], decode=False)
    assert f.gain == g.gain == float(gain.mean())
    y = model.population.transform(seq[[0, 1]]).frame_coefficients[-1]
    y_big = model.population.transform(big[[0, 1]]).frame_coefficients[-1]
    own = (g.trajectory - _analogue_term(model, big, 2, seq.times[2:])) \
        - (f.trajectory - _analogue_term(model, seq, 2, seq.times[2:]))
    assert torch.allclose(own, (gain * (y_big - y)).expand_as(f.trajectory), atol=1e-9)
    inverse = model.population.pca.inverse_features
    assert bool((inverse(g.trajectory).norm(dim=-1) > inverse(f.trajectory).norm(dim=-1)).all())


def test_forecast_analogue_term_follows_the_nearest_training_plant(model: FourDTreeModel, plants: list,
                                                                    tmp_path) -> None:
    """The analogue term weighs the training plants by the registered distance of the last observed frame to each
    at that age: a training plant's own frame is nearest to itself, and with a narrow kernel the term is that
    plant's own later deviation from the 4D mean. Its weight and width are the fit's leave-one-out choice (the least
    left-out error; on these three plants it may be 0, the 4D mean's term alone). A checkpoint without the term's
    buffer forecasts without it."""
    ages = torch.tensor([0.0, 1.0, 2.5], dtype=torch.float64)
    for j, seq in enumerate(plants[:3]):
        age = float(seq.times[1] - seq.times[0])
        d = model._analogue_distances(seq.frames[1], age)
        assert d.shape == (3,) and int(d.argmin()) == j, d
        assert torch.isinf(model._analogue_distances(seq.frames[1], age, exclude=j)[j])
        own = model._training_at_age(ages)[j] - model._mean_at_age(ages, 0.0)
        narrow = 1e-9 * float(d.min()) ** 2
        assert torch.allclose(model._analogue(d, ages, narrow, math.inf), own, atol=1e-9)
        # the 4D mean's pseudo-plant nearer than every training plant: the term vanishes
        assert float(model._analogue(d, ages, narrow, 0.25 * float(d.min()) ** 2).abs().max()) < 1e-9
    # the weight comes from the fit's leave-one-out choice among FORECAST_SHRINK
    from torch4dtree.model.fourd import FORECAST_SHRINK

    report = model.report_["forecast"]
    table = report["loo_error"]  # the chosen width's left-out errors, per analogue weight then gain shrink
    assert len(table) == len(FORECAST_SHRINK) and report["analogue"] in FORECAST_SHRINK
    chosen = table[FORECAST_SHRINK.index(report["analogue"])][FORECAST_SHRINK.index(report["shrink"])]
    assert chosen == min(min(row) for row in table), (report["analogue"], report["shrink"], table)
    assert table[1][0] != table[0][0]  # the analogue term enters the left-out errors
    assert model.forecast_analogue.tolist() == [report["width"], report["analogue"], report["null"]]
    # an older checkpoint (no forecast_analogue): the 4D mean plus the gains' term alone, against the model with the
    # term on (the fit's width and null, weight 0.5 if the fit chose 0)
    model = copy.deepcopy(model)
    model.forecast_analogue = torch.tensor([report["width"], report["analogue"] or 0.5, report["null"]],
                                           dtype=torch.float64)
    seq = plants[3]
    assert float(torch.as_tensor(_analogue_term(model, seq, 2, seq.times[2:])).abs().max()) > 1e-6
    path = tmp_path / "model.pt"
    model.save(str(path))
    raw = torch.load(path, weights_only=True)
    del raw["state_dict"]["forecast_analogue"]
    torch.save(raw, path)
    old = load(path)
    assert old.forecast_analogue.tolist() == [0.0, 0.0, 0.0]
    f_old = old.forecast(seq[[0, 1]], seq.times[2:], decode=False)
    f_new = model.forecast(seq[[0, 1]], seq.times[2:], decode=False)
    assert torch.allclose(f_old.trajectory, f_new.trajectory - _analogue_term(model, seq, 2, seq.times[2:]), atol=1e-9)


def test_calibration_writes_left_out_plants_in_the_others_subspace() -> None:
    """The forecast's calibration projects a left-out plant onto the principal subspace of the others' frames (as a
    new plant's encoding is projected onto the fit's): the others' frames stay, a direction none of them has goes,
    and a variance share keeps the fewest components that reach it."""
    from torch4dtree.model.fourd import _subspace_projector

    g = torch.Generator().manual_seed(0)
    x = torch.randn(6, 3, generator=g, dtype=torch.float64) @ torch.randn(3, 10, generator=g, dtype=torch.float64)
    project = _subspace_projector(x, None, 1.0)
    assert torch.allclose(project(x), x, atol=1e-9)
    _, _, vh = torch.linalg.svd(x - x.mean(0))
    other = vh[-1]  # orthogonal to every centred row
    assert torch.allclose(project(x[0] + 5 * other), x[0], atol=1e-9)
    one = _subspace_projector(x, 1, 0.99)(x)
    assert torch.linalg.matrix_rank(one - x.mean(0)) == 1
    assert float((one - x).norm()) > 1e-3


def test_persistence_gains_follow_what_persists() -> None:
    """The forecast's gains: a deviation that persists at half strength in some components gives gains near 0.5
    there and near 0 elsewhere; one that does not persist at all gives the 4D mean (shrink factor 0)."""
    from torch4dtree.model.fourd import persistence_gains

    g = torch.Generator().manual_seed(0)
    d = torch.randn(12, 4, generator=g, dtype=torch.float64)
    keep = torch.tensor([1.0, 1.0, 0.0, 0.0], dtype=torch.float64)
    f = [0.5 * keep * d[i] + 0.05 * torch.randn(3, 4, generator=g, dtype=torch.float64) for i in range(12)]
    gain, shrink, errors = persistence_gains(d, f)
    assert shrink == 1.0 and errors[-1] < 0.5 * errors[0]
    assert torch.allclose(gain[:2], torch.full((2,), 0.5, dtype=torch.float64), atol=0.05)
    assert bool((gain[2:] < 0.05).all())
    f = [torch.randn(3, 4, generator=g, dtype=torch.float64) for _ in range(12)]
    gain, shrink, errors = persistence_gains(d, f)
    assert shrink == 0.0 and bool((gain == 0).all()) and errors[0] == min(errors)
    gain, shrink, _ = persistence_gains(d[:1], f[:1])  # one plant: nothing to validate on
    assert shrink == 0.0 and bool((gain == 0).all())


@pytest.mark.parametrize("kind", ["tomato", "maize"])
def test_forecast_beats_baselines(kind: str) -> None:
    """Issue 13's must-hold on 13 held-out synthetic plants of each kind (fit on 7).

    ``benchmarks/bench_forecast.py --plants 20`` (this setting), seeds 3-8: tomato wins 6 / 6, +1.3 % .. +9.1 %
    (seed 3: +7.0 %; the forecast before the analogue term: 5 / 6, mean +0.8 %, seed 3 +2.0 %). 13 plants, not 5:
    a seed's margin over 5 plants varies by several % (single plants gain or lose 10-20 %), as much as the tomato
    effect; over 5 held-out plants tomato wins 15 of seeds 3-20 and loses seed 3 by 0.9 % (worst: seed 12, -13.5 %;
    before: 14 wins, seed 3 +0.2 %). Maize over 5 plants: 18 / 18, +5 % .. +44 % (before +1 % .. +27 %)."""
    from torch4dtree.data import synthetic_dataset

    seqs = [p.sequence for p in synthetic_dataset(kind, plants=20, seed=3, n_frames=6, T=16)]
    m = FourDTreeModel(ModelSettings(n_t=16)).fit(seqs[:7])
    # the leave-one-out over 7 plants keeps the analogue term (weight 0.25 or 0.5, rank / 12 or nodes / 100)
    assert m.report_["forecast"]["analogue"] > 0, m.report_["forecast"]
    errs = {"forecast": 0.0, "last": 0.0, "mean": 0.0}
    for h in seqs[7:]:
        half = len(h) // 2
        truth = m.population.transform(h).frame_coefficients[half:]
        f = m.forecast(h[list(range(half))], h.times[half:], decode=False)
        last = m.population.transform(h[list(range(half))]).frame_coefficients[-1]
        u = ((h.times[half:] - h.times[0]) / float(m.duration)).clamp(0, 1)
        pop = time_warp_trajectory(m.mean.trajectory, u.to(m.mean.trajectory))
        for key, x in (("forecast", f.trajectory), ("last", last[None]), ("mean", pop)):
            errs[key] += float((x - truth).norm(dim=-1).mean())
    assert errs["forecast"] < errs["last"] and errs["forecast"] < errs["mean"], errs


# ----------------------------------------------------------------------------- checkpoints


def test_bad_checkpoints_fail_clearly(model: FourDTreeModel, tmp_path, capsys) -> None:
    good = tmp_path / "good.pt"
    model.save(str(good))
    data = good.read_bytes()
    (tmp_path / "truncated.pt").write_bytes(data[: len(data) // 2])
    (tmp_path / "corrupt.pt").write_bytes(bytes(range(256)) * 10)
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")
    for name in ("truncated", "corrupt", "foreign", "missing"):
        with pytest.raises(CheckpointError, match=name):
            load(tmp_path / f"{name}.pt")
    from torch4dtree.cli.main import main

    capsys.readouterr()
    assert main(["sample", str(tmp_path / "truncated.pt"), "--out", str(tmp_path / "s"), "--video", "none"]) == 2
    err = capsys.readouterr().err
    assert "not a readable torch4dtree checkpoint" in err and "Traceback" not in err
    with pytest.raises(FileExistsError):
        model.save(str(good))


def test_large_batches_of_trajectories_equal_small_ones() -> None:
    """Batches above SAMPLE_CHUNK are decoded in chunks: the same trajectories as row by row, any leading dims."""
    from torch4dtree.model.trajectory import SAMPLE_CHUNK

    a = _trajectories(6, seed=2)
    reg = TrajectoryMean().fit(a).registered_
    pca = TrajectoryPCA().fit(reg.registered[:, 0], reg.q_registered)
    z = torch.randn(2, SAMPLE_CHUNK + 3, pca.n_modes, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    rows = torch.stack([torch.cat([pca.trajectories(c) for c in x.split(100)]) for x in z])
    assert torch.allclose(pca.trajectories(z), rows, atol=1e-12)


def test_sequences_at_another_resolution_are_encoded_at_the_fits(model: FourDTreeModel, plants: list) -> None:
    """Frames read with another T than the fit's (a checkpoint without its config makes the CLI read them at the
    default T) are resampled to the layout's T, not failed on with a shape error deep inside."""
    from torch4dtree.trees.structures import TreeSequence

    seq = plants[1]
    fine = TreeSequence(seq.frames.resample(3 * seq.frames.T), seq.times, seq.name)
    z, z_fine = model.encode(seq), model.encode(fine)
    assert z_fine.shape == z.shape and torch.allclose(z_fine, z, atol=0.05 * float(z.abs().max()) + 1e-6)
    f = model.forecast(fine[[0, 1]], seq.times[2:], decode=False)
    assert f.trajectory.shape[-1] == model.population.k


def test_samples_are_new_plants_not_copies() -> None:
    """Issue 13's must-hold on a 20-plant synthetic set: no sample is closer to a training plant (4D distance after
    temporal registration in the model's tree space) than the median nearest-neighbour distance between training
    plants divided by 4 (about 20 s; benchmarks/bench_model.py runs the same at T = 64)."""
    from torch4dtree.data import synthetic_dataset
    from torch4dtree.evaluate.generative_metrics import distance_matrix, novelty

    seqs = [p.sequence for p in synthetic_dataset("tomato", plants=20, seed=0, n_frames=6, T=16)]
    m = FourDTreeModel(ModelSettings(n_t=16)).fit(seqs)
    train = m.population.trajectories.detach()
    z = m.sample_coefficients(200, torch.Generator().manual_seed(1))
    nov = novelty(distance_matrix(m.trajectories(z).detach(), train), distance_matrix(train))
    assert nov["threshold"] > 0 and nov["share_closer"] == 0.0, nov
    # and the check can fail: the training plants themselves (memorisation) are all within the threshold
    memorised = novelty(distance_matrix(train, train), distance_matrix(train))
    assert memorised["share_closer"] == 1.0, memorised


def test_old_style_checkpoint_args_load_into_the_settings(model: FourDTreeModel, plants: list, tmp_path) -> None:
    """A checkpoint whose ``args`` are the flat constructor keywords (``registration`` / ``temporal`` dicts,
    ``positions`` / ``cross_lp`` / ``cross_order_tol`` at the top level) rebuilds the same settings and outputs."""
    from torch4dtree.settings import CrossSettings, RegistrationSettings, TemporalSettings

    path = tmp_path / "old.pt"
    model.save(str(path))
    raw = torch.load(path, weights_only=True)
    s = model.settings
    raw["args"] = {"lambdas": list(s.lambdas), "rotation": s.rotation, "n_t": s.n_t,
                   "tree_components": s.tree_components, "tree_variance": s.tree_variance,
                   "medoid_candidates": s.medoid_candidates, "registration": {"neighbourhood": 4}, "modes": s.modes,
                   "mode_variance": s.mode_variance, "c": s.c, "mean_iters": s.mean_iters, "temporal": {},
                   "positions": s.cross.positions, "cross_lp": s.cross.lp, "cross_order_tol": s.cross.order_tol}
    torch.save(raw, path)
    old = load(path)
    assert old.settings == model.settings
    assert isinstance(old.settings.registration, RegistrationSettings)
    assert isinstance(old.settings.cross, CrossSettings) and isinstance(old.settings.temporal, TemporalSettings)
    z = torch.randn(3, model.n_modes, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert torch.equal(old(z).trajectory, model(z).trajectory)
    assert torch.equal(old.encode(plants[3]), model.encode(plants[3]))
    raw["args"]["registration"] = {"neighbourhod": 4}
    torch.save(raw, path)
    with pytest.raises(CheckpointError, match="neighbourhod"):
        load(path)
