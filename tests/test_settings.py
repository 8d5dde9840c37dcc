"""The typed settings (torch4dtree.settings): validation names the setting, dicts round-trip, and the Config that
builds them reads the shipped JSON keys."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from torch4dtree.config import Config, load_config
from torch4dtree.settings import (
    CrossSettings,
    ModelSettings,
    OrganSettings,
    RegistrationSettings,
    TemporalSettings,
)
from torch4dtree.trees.structures import TreeError


@pytest.mark.parametrize(("make", "name"), [
    (lambda: RegistrationSettings(neighbourhood=0), "neighbourhood"),
    (lambda: RegistrationSettings(up=(0, 0, 0)), "up"),
    (lambda: RegistrationSettings(coarse=1), "coarse"),
    (lambda: RegistrationSettings(prune="yes"), "prune"),
    (lambda: CrossSettings(positions="fraction"), "positions"),
    (lambda: CrossSettings(lp=-1.0), "cross_lp"),
    (lambda: CrossSettings(order_tol=float("nan")), "cross_order_tol"),
    (lambda: CrossSettings(fallback_rotation="spin"), "fallback_rotation"),
    (lambda: TemporalSettings(refine=-1), "refine"),
    (lambda: TemporalSettings(backend="gpu"), "backend"),
    (lambda: ModelSettings(n_t=1), "n_t"),
    (lambda: ModelSettings(lambdas=(1.0, 0.0, 1.0)), "lambdas"),
    (lambda: ModelSettings(rotation="spin"), "rotation"),
    (lambda: ModelSettings(tree_variance=1.5), "tree_variance"),
    (lambda: ModelSettings(modes=0), "modes"),
    (lambda: ModelSettings(registration={"neighbourhood": 4}), "registration"),
    (lambda: ModelSettings.from_dict({"n_tt": 4}), "n_tt"),
    (lambda: ModelSettings.from_dict({"cross": {"lp": 1.0}, "cross_lp": 2.0}), "cross_lp"),
    (lambda: OrganSettings(n_ages=1), "n_ages"),
    (lambda: OrganSettings(bandwidth=0), "bandwidth"),
    (lambda: OrganSettings(persistence=-0.1), "persistence"),
    (lambda: OrganSettings(jitter=float("inf")), "jitter"),
    (lambda: OrganSettings(c=0), "c must"),
    (lambda: OrganSettings(registration={"neighbourhood": 4}), "registration"),
    (lambda: OrganSettings.from_dict({"bandwith": 1.0}), "bandwith"),
    (lambda: OrganSettings.from_dict({"registration": {"neighborhood": 4}}), "neighborhood"),
])
def test_bad_values_name_the_setting(make, name):
    with pytest.raises(TreeError, match=name):
        make()


def test_settings_are_frozen_and_round_trip():
    s = ModelSettings(lambdas=[1, 2, 3], n_t=8, registration=RegistrationSettings(up=[0, 1, 0], band=3),
                      cross=CrossSettings(lp=None, fallback_rotation=None), temporal=TemporalSettings(refine=4))
    assert s.lambdas == (1.0, 2.0, 3.0) and s.registration.up == (0.0, 1.0, 0.0)
    d = s.to_dict()
    assert json.loads(json.dumps(d)) == d  # plain JSON values
    assert ModelSettings.from_dict(d) == s
    with pytest.raises(AttributeError):
        s.n_t = 4  # type: ignore[misc]


def test_organ_settings_round_trip():
    s = OrganSettings(n_ages=5, bandwidth=1, persistence=1, registration=RegistrationSettings(up=[0, 1, 0]))
    assert (s.bandwidth, s.persistence) == (1.0, 1.0) and isinstance(s.bandwidth, float)
    d = s.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert OrganSettings.from_dict(d) == s and OrganSettings.from_dict({}) == OrganSettings()
    with pytest.raises(AttributeError):
        s.jitter = 0.0  # type: ignore[misc]


def test_config_chooses_the_model_and_builds_the_organ_settings(tmp_path):
    assert Config().model == "organs"
    cfg = Config(model="organs", organ_bandwidth=1.5, organ_persistence=0.5, organ_jitter=0.0, c=2.0,
                 neighbourhood=6)
    assert cfg.organ_settings() == OrganSettings(bandwidth=1.5, persistence=0.5, jitter=0.0, c=2.0,
                                                 registration=RegistrationSettings(neighbourhood=6))
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    assert load_config(path) == cfg
    for bad, name in (({"model": "fancy"}, "model must be one of"), ({"organ_bandwidth": 0}, "organ_bandwidth"),
                      ({"organ_persistence": 2}, "organ_persistence"), ({"organ_jitter": -1}, "organ_jitter")):
        path.write_text(json.dumps(bad))
        with pytest.raises(TreeError, match=name):
            load_config(path)


def test_config_builds_the_settings_and_round_trips(tmp_path):
    cfg = Config(rotation="vertical", lambdas=(1.0, 1.0, 2.0), neighbourhood=6, cross_positions="arclength",
                 cross_lp=None, cross_order_tol=0.05, n_t=16, modes=3, c=2.5, mean_iters=4)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    back = load_config(path)
    assert back == cfg
    m = back.model_settings()
    assert m.registration == back.registration_settings() == RegistrationSettings(neighbourhood=6)
    assert m.cross == back.cross_settings() == CrossSettings(positions="arclength", lp=None, order_tol=0.05)
    assert (m.lambdas, m.rotation, m.n_t, m.modes, m.c, m.mean_iters) == ((1.0, 1.0, 2.0), "vertical", 16, 3, 2.5, 4)
    for bad, name in (({"neighbourhood": 0}, "neighbourhood"), ({"n_t": 1}, "n_t"), ({"c": -1}, "c must"),
                      ({"mode_variance": 0}, "mode_variance"), ({"cross_lp": "12"}, "cross_lp")):
        path.write_text(json.dumps(bad))
        with pytest.raises(TreeError, match=name):
            load_config(path)


def test_settings_and_config_import_without_torch():
    code = "import sys, torch4dtree.settings, torch4dtree.config; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
