"""The fit report's sample figure: samples and real plants at the same ages, at one scale."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import torch

from torch4dtree.data import synthetic_dataset
from torch4dtree.evaluate.model_report import age_columns, write_sample_figure
from torch4dtree.model import OrganModel


def test_age_columns_pick_the_frames_nearest_each_age() -> None:
    seq = synthetic_dataset("tomato", plants=1, seed=2, n_frames=7, T=8)[0].sequence
    t = seq.times.double()
    age = (t - t[0]) / (t[-1] - t[0])
    cols = age_columns(seq, 4)
    picked = [int((age - float((c - t[0]) / (t[-1] - t[0]))).abs().argmin()) for c in cols.times.double()]
    for j, i in zip(np.linspace(0, 1, 4), picked):  # no other frame is nearer to the column's age
        assert abs(float(age[i]) - j) <= float((age - j).abs().min()) + 1e-12


def test_sample_figure_shows_real_plants_below_the_samples(tmp_path) -> None:
    plants = [p.sequence for p in synthetic_dataset("maize", plants=3, seed=0, n_frames=4, T=8, dtype=torch.float64)]
    model = OrganModel().fit(plants)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    alone = iio.imread(write_sample_figure(model, tmp_path / "a", 48, seed=0, n_samples=2))
    beside = iio.imread(write_sample_figure(model, tmp_path / "b", 48, seed=0, n_samples=2, real=plants))
    assert beside.shape[0] > alone.shape[0] + 48  # two more rows of cells
    ink = (np.abs(beside[..., :3].astype(int) - 255).sum(-1) > 60)
    assert ink[-60:].any()  # the bottom row (a real plant) is drawn
