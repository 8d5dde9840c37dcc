"""The cross-sequence registrations' settings (positions, cross_lp, cross_order_tol): they reach register4d's and
Population's registrations (and only those: within a sequence register_sequence keeps its own), travel in configs and
checkpoints, old checkpoints load as fitted (warped positions, any order), and the default keeps organs of different
plants matched to their own kind, in their order along the stem."""

from __future__ import annotations

import json

import pytest
import torch

from torch4dtree import settings as settings_module
from torch4dtree.config import Config, load_config
from torch4dtree.data import synthetic_dataset
from torch4dtree.evaluate import truth
from torch4dtree.model import FourDTreeModel
from torch4dtree.settings import CrossSettings, ModelSettings, RegistrationSettings
from torch4dtree.temporal import population as population_module
from torch4dtree.temporal import spatiotemporal as spatiotemporal_module
from torch4dtree.temporal.population import Population
from torch4dtree.temporal.spatiotemporal import register4d, representative_tree
from torch4dtree.trees import registration as registration_module

ARC = CrossSettings(positions="arclength", lp=60.0, order_tol=0.1)


@pytest.fixture(scope="module")
def plants() -> list:
    return [p.sequence for p in synthetic_dataset("bean", plants=3, seed=0, n_frames=3, T=12)]


def _spy_registrations(monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """Record the keyword arguments of every tree registration (:meth:`RegistrationSettings.register`)."""
    calls: list[dict] = []
    original = RegistrationSettings.register

    def wrapped(self: RegistrationSettings, *args: object, **kwargs: object) -> object:
        calls.append(kwargs)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(RegistrationSettings, "register", wrapped)
    return calls


def _spy(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[dict]:
    """Record the keyword arguments of every call of ``module.name``."""
    calls: list[dict] = []
    original = getattr(module, name)

    def wrapped(*args: object, **kwargs: object) -> object:
        calls.append(kwargs)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, wrapped)
    return calls


def test_population_cross_registrations_use_the_setting(plants, monkeypatch):
    search = RegistrationSettings(neighbourhood=3)
    cross = _spy_registrations(monkeypatch)
    within = _spy(monkeypatch, population_module, "register_sequence")
    pop = Population(n_t=4, medoid_candidates=2, registration=search, cross=ARC).fit(plants)
    # within a sequence: register_sequence's own positions and order, the shared search settings
    assert within and all(set(kw) == {"progress", "registration"} and kw["registration"] is search for kw in within)
    cross = [kw for kw in cross if kw["positions"] != settings_module.SEQUENCE_POSITIONS]  # not within-sequence
    assert cross and all(kw["positions"] == "arclength" and kw["order_tol"] == 0.1 for kw in cross)
    rep = pop.report_["cross_registration"]
    assert rep["positions"] == "arclength" and rep["order_tol"] == 0.1
    # lp 60 relative for the registrations, the space keeps lp 1 relative: the same length scale (median)
    assert rep["lambdas"][2] == pytest.approx(60.0 * pop.lambdas_[2])
    # transform registers a new plant with the same settings
    calls = _spy_registrations(monkeypatch)
    pop.transform(plants[0])
    calls = [kw for kw in calls if kw["positions"] != settings_module.SEQUENCE_POSITIONS]
    assert len(calls) == 1 and calls[0]["positions"] == "arclength" and calls[0]["order_tol"] == 0.1


def test_population_fit_differs_with_arclength_positions(plants):
    default = Population(n_t=4, medoid_candidates=1).fit(plants)
    arc = Population(n_t=4, medoid_candidates=1, cross=CrossSettings(positions="arclength")).fit(plants)
    assert default.report_["cross_registration"]["positions"] == settings_module.CROSS_POSITIONS
    assert default.report_["cross_registration"]["order_tol"] == settings_module.CROSS_ORDER_TOL
    # the same weights, other position features: the registered distances differ
    assert default.report_["cross_registration"]["lambdas"] == arc.report_["cross_registration"]["lambdas"]
    assert default.report_["cross_distance_after"] != pytest.approx(arc.report_["cross_distance_after"], rel=1e-6)


def test_register4d_cross_registration_uses_the_setting(plants, monkeypatch):
    within = _spy(monkeypatch, spatiotemporal_module, "register_sequence")
    calls = _spy_registrations(monkeypatch)
    cross = CrossSettings(positions="arclength", lp=60.0, order_tol=None)
    r = register4d(plants[0], plants[1], n_t=4, cross=cross)
    calls = [kw for kw in calls if kw["positions"] != settings_module.SEQUENCE_POSITIONS]  # not within-sequence
    assert calls and all(kw["positions"] == "arclength" and kw["order_tol"] is None for kw in calls)
    assert within and all(set(kw) == {"progress", "registration"} for kw in within)
    assert r.cross_registration["positions"] == "arclength" and r.cross_registration["order_tol"] is None
    default = register4d(plants[0], plants[1], n_t=4)
    assert default.cross_registration["positions"] == settings_module.CROSS_POSITIONS
    # lp relative to the same length: the effective lp scales with cross_lp (None: the space's lp = 1)
    assert r.cross_registration["lambdas"][2] == pytest.approx(
        60.0 / (settings_module.CROSS_LP or 1.0) * default.cross_registration["lambdas"][2])
    space = register4d(plants[0], plants[1], n_t=4, cross=CrossSettings(lp=None))
    assert r.cross_registration["lambdas"][2] == pytest.approx(60.0 * space.cross_registration["lambdas"][2])
    with pytest.raises(ValueError, match="positions"):
        CrossSettings(positions="fraction")
    with pytest.raises(ValueError, match="cross_lp"):
        CrossSettings(lp=-1.0)
    for bad in (-0.1, float("nan"), True):
        with pytest.raises(ValueError, match="cross_order_tol"):
            CrossSettings(order_tol=bad)


def test_config_round_trip_and_literals(tmp_path):
    assert settings_module.POSITIONS == registration_module.POSITIONS
    assert settings_module.DEFAULT_POSITIONS == registration_module.DEFAULT_POSITIONS == Config().positions
    cfg = Config(cross_positions="arclength", cross_lp=60, cross_order_tol=None)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    back = load_config(path)
    assert back == cfg and back.cross_lp == 60.0
    settings = back.model_settings()
    assert settings.cross == CrossSettings(positions="arclength", lp=60.0, order_tol=None)
    model = FourDTreeModel(settings)
    assert model.population.cross == settings.cross
    for bad in ({"cross_positions": "fraction"}, {"cross_lp": -1}, {"cross_lp": "60"}, {"cross_lp": True},
                {"cross_order_tol": -0.01}, {"cross_order_tol": "0.02"}):
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="cross_"):
            load_config(path)


