"""The cross-sequence registrations' settings (positions, cross_lp): they reach register4d's and Population's
registrations (and only those: within a sequence register_sequence keeps its own), travel in configs and
checkpoints, and old checkpoints load as fitted (warped positions)."""

from __future__ import annotations

import json

import pytest
import torch

from torch4dtree import config as config_module
from torch4dtree.config import Config, load_config
from torch4dtree.data import synthetic_dataset
from torch4dtree.model import FourDTreeModel
from torch4dtree.temporal import population as population_module
from torch4dtree.temporal import spatiotemporal as spatiotemporal_module
from torch4dtree.temporal.population import Population
from torch4dtree.temporal.spatiotemporal import register4d
from torch4dtree.trees import registration as registration_module


@pytest.fixture(scope="module")
def plants() -> list:
    return [p.sequence for p in synthetic_dataset("bean", plants=3, seed=0, n_frames=3, T=12)]


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
    cross = _spy(monkeypatch, population_module, "register_to_reference")
    within = _spy(monkeypatch, population_module, "register_sequence")
    pop = Population(n_t=4, medoid_candidates=2, positions="arclength", cross_lp=60.0).fit(plants)
    assert cross and all(kw["positions"] == "arclength" for kw in cross)
    assert within and all("positions" not in kw and "cross_lp" not in kw for kw in within)
    rep = pop.report_["cross_registration"]
    assert rep["positions"] == "arclength"
    # lp 60 relative for the registrations, the space keeps lp 1 relative: the same length scale (median)
    assert rep["lambdas"][2] == pytest.approx(60.0 * pop.lambdas_[2])
    # transform registers a new plant with the same settings
    cross.clear()
    pop.transform(plants[0])
    assert len(cross) == 1 and cross[0]["positions"] == "arclength"


def test_population_fit_differs_with_arclength_positions(plants):
    warped = Population(n_t=4, medoid_candidates=1).fit(plants)
    arc = Population(n_t=4, medoid_candidates=1, positions="arclength").fit(plants)
    assert warped.report_["cross_registration"]["positions"] == "warped"
    # the same weights, other position features: the registered distances differ
    assert warped.report_["cross_registration"]["lambdas"] == arc.report_["cross_registration"]["lambdas"]
    assert warped.report_["cross_distance_after"] != pytest.approx(arc.report_["cross_distance_after"], rel=1e-6)


def test_register4d_cross_registration_uses_the_setting(plants, monkeypatch):
    calls = _spy(monkeypatch, spatiotemporal_module, "register_trees")
    within = _spy(monkeypatch, spatiotemporal_module, "register_sequence")
    r = register4d(plants[0], plants[1], n_t=4, positions="arclength", cross_lp=60.0)
    assert calls and all(kw["positions"] == "arclength" for kw in calls)
    assert within and all("positions" not in kw for kw in within)
    assert r.cross_registration["positions"] == "arclength"
    default = register4d(plants[0], plants[1], n_t=4)
    assert default.cross_registration["positions"] == spatiotemporal_module.CROSS_POSITIONS
    # lp relative to the same length: the effective lp scales with cross_lp (None: the space's lp = 1)
    assert r.cross_registration["lambdas"][2] == pytest.approx(
        60.0 / (spatiotemporal_module.CROSS_LP or 1.0) * default.cross_registration["lambdas"][2])
    space = register4d(plants[0], plants[1], n_t=4, cross_lp=None)
    assert r.cross_registration["lambdas"][2] == pytest.approx(60.0 * space.cross_registration["lambdas"][2])
    with pytest.raises(ValueError, match="positions"):
        register4d(plants[0], plants[1], n_t=4, positions="fraction")
    with pytest.raises(ValueError, match="cross_lp"):
        Population(cross_lp=-1.0)


def test_config_round_trip_and_literals(tmp_path):
    # the config module keeps literals (no torch import): they must equal the library's
    assert config_module.POSITIONS == registration_module.POSITIONS
    assert config_module.DEFAULT_POSITIONS == registration_module.DEFAULT_POSITIONS == Config().positions
    assert config_module.CROSS_POSITIONS == spatiotemporal_module.CROSS_POSITIONS
    assert config_module.CROSS_LP == spatiotemporal_module.CROSS_LP
    cfg = Config(cross_positions="arclength", cross_lp=60)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    back = load_config(path)
    assert back == cfg and back.cross_lp == 60.0
    args = back.model_args()
    assert args["positions"] == "arclength" and args["cross_lp"] == 60.0
    model = FourDTreeModel(**args)
    assert model.population.positions == "arclength" and model.population.cross_lp == 60.0
    for bad in ({"cross_positions": "fraction"}, {"cross_lp": -1}, {"cross_lp": "60"}, {"cross_lp": True}):
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="cross_"):
            load_config(path)


def test_checkpoint_keeps_the_setting_and_old_ones_load_as_warped(plants, tmp_path):
    from torch4dtree import load

    model = FourDTreeModel(n_t=4, medoid_candidates=1, positions="arclength", cross_lp=60.0).fit(plants)
    path = tmp_path / "m.pt"
    model.save(str(path))
    loaded = load(path)
    pop, pop0 = loaded.population, model.population
    assert (pop.positions, pop.cross_lp, pop.cross_lambdas_) == (pop0.positions, pop0.cross_lp, pop0.cross_lambdas_)
    assert loaded.args["positions"] == "arclength" and loaded.args["cross_lp"] == 60.0
    torch.testing.assert_close(loaded.population.transform(plants[2]).trajectory,
                               model.population.transform(plants[2]).trajectory)
    # a checkpoint written before the setting existed: no args, no extra-state keys -> warped, the space's lp
    raw = torch.load(path, weights_only=True)
    for key in ("positions", "cross_lp"):
        raw["args"].pop(key)
    extra = raw["state_dict"]["population._extra_state"]
    for key in ("positions", "cross_lp", "cross_lambdas_"):
        extra.pop(key)
    torch.save(raw, path)
    old = load(path)
    assert old.population.positions == "warped" and old.population.cross_lp is None
    assert old.population.cross_lambdas_ == old.population.lambdas_
    assert old.args["positions"] == "warped"
    # whatever the constructor's default: the state fitted before the setting existed wins
    rebuilt = FourDTreeModel(**{**raw["args"], "positions": "arclength", "cross_lp": 60.0})
    rebuilt.load_state_dict(raw["state_dict"])
    assert rebuilt.population.positions == "warped" and rebuilt.population.cross_lp is None
    assert rebuilt.args["positions"] == "warped" and rebuilt.args["cross_lp"] is None
