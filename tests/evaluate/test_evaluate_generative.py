"""The generative-model section of ``torch4dtree evaluate`` (evaluate/generative.py): metrics on constructed cases,
the ground metric, the split, one quick run on a tiny synthetic dataset (about 30 s), and the plausibility and
novelty checks on a small population."""

from __future__ import annotations

import argparse
import json
import math
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path

import pytest
import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.evaluate import EvalData, EvalSettings, Plant4D, dumps, load_eval_data
from torch4dtree.evaluate import generative as gen
from torch4dtree.evaluate import generative_metrics as metrics
from torch4dtree.evaluate import generative_split as split
from torch4dtree.evaluate.data import MAX_FOLDS, MORPHO_DRAWS, QUICK_MORPHO_DRAWS
from torch4dtree.evaluate.generative_organs import POINT_RULE, RepeatedPairs, encode_plants, event_rates, organ_events
from torch4dtree.evaluate.morphometrics import compare_populations, population_curves
from torch4dtree.model.organs import OrganModel
from torch4dtree.temporal import register_trajectories
from torch4dtree.temporal.population import Population


def _line(points: list[float]) -> torch.Tensor:
    return torch.tensor(points, dtype=torch.float64)


def _metrics(samples: list[float], refs: list[float]) -> dict[str, float]:
    """set_metrics of points on a line (distance |x - y|)."""
    s, r = _line(samples), _line(refs)
    return metrics.set_metrics((s[:, None] - s).abs(), (s[:, None] - r).abs(), (r[:, None] - r).abs())


# ----------------------------------------------------------------------------- metrics on constructed cases


def test_metrics_of_separable_sets() -> None:
    m = _metrics([10.0, 11.0], [0.0, 1.0])
    assert m["nna"] == 1.0  # every point's nearest neighbour is of its own set
    assert m["mmd"] == pytest.approx(9.5)  # (10 + 9) / 2
    assert m["cov"] == 0.5  # both samples are nearest to the reference at 1


def test_metrics_of_a_memorised_set() -> None:
    m = _metrics([5.0, 0.0, 7.0], [0.0, 5.0, 7.0])  # the references themselves, in another order
    assert m == {"mmd": 0.0, "cov": 1.0, "nna": 0.0, "nna_samples": 0.0, "nna_real": 0.0}


def test_metrics_by_hand() -> None:
    # R = {0, 1.5, 10}, S = {2, 11, 12.5}: nearest neighbours R0 -> R1.5 (right), R1.5 -> S2, R10 -> S11, S2 -> R1.5,
    # S11 -> R10 (wrong), S12.5 -> S11 (right): 2 of 6. Samples' nearest references: 1.5, 10, 10 -> 2 of 3.
    m = _metrics([2.0, 11.0, 12.5], [0.0, 1.5, 10.0])
    assert m["nna"] == pytest.approx(1 / 3)
    assert m["nna_samples"] == pytest.approx(1 / 3) and m["nna_real"] == pytest.approx(1 / 3)
    assert m["cov"] == pytest.approx(2 / 3)
    assert m["mmd"] == pytest.approx((2.0 + 0.5 + 1.0) / 3)
    # two pairs of the same set and two mixed pairs: exactly half right
    m = _metrics([10.0, 11.0, 20.5, 30.5], [0.0, 1.0, 20.0, 30.0])
    assert m["nna"] == 0.5
    # a collapsed generator between real plants that are far apart: 50 % by samples 100 % / real 0 %
    m = _metrics([5.0, 5.0], [0.0, 10.0])
    assert (m["nna"], m["nna_samples"], m["nna_real"], m["cov"]) == (0.5, 1.0, 0.0, 0.5)


def test_a_training_plant_at_random_is_drawn_independently() -> None:
    """The memorising baseline draws its samples as a generator does, independently: with as many held-out as
    training plants, drawing without replacement would make every draw the whole training set."""
    idx = gen.training_draws(20, 20, 50, torch.Generator().manual_seed(0))
    assert idx.shape == (50, 20)
    assert sum(len(set(row.tolist())) < 20 for row in idx) >= 45  # a draw of 20 without a repeat: 2e-8
    counts = torch.bincount(idx.reshape(-1), minlength=20)
    assert counts.min() >= 25 and counts.max() <= 75  # uniform: 50 each
    train = torch.zeros(20, 4, 2, dtype=torch.float64)
    _, draws = gen._pool("memorise", None, train, 20, 50, torch.Generator().manual_seed(0))  # the section's row
    assert torch.equal(draws, idx)