def test_checkpoint_keeps_the_setting_and_old_ones_load_as_warped(plants, tmp_path):
    from torch4dtree import load

    model = FourDTreeModel(ModelSettings(n_t=4, medoid_candidates=1, cross=ARC)).fit(plants)
    path = tmp_path / "m.pt"
    model.save(str(path))
    loaded = load(path)
    pop, pop0 = loaded.population, model.population
    assert (pop.cross, pop.cross_lambdas_) == (pop0.cross, pop0.cross_lambdas_)
    assert loaded.settings == model.settings and loaded.settings.cross == ARC
    torch.testing.assert_close(loaded.population.transform(plants[2]).trajectory,
                               model.population.transform(plants[2]).trajectory)
    # a checkpoint without the cross settings: no args, no extra-state keys -> warped, the space's lp
    raw = torch.load(path, weights_only=True)
    raw["args"].pop("cross")
    extra = raw["state_dict"]["population._extra_state"]
    for key in ("positions", "cross_lp", "cross_lambdas_", "cross_order_tol"):
        extra.pop(key)
    torch.save(raw, path)
    old = load(path)
    warped = CrossSettings(positions="warped", lp=None, order_tol=None)
    assert old.population.cross == warped and old.settings.cross == warped
    assert old.population.cross_lambdas_ == old.population.lambdas_
    # whatever the constructor's settings: the state fitted without the cross settings wins
    rebuilt = FourDTreeModel(ModelSettings.from_dict({**raw["args"], "cross": ARC.to_dict()}))
    rebuilt.load_state_dict(raw["state_dict"])
    assert rebuilt.population.cross == warped and rebuilt.settings.cross == warped


@pytest.fixture(scope="module")
def beans() -> tuple[list, list]:
    """Three bean plants whose leaves look alike, registered within themselves, and every slot's organ."""
    from torch4dtree.temporal import register_sequence

    plants = synthetic_dataset("bean", plants=5, seed=0, n_frames=6, T=16, dtype=torch.float64)[2:]
    aligned = [register_sequence(p.sequence) for p in plants]
    return aligned, [truth._slot_labels(p, a) for p, a in zip(plants, aligned)]  # reads only p.sequence


