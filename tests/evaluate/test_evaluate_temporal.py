"""Table 3 of `torch4dtree evaluate` (evaluate/temporal.py): structure on a tiny synthetic set, warp direction."""

from __future__ import annotations

import json
import math

import pytest
import torch

from torch4dtree.curves.warps import random_warp
from torch4dtree.evaluate import EvalSettings, Plant4D, dumps, load_eval_data, pairs
from torch4dtree.evaluate import temporal as table3
from torch4dtree.temporal import register_trajectories, resample_trajectory, time_warp_trajectory

SETTINGS = EvalSettings(T=16, quick=True)


@pytest.fixture(scope="module")
def data(synthetic_folder):
    return load_eval_data(synthetic_folder(3, 5, 5), "synthetic", T=16)


@pytest.fixture(scope="module")
def report(data):
    return table3.run({"synthetic": data}, SETTINGS)


def _late_warp(a: float = 1.5) -> table3.PlantWarp:
    """A known smooth warp (the copy shows early frames late: gamma(x) = (e^{a x} - 1) / (e^a - 1))."""
    x = torch.linspace(0, 1, table3.WARP_GRID, dtype=torch.float64)
    return table3.PlantWarp(torch.expm1(a * x) / math.expm1(a), [0, 2, 4], False)


def test_quick_run_structure(report):
    t3 = report["table3"]
    assert t3["source"] == "synthetic" and list(t3["kinds"]) == ["tomato"]
    rows = t3["kinds"]["tomato"]
    assert set(rows) == {key for key, _, _ in table3.ROWS}
    assert rows["pairs"]["n"] == rows["pairs_unsync"]["n"] == 2  # quick: .pairs keeps 2 of the 3 pairs
    assert rows["warped"]["n"] == rows["warped_missing"]["n"] == rows["warped_missing_pipeline"]["n"] == 2
    for key, _, _ in table3.ROWS:
        r = rows[key]
        assert "paper" not in r  # the paper measured Pheno4D, not these plants
        for part in ("before", "after"):
            assert all(math.isfinite(r[part][s]) for s in ("mean", "median", "std"))
        assert r["raised"] == 0 and math.isfinite(r["ratio"])
        assert all(x["after"] <= x["before"] + 1e-9 for x in r["rows"])
    for key in table3.WARPED_ROWS:
        assert all(0 <= x["warp_error"] < 1 and x["identity_error"] > 0 for x in rows[key]["rows"])
        assert all(x["frames"] < x["of"] for x in rows[key]["rows"]) == (key != "warped")
    # same trees, all frames: the registration removes nearly all the distance and finds the warp
    assert rows["warped"]["ratio"] < 0.1
    assert all(x["warp_error"] < 0.2 * x["identity_error"] for x in rows["warped"]["rows"])
    assert all(x["unwarped"] < 1e-9 for x in rows["warped"]["rows"])  # the unwarped copy is the plant
    assert all(x["unwarped"] > 0 for x in rows["warped_missing"]["rows"])
    assert set(report["timings"]) == {"temporal_register_tomato", "table3_pairs_tomato", "table3_warped_tomato"}
    assert all(set(v) == {"seconds", "paper_seconds", "what"} and v["seconds"] > 0 for v in report["timings"].values())
    json.loads(dumps(report))  # strict JSON
    md = "\n".join(table3.markdown(report))
    assert "## Table 3" in md and "(b) warped copy, missing days, whole pipeline" in md


def test_known_warp_is_recovered(data):
    """The copy shows frame j at gamma(u_j); the recovered warp is gamma (forward), far from its inverse."""
    aligned = pairs.aligned_sequence(data, data.plants[0].name)
    warp = _late_warp()
    full, missing = table3.warped_copies(aligned, warp, SETTINGS.n_t)
    assert full["frames"] == 5 and missing["frames"] == 3
    assert full["warp_error"] < 0.01 < full["identity_error"] / 5
    assert full["after"] < 0.05 * full["before"]
    assert missing["warp_error"] < missing["identity_error"] / 2


def test_true_warp_direction():
    """true_warp is the warp register_trajectories returns (mov(xi(t)) = ref(t)), not its inverse."""
    g = torch.Generator().manual_seed(0)
    coeffs = torch.randn(7, 4, generator=g, dtype=torch.float64).cumsum(0)
    u = torch.tensor([0.0, 0.1, 0.25, 0.45, 0.6, 0.8, 1.0], dtype=torch.float64)
    gamma = table3.PlantWarp(random_warp(1, table3.WARP_GRID, generator=g, strength=1.0)[0], [], False)
    s = gamma.at(u)
    n_t = 64
    ref, mov = resample_trajectory(coeffs, u, n_t), resample_trajectory(coeffs, s, n_t)
    truth, inverse = table3.true_warp(u, s, n_t), table3.true_warp(s, u, n_t)
    # mov(xi*(t)) = ref(t) up to the n_t samples (the frames' kinks fall between them)
    at_truth, at_inverse = ((time_warp_trajectory(mov, w) - ref).norm() / ref.norm() for w in (truth, inverse))
    assert float(at_truth) < 0.05 * float(at_inverse)
    rec = register_trajectories(ref, mov).warp
    assert table3.warp_error(rec, truth) < 0.1 * table3.warp_error(rec, inverse)


def test_kept_days(data):
    """Missing days: the altered copy's days where it has one (matched by time), else simulated (ends kept)."""
    plant = data.plants[1]
    g = torch.Generator().manual_seed(0)
    keep, altered = table3._kept_days(plant, g)
    assert not altered and keep[0] == 0 and keep[-1] == len(plant.sequence) - 1 and len(keep) == 4
    with_alt = Plant4D(plant.kind, plant.name, plant.sequence, plant.files, altered=plant.sequence[[0, 2, 4]])
    assert table3._kept_days(with_alt, g) == ([0, 2, 4], True)
    lost_end = Plant4D(plant.kind, plant.name, plant.sequence, plant.files, altered=plant.sequence[[0, 2, 3]])
    assert table3._kept_days(lost_end, g)[1] is False  # no true warp without the last day: simulated instead


def test_unsynchronised_without_warp_is_the_pair(data, report):
    """With the identity warp and no missing days, the re-timed moving plant is the pair's own trajectory."""
    ref, mov, r = pairs.registered_pairs(data, "tomato", SETTINGS)[0]  # cached by the report
    ident = table3.PlantWarp(torch.linspace(0, 1, table3.WARP_GRID, dtype=torch.float64), list(range(len(
        r.sequences[1]))), False)
    res = table3._unsynchronised(r, ident, SETTINGS.n_t)
    assert res["before"] == pytest.approx(r.distance_after_spatial, rel=1e-9)
    assert res["after"] == pytest.approx(r.distance_after_temporal, rel=1e-9)
    assert report["table3"]["kinds"]["tomato"]["pairs"]["rows"][0]["moving"] == mov