def test_novelty_threshold() -> None:
    t = _line([0.0, 4.0, 10.0])  # training nearest neighbours 4, 4, 6: median 4, threshold 1
    s = _line([0.5, 7.0, 12.0])
    n = metrics.novelty((s[:, None] - t).abs(), (t[:, None] - t).abs())
    assert n["threshold"] == 1.0 and n["share_closer"] == pytest.approx(1 / 3) and n["nearest_min"] == 0.5


def test_folds_cover_every_plant_once() -> None:
    for n in (4, 5, 7, 20):
        folds = split.folds_of(n, torch.Generator().manual_seed(3))
        assert sorted(i for f in folds for i in f) == list(range(n))
        assert all(len(f) >= 2 and n - len(f) >= 2 for f in folds)
        assert len(folds) == min(n // 2, MAX_FOLDS)
        assert folds == split.folds_of(n, torch.Generator().manual_seed(3))
    assert split.folds_of(3, torch.Generator()) == []


def _plants(n: int, prefix: str = "p") -> list[Plant4D]:
    seq = synthetic_plant("maize", seed=0, n_frames=2, T=8).sequence
    return [Plant4D("maize", f"{prefix}{i}", seq, [Path(f"/{prefix}/{i}/day_0.swc")]) for i in range(n)]


def test_splits_fit_on_half_or_on_a_given_folder() -> None:
    plants = _plants(40)
    halves = split.splits(plants, EvalSettings(folds=2), torch.Generator().manual_seed(0))
    assert [(len(t), len(h)) for t, h in halves] == [(20, 20), (20, 20)]
    assert {p.name for p in halves[0][1]} == {p.name for p in halves[1][0]}  # each half held out once
    quick = split.splits(plants, EvalSettings(quick=True), torch.Generator().manual_seed(0))
    assert [(len(t), len(h)) for t, h in quick] == [(27, 13)]  # 3 folds, the largest training set
    held = _plants(20, "h")
    assert split.splits(plants[:20], EvalSettings(), torch.Generator(), held) == [(plants[:20], held)]
    assert split.splits(plants[:1], EvalSettings(), torch.Generator(), held) == []
    train, other = EvalData(Path("a"), "folder", plants[:20]), EvalData(Path("b"), "synthetic", held)
    assert split.heldout_by_kind(train, other) == {"maize": held}
    with pytest.raises(ValueError, match="also training plants"):
        split.heldout_by_kind(train, EvalData(Path("b"), "folder", plants[5:7]))
    with pytest.raises(ValueError, match="folds"):
        EvalSettings(folds=1)
    with pytest.raises(ValueError, match="morpho_draws"):
        EvalSettings(morpho_draws=0)
    assert EvalSettings(morpho_draws=7).generative_draws() == 7
    assert EvalSettings(morpho_draws=7, quick=True).generative_draws() == QUICK_MORPHO_DRAWS


def test_cli_split_options(tmp_path: Path) -> None:
    from torch4dtree.cli.evaluate import add_arguments, settings_from_args
    from torch4dtree.cli.options import UsageError

    p = argparse.ArgumentParser()
    add_arguments(p)
    (tmp_path / "train").mkdir()
    (tmp_path / "held").mkdir()
    s = settings_from_args(p.parse_args([str(tmp_path / "train"), "--heldout", str(tmp_path / "held"), "--draws", "7",
                                         "--T", "16"]))
    assert (s.heldout, s.folds, s.morpho_draws, s.T) == (str(tmp_path / "held"), MAX_FOLDS, 7, 16)
    s = settings_from_args(p.parse_args([str(tmp_path / "train"), "--folds", "2"]))
    assert (s.heldout, s.folds, s.morpho_draws) == (None, 2, MORPHO_DRAWS)
    with pytest.raises(UsageError):
        settings_from_args(p.parse_args([str(tmp_path / "train"), "--heldout", str(tmp_path / "held"), "--folds", "2"]))
    with pytest.raises(UsageError):
        settings_from_args(p.parse_args([str(tmp_path / "train"), "--heldout", str(tmp_path / "train")]))
    with pytest.raises(FileNotFoundError):
        settings_from_args(p.parse_args([str(tmp_path / "train"), "--heldout", str(tmp_path / "none")]))


def test_ground_metric_is_symmetric_and_the_better_direction() -> None:
    g = torch.Generator().manual_seed(0)
    t = torch.linspace(0, 1, 16, dtype=torch.float64)[None, :, None]
    a = torch.randn(5, 1, 3, generator=g, dtype=torch.float64) * torch.sin(3 * t) + t
    b = torch.randn(5, 1, 3, generator=g, dtype=torch.float64) * t.square()
    d = metrics.distance4d(a, b)
    assert torch.allclose(d, metrics.distance4d(b, a))
    both = torch.minimum(register_trajectories(a, b).distance, register_trajectories(b, a).distance)
    assert torch.allclose(d, both)
    assert float(metrics.distance4d(a, a).abs().max()) == 0.0 and bool((d > 0).all())
    m = metrics.distance_matrix(a)
    assert torch.equal(m, m.T) and torch.equal(m.diagonal(), torch.zeros(5, dtype=torch.float64))
    assert torch.allclose(metrics.distance_matrix(a, b).diagonal(), d)


def test_ground_metric_does_not_depend_on_the_pairs_per_call(monkeypatch: pytest.MonkeyPatch) -> None:
    g = torch.Generator().manual_seed(1)
    a, b = (torch.randn(7, 8, 4, generator=g, dtype=torch.float64) for _ in range(2))
    whole = metrics.distance4d(a, b)
    monkeypatch.setattr(metrics, "PAIR_VALUES", 2 * 4 * 4 * 3)  # 3 pairs a call
    assert metrics.pairs_per_call(4) == 3
    assert torch.equal(metrics.distance4d(a, b), whole)


def test_ground_metric_in_each_pairs_span_is_the_metric_in_all_coordinates() -> None:
    g = torch.Generator().manual_seed(3)
    a = torch.randn(6, 8, 40, generator=g, dtype=torch.float64).cumsum(1)
    b = a.flip(0) + 0.5 * torch.randn(6, 8, 40, generator=g, dtype=torch.float64).cumsum(1)
    xs, ys = metrics.pair_span(a, b)
    assert xs.shape == (6, 8, 16) and torch.allclose(torch.cdist(xs, ys), torch.cdist(a, b))
    full = torch.minimum(register_trajectories(a, b).distance, register_trajectories(b, a).distance)
    assert torch.allclose(metrics.distance4d(a, b), full, rtol=1e-6, atol=0)
    assert torch.equal(metrics.pair_span(a[..., :16], b[..., :16])[0], a[..., :16])


def test_draws_read_from_a_known_matrix_equal_their_registrations() -> None:
    g = torch.Generator().manual_seed(2)
    pool = torch.randn(6, 8, 5, generator=g, dtype=torch.float64).cumsum(1)
    idx = torch.stack([torch.randperm(6, generator=g)[:4] for _ in range(3)] + [torch.tensor([1, 1, 0, 5])])
    assert torch.equal(metrics.within_draw(pool, idx, metrics.distance_matrix(pool)), metrics.within_draw(pool, idx))
    with pytest.raises(ValueError, match="known distances"):
        metrics.within_draw(pool, idx, torch.zeros(5, 5, dtype=torch.float64))


# ----------------------------------------------------------------------------- the section on a tiny dataset


@pytest.fixture(scope="module")
def report(synthetic_folder) -> dict:
    datas = {"synthetic": load_eval_data(synthetic_folder(5, 0, 5), "synthetic", T=16)}
    return gen.run(datas, EvalSettings(T=16, quick=True), False)


def test_structure_and_timings(report: dict) -> None:
    assert set(report) == {"generative", "timings"}
    g = report["generative"]
    assert g["source"] == "synthetic" and set(g["generators"]) == set(gen.ALL_GENERATORS)
    r = g["kinds"]["tomato"]
    assert r["plants"] == 5 and len(r["folds"]) == 1  # quick: one fold
    fold = r["folds"][0]
    assert len(fold["held_out"]) == 2 and len(fold["train"]) == 3 and not set(fold["held_out"]) & set(fold["train"])
    assert set(r["generators"]) == set(gen.ALL_GENERATORS)
    for stage in ("generative_fit", "generative_mean", "generative_sample", "generative_decode",
                  "generative_organ_fit", "generative_organ_sample", "generative_organ_encode"):
        t = report["timings"][stage]
        assert set(t) == {"seconds", "paper_seconds", "what"} and t["seconds"] > 0
    assert report["timings"]["generative_sample"]["paper_seconds"] == 0.0001
    json.loads(dumps(report))  # JSON-safe
    md = "\n".join(gen.markdown(report))
    assert "### tomato" in md and "Where the models lose" in md and "1-NNA" in md
    assert "| organs |" in md and "forecast of the organ model" in md and "held-out plants |" in md


def test_metrics_finite_and_in_range(report: dict) -> None:
    r = report["generative"]["kinds"]["tomato"]
    for name, m in r["generators"].items():
        assert m["mmd"]["n"] == r["folds"][0]["draws"], name
        assert math.isfinite(m["mmd"]["mean"]) and m["mmd"]["min"] >= 0, name
        for key in ("cov", "nna"):
            assert 0.0 <= m[key]["min"] <= m[key]["max"] <= 1.0, (name, key)
    # the collapsed generator: every draw is the same, and its samples are each other's nearest neighbours
    mean = r["generators"]["mean"]
    assert mean["mmd"]["std"] == 0.0 and mean["cov"]["max"] == 0.5 and mean["nna_samples"]["min"] == 1.0
    for key in ("model", "last", "mean"):
        assert math.isfinite(r["forecast"][key]["mean"]) and r["forecast"][key]["n"] == 2
        # the layout's distance adds what the tree PCA misses: never below the coordinates' distance
        assert r["forecast"][key]["mean"] >= r["forecast"]["tree_pca"][key]["mean"] - 1e-9
    for key, s in r["reconstruction"].items():
        assert math.isfinite(s["mean"]), key
    assert 0.0 <= r["reconstruction"]["outside_share"]["max"] < 1.0
    assert 0.0 <= r["reconstruction"]["off_tree_space_share"]["max"] < 1.0


def test_memorised_training_set_and_reconstruction(report: dict) -> None:
    r = report["generative"]["kinds"]["tomato"]
    # the training set memorised, against itself: every sample on a real plant
    assert r["sanity"] == {"mmd": 0.0, "cov": 1.0, "nna": 0.0}
    fold = r["folds"][0]
    # projecting on the modes never moves a plant farther than the 4D mean is (the DP's tolerance aside)
    for rec, mean in zip(fold["training_reconstruction"], fold["training_to_mean"]):
        assert rec <= 1.02 * mean
    for p in fold["plants"]:
        assert p["reconstruction"] <= 1.02 * p["to_mean"], p["plant"]
    # the training plants are nearly reconstructed (all their variance but the modes dropped), held-out ones not
    assert max(fold["training_reconstruction"]) < min(p["reconstruction"] for p in fold["plants"])


def test_organ_model_rows_exist_and_are_finite(report: dict) -> None:
    r = report["generative"]["kinds"]["tomato"]
    for name in gen.ORGAN_GENERATORS:
        for key in ("mmd", "cov", "nna"):
            assert math.isfinite(r["generators"][name][key]["mean"]), (name, key)
    assert math.isfinite(r["morphometrics"]["organs"]["worst_ratio"]["mean"])
    assert 0.0 <= r["novelty"]["organs"]["share_closer"] <= 1.0
    assert 0.0 <= r["reconstruction"]["outside_keys_share"]["min"] <= r["reconstruction"]["outside_keys_share"]["max"]
    assert r["reconstruction"]["outside_keys_share"]["max"] < 1.0
    for who in gen.EVENT_ROWS:
        e = r["organ_events"][who]
        assert 0.0 <= e["shrink"] <= 1.0 and 0.0 <= e["vanish"] <= 1.0 and e["organ_steps"] > 0, who
    f = r["organ_forecast"]
    assert f["plants"] == 2 and 0 <= f["wins_vs_both"] <= min(f["wins_vs_last"], f["wins_vs_mean"])
    assert f["point"] == POINT_RULE
    for key in ("organs", "organs_mean", "organs_draw", "last", "mean"):
        assert math.isfinite(f[key]["mean"]) and f[key]["min"] >= 0, key


def test_organ_events_count_a_vanishing_organ() -> None:
    plant = synthetic_plant("maize", seed=0, n_frames=3, T=16).sequence
    grown = organ_events(plant)
    assert grown["present"] > 0 and grown["shrink"] == 0
    backwards = type(plant)(plant.frames[[2, 1, 0]], plant.times, plant.name)  # time reversed: organs shrink, vanish
    rev = event_rates([backwards])
    assert rev["vanish"] > 0 or rev["shrink"] > 0


@pytest.mark.parametrize("threads", [False, True])
def test_encoding_once_gives_the_encodings_and_event_rates_of_registering_twice(threads: bool) -> None:
    plants = [synthetic_plant("maize", seed=i, n_frames=3, T=16).sequence for i in range(3)]
    plants.append(plants[0][[0]])  # one frame: encoded, no events
    pop = Population(n_t=4, medoid_candidates=1).fit(plants[:2])
    with ThreadPoolExecutor(2) if threads else nullcontext() as ex:
        encs, aligned = encode_plants(pop, plants, ex)
    assert [a is None for a in aligned] == [False, False, False, True]
    for e, f in zip(encs, pop.transform_many(plants)):
        for x, y in ((e.trajectory, f.trajectory), (e.frame_coefficients, f.frame_coefficients),
                     (e.dropped_sq_norm, f.dropped_sq_norm), (e.aligned.features(), f.aligned.features())):
            assert torch.equal(x, y)
    assert event_rates(plants, aligned) == event_rates(plants)


def test_remembered_pairs_encode_as_the_population_does_and_search_each_pair_once() -> None:
    plants = [synthetic_plant("maize", seed=i, n_frames=4, T=16).sequence for i in range(2)]
    pop = Population(n_t=4, medoid_candidates=1).fit(plants)
    pairs = RepeatedPairs.of(pop.registration)
    plant = plants[1]
    longer = type(plant)(plant.frames[[0, 1, 2, 3, 3]], torch.cat([plant.times, plant.times[-1:] + 1]), plant.name)
    enc = encode_plants(pop, [plant], registration=pairs)[0][0]
    assert len(pairs.memo) == 3  # the three consecutive pairs
    assert torch.equal(enc.aligned.features(), pop.transform(plant).aligned.features())
    again = encode_plants(pop, [longer], registration=pairs)[0][0]
    assert len(pairs.memo) == 4  # only the new pair searched
    assert torch.equal(again.aligned.features(), pop.transform(longer).aligned.features())


# ----------------------------------------------------------------------------- the checks, on a small population


def _plausible(samples: list, real: list) -> bool:
    """evaluate's morphometric plausibility: every median within 0.5-2x of the real plants' and 1-NNA below 90 %."""
    c = compare_populations(population_curves(real), population_curves(samples))
    return c["worst_ratio"] > 0.5 and c["one_nna"] < 0.9


def _copies(samples: list, train: list) -> float:
    """evaluate's novelty check in morphometric space (log curves, standardised by the training plants): the share
    of samples closer to a training plant than the training plants' median nearest-neighbour distance / 4."""
    t = torch.from_numpy(population_curves(train)).log1p().flatten(1)
    s = torch.from_numpy(population_curves(samples)).log1p().flatten(1)
    scale = t.std(0).clamp_min(1e-9)
    return metrics.novelty(torch.cdist(s / scale, t / scale), torch.cdist(t / scale, t / scale))["share_closer"]


def test_the_organ_model_passes_where_a_collapsed_and_a_memorising_generator_fail() -> None:
    plants = [synthetic_plant("bean", seed, n_frames=4, T=16).sequence for seed in range(16)]
    train, held = plants[:8], plants[8:]
    samples = OrganModel().fit(train).sample(16, generator=torch.Generator().manual_seed(3))
    assert _plausible(samples, held) and _copies(samples, train) < 0.5
    middle = sorted(train, key=lambda p: float(p.frames[len(p) - 1].total_length()[0]))[len(train) // 2]
    assert not _plausible([middle] * 16, held)  # collapsed onto one typical plant
    assert _copies(train, train) == 1.0  # memorising: every sample is a training plant