def _same_organ(matches: list[tuple[int, int]], organs_b: list[int], organs_a: list[int]) -> list[bool]:
    """Per matched pair (B slot, A slot): the same organ, pairs with a spur (label 99) left out as
    :func:`~torch4dtree.data.identity_scores` does (a spur is no organ)."""
    return [organs_b[b] == organs_a[a] for b, a in matches if 99 not in (organs_b[b], organs_a[a])]


def test_default_cross_registration_keeps_organs_and_their_order(beans):
    """The default (node ranks on the main branch, lp 12, children in their order along the parent) matches every
    organ slot of three pairs to its own organ, and the main branch's matched leaves keep their order up the stem;
    warped positions, lp 10 and any order match leaf 3 to leaf 6 and the like (precision 0.03 / 0.07 / 0.21 on these
    pairs, 1.00 with the default)."""
    aligned, organs = beans
    old_precision = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        r = register4d(aligned[i], aligned[j], rotation="vertical")
        same = _same_organ(r.matches, organs[j], organs[i])
        assert sum(same) >= 0.95 * len(same), (i, j, sum(same), len(same))
        # the main branch's children (slot 0 in both), in A's order along the stem: B's partners do not go down
        rep_a, rep_b = representative_tree(aligned[i]), representative_tree(aligned[j])
        kids = sorted((float(rep_a.s[a]), float(rep_b.s[b])) for b, a in r.matches
                      if int(rep_a.parent[a]) == 0 and int(rep_b.parent[b]) == 0)
        assert len(kids) >= 4
        assert all(y2 >= y1 - 0.02 for (_, y1), (_, y2) in zip(kids, kids[1:])), kids
        old = register4d(aligned[i], aligned[j], rotation="vertical",
                         cross=CrossSettings(positions="warped", lp=10.0, order_tol=None))
        hits = _same_organ(old.matches, organs[j], organs[i])
        old_precision.append(sum(hits) / len(hits))
    assert min(old_precision) < 0.5, old_precision


def test_register4d_keeps_the_registration_organs_at_a_large_lp(beans, monkeypatch):
    """lp 100 leaves spurs and organs at other nodes unmatched, which the 4D distance (lp 1) pays for in full: the
    registration's pairs completed in index order between them (``completed``) still beat the index order, and the
    organs stay matched. Planted bug, no completion: the index order with 4D warps wins (3 of 17 slots the same
    organ)."""
    aligned, organs = beans
    cross = CrossSettings(positions="nodes", lp=100.0)  # the simulator plants' setting across plants
    r = register4d(aligned[0], aligned[1], rotation="vertical", cross=cross)
    same = _same_organ(r.matches, organs[1], organs[0])
    assert r.spatial_candidate.startswith("completed") and sum(same) == len(same) >= 15, (r.spatial_candidate, same)
    assert r.distance_after_spatial < r.distance_before
    monkeypatch.setattr(spatiotemporal_module, "completed_matches", lambda matches, *args: sorted(matches))
    bug = register4d(aligned[0], aligned[1], rotation="vertical", cross=cross)
    same = _same_organ(bug.matches, organs[1], organs[0])
    assert bug.spatial_candidate == "index_order_4d" and sum(same) < 0.5 * len(same), (bug.spatial_candidate, same)


def test_completion_pairs_a_gap_by_place():
    """A gap with more children on one side is paired by place, not from the bottom: B's lowest leaf of a shoot
    matched to a spur below A's lowest leaf (a 4D pair of beans at lp 100 does this), B's two leaves above it go to
    A's leaves at their places (0.56 -> 0.55, 0.77 -> 0.73), not to A's two lowest (every pair shifted by one node).
    Planted bug, the gap paired from the bottom: (3, 3), (4, 4)."""
    parent_b, parent_a = [-1, 0, 1, 1, 1], [-1, 0, 1, 1, 1, 1]
    s_b = [0.0, 0.5, 0.35, 0.56, 0.77]
    s_a = [0.0, 0.5, 0.27, 0.34, 0.55, 0.73]  # 2: a spur, 3-5: leaves
    done = spatiotemporal_module.completed_matches([(0, 0), (1, 1), (2, 2)], parent_b, parent_a, s_b, s_a)
    assert done == [(0, 0), (1, 1), (2, 2), (3, 4), (4, 5)]
    # B's side longer: the same choice from the other side; equal places: extras at the top, as the index order
    assert spatiotemporal_module.gap_pairs([2, 3, 4], [4, 5], s_b, s_a) == [(3, 4), (4, 5)]
    assert spatiotemporal_module.gap_pairs([1, 2, 3], [1, 2], [0.5] * 4, [0.5] * 3) == [(1, 1), (2, 2)]
