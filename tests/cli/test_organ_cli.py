"""End to end with the organ model: synth -> fit --model organs -> sample -> forecast, and its checkpoint."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from torch4dtree.cli.main import main
from torch4dtree.io import LoadOptions, read_sequence, sequence_folders, write_sequence
from torch4dtree.model import FourDTreeModel, OrganModel, load


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("organ_ds") / "tomato"
    assert main(["synth", "--kind", "tomato", "--plants", "4", "--frames", "4", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def run(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("organ_run") / "run"
    assert main(["fit", str(dataset), "--model", "organs", "--T", "16", "--out", str(out), "--quiet",
                 "--no-figures"]) == 0
    return out


def test_fit_writes_an_organ_model_run(run: Path) -> None:
    model = load(run / "model.pt")
    assert isinstance(model, OrganModel) and model.is_fitted
    assert model.checkpoint_config["model"] == "organs" and model.checkpoint_config["T"] == 16
    r = json.loads((run / "report.json").read_text())
    assert r["model"] == "organs" and r["dataset"]["sequences"] == 4 and r["organs"]["plants"] == 4
    assert r["organs"]["organs"] >= r["organs"]["keys"] >= 1 and r["seconds"]["fit"] > 0
    assert "OrganModel" in (run / "report.md").read_text()
    assert "organ model" in (run / "fit.log").read_text()
    assert not (run / "samples.png").exists()


def test_sample_writes_readable_plants(run: Path, tmp_path: Path) -> None:
    out = tmp_path / "samples"
    assert main(["sample", str(run / "model.pt"), "--n", "2", "--seed", "1", "--out", str(out), "--video",
                 "none"]) == 0
    model = load(run / "model.pt")
    for k in range(2):
        seq = read_sequence(out / f"sample_{k:03d}", LoadOptions(T=16)).sequence
        assert len(seq) == len(model.ages) and int(seq.frames.num_branches.min()) >= 1
    meta = json.loads((out / "samples.json").read_text())
    assert meta["c"] == model.settings.c and len(meta["coefficients"]) == 2


def test_forecast_continues_a_plant(run: Path, dataset: Path, tmp_path: Path) -> None:
    plant = read_sequence(sequence_folders(dataset)[0], LoadOptions(T=16, dtype=torch.float64)).sequence
    seen = tmp_path / "seen"
    write_sequence(seen, plant[[0, 1]])
    out = tmp_path / "forecast"
    until = float(plant.times[-1]) + 100.0
    assert main(["forecast", str(run / "model.pt"), str(seen), "--until", str(until), "--n", "2", "--out",
                 str(out)]) == 0
    meta = json.loads((out / "forecast.json").read_text())
    assert meta["kind"] == "organs" and meta["continuations"] == ["forecast", "forecast_001", "forecast_002"]
    for name in meta["continuations"]:
        seq = read_sequence(out / name, LoadOptions(T=16)).sequence
        assert len(seq) == len(meta["times"]) >= 1
        assert float(seq.times[0]) > float(plant.times[1])
    # the organ model has no time step: --steps is refused, by name
    assert main(["forecast", str(run / "model.pt"), str(seen), "--until", str(until), "--steps", "3", "--out",
                 str(tmp_path / "f2")]) == 2


def test_fit_organs_with_figures(dataset: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "organs.json"
    cfg.write_text(json.dumps({"model": "organs", "T": 16, "render_size": 64, "organ_bandwidth": 1.0}))
    out = tmp_path / "run"
    assert main(["fit", str(dataset), "--config", str(cfg), "--out", str(out), "--quiet"]) == 0
    assert load(out / "model.pt").settings.bandwidth == 1.0
    assert not (out / "mean.png").exists() and not (out / "modes.png").exists()
    import imageio.v3 as iio

    img = np.asarray(iio.imread(out / "samples.png"))[..., :3].astype(int)
    ink = (np.abs(img - 255).sum(-1) > 60).mean()  # share of pixels that are not background
    assert 0.001 < ink < 0.5
    assert "samples.png" in (out / "report.md").read_text()


def test_model_flag_overrides_the_config(dataset: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "paper.json"
    cfg.write_text(json.dumps({"model": "paper"}))
    out = tmp_path / "run"
    assert main(["fit", str(dataset), "--config", str(cfg), "--model", "organs", "--T", "16", "--out", str(out),
                 "--quiet", "--no-figures"]) == 0
    assert not isinstance(load(out / "model.pt"), FourDTreeModel)
