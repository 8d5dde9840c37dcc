"""The figures of ``torch4dtree evaluate`` (rendered for real, offscreen) on a tiny synthetic dataset."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

pytest.importorskip("pyrender")

from torch4dtree.cli import main  # noqa: E402
from torch4dtree.evaluate import EvalSettings, load_eval_data  # noqa: E402
from torch4dtree.evaluate.figures import (  # noqa: E402
    figure_layout,
    index_order_registration,
    line_plot,
    registration_pair,
    registration_row,
    write_figures,
)

SETTINGS = EvalSettings(T=16, quick=True)
NAMES = ["registration.png", "geodesic4d.png", "samples.png", "mean.png", "modes.png", "samples_paper.png"]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth") / "tomato"
    assert main(["synth", "--kind", "tomato", "--plants", "3", "--frames", "4", "--out", str(root)]) == 0
    return load_eval_data(root, "synthetic", T=SETTINGS.T)


@pytest.fixture(scope="module")
def written(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("figures")
    report: dict = {}
    files = write_figures(report, {"synthetic": data}, SETTINGS, out)
    return report, files


def _read(path) -> np.ndarray:
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))[..., :3]


def _assert_drawn(img: np.ndarray, min_colours: int = 6) -> None:
    """Not blank: a share of non-white pixels and several distinct colours among them."""
    ink = img[(img < 245).any(-1)]
    assert len(ink) > 0.002 * img.shape[0] * img.shape[1]
    # colours, not antialiasing shades of one: quantise before counting
    assert len(np.unique(ink // 32, axis=0)) >= min_colours


def test_every_figure_is_written_small_and_drawn(written):
    report, files = written
    assert [f.rsplit("/", 1)[1] for f in files] == NAMES
    assert "figure_notes" not in report
    assert report["timings"]["figures"]["seconds"] > 0
    for f in files:
        img = _read(f)
        assert img.ndim == 3 and img.dtype == np.uint8
        assert max(img.shape[:2]) < 2000  # a small picture, not a binary blob for the repository
        _assert_drawn(img)


def test_grid_figures_have_the_stated_size(written):
    """Cells of ``figure_layout``: the picture is the grid of cells plus its labels and title (< 200 px)."""
    _, files = written
    lay = figure_layout(SETTINGS)
    path = dict(zip(NAMES, files))
    h, w = _read(path["geodesic4d.png"]).shape[:2]
    rows = 2 * lay.steps  # before and after registration
    assert 0 < w - lay.columns * lay.cell < 200 and 0 < h - rows * lay.cell < 200
    h, w = _read(path["mean.png"]).shape[:2]
    assert 0 < w - lay.columns * lay.cell < 200 and 0 < h - lay.cell < 200
    h, w = _read(path["samples_paper.png"]).shape[:2]
    assert h > 3 * lay.cell // 2  # 3 samples above 3 of the plants the model was fitted on


def test_samples_figure_shows_generated_above_real_at_the_figure_ages(written):
    """samples.png: 3 generated plants then the 3 real ones, one row each, one column per age; cells as tall as
    the plants need (at most the layout's cell), with a label strip each and a scale bar below."""
    from torch4dtree.evaluate.figures import FIGURE_AGES

    _, files = written
    lay = figure_layout(SETTINGS)
    img = _read(dict(zip(NAMES, files))["samples.png"])
    h, w = img.shape[:2]
    assert w <= 300 + len(FIGURE_AGES) * lay.cell and h <= 300 + 6 * 1.5 * lay.cell
    rows_ink = (img < 200).any(-1).any(1)  # rows of pixels with dark ink: plants, labels
    assert rows_ink[-40:].any()  # the scale bar strip at the bottom


def test_registration_figure_matched_branches_share_colours(data, written):
    from torch4dtree.render import UNLABELLED_COLOR, branch_colors, fit_size
    from torch4dtree.trees.registration import register_trees

    lay = figure_layout(SETTINGS)
    plant, k = registration_pair(data)
    a, b = plant.sequence.frames[k], plant.sequence.frames[k + 1]
    res = register_trees(a, b, lambdas=SETTINGS.lambdas)
    row = registration_row(a, b, res, lay.steps)
    assert row.num_trees == lay.steps
    n = row.num_branches.tolist()
    first = [0, *np.cumsum(n).tolist()]
    colours = branch_colors(row, "label")
    ref0 = first[lay.steps - 1]
    assert res.matches and res.unmatched_reference  # the later frame has new branches: both cases are shown
    for i, j in res.matches:
        assert (colours[i] == colours[ref0 + j]).all()
    assert (colours[[ref0 + j for j in res.unmatched_reference]] == UNLABELLED_COLOR).all()
    assert (colours[res.unmatched_moving] == UNLABELLED_COLOR).all()  # (an empty list selects nothing)
    # inside the geodesic a branch is either one of the matched ones or grey
    matched = {j for _, j in res.matches}
    inside = row.label[first[1]:ref0].tolist()
    assert set(inside) <= matched | {-1} and matched & set(inside)
    # the picture is this row, one cell per tree
    h, w = _read(written[1][0]).shape[:2]
    cw, ch = fit_size([row], lay.cell)
    assert w == lay.steps * cw and 0 < h - ch < 200


def test_before_registration_is_the_index_order_state(data):
    """The "before" half of geodesic4d.png is a geodesic as long as register4d's distance before registration."""
    from torch4dtree.temporal import register4d
    from torch4dtree.temporal.registration import register_trajectories

    a, b = data.plants[0].sequence, data.plants[1].sequence
    res = register4d(a, b, n_t=8)
    before = index_order_registration(res)
    d = float(register_trajectories(before.alpha_ref, before.alpha_mov_registered).distance_before)
    assert d == pytest.approx(res.distance_before, rel=1e-9)
    assert torch.equal(before.warp, torch.linspace(0, 1, 8, dtype=before.warp.dtype))
    assert len(before.geodesic(3)) == 3


def test_no_plants_gives_a_note_not_a_crash(tmp_path):
    report: dict = {}
    assert write_figures(report, {}, SETTINGS, tmp_path) == []
    assert report["figure_notes"]


def test_line_plot_draws_curves_with_gaps():
    img = line_plot({"ours": ([0, 1, 2, 3], [0.1, 0.4, math.nan, 0.9]), "paper": ([0, 3], [0.2, 0.5])},
                    title="error vs noise", xlabel="noise", ylabel="error", size=(400, 260))
    assert img.shape == (260, 400, 3) and img.dtype == np.uint8
    _assert_drawn(img, min_colours=3)


def test_robustness_figure_plots_the_report_curves(tmp_path):
    """One panel per perturbation with curves from the report; nothing without a robustness section."""
    from PIL import Image

    from torch4dtree.evaluate.figures import robustness_figure

    assert robustness_figure({}, tmp_path / "none.png") is None and not (tmp_path / "none.png").exists()
    rows = [{"level": lv, "precision": p} for lv, p in ((0.0, 1.0), (0.01, 0.8), (0.05, 0.4))]
    report = {"robustness": {"sources": {"swc": {"tomato": {"curves": {"rule": {"noise": rows, "drop": rows}}}}}}}
    path = robustness_figure(report, tmp_path / "robustness.png")
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape[1] > 1.5 * img.shape[0]  # two panels side by side
    colours = {tuple(c) for c in img.reshape(-1, 3)[::7].tolist()}
    assert len(colours) > 5


def test_ticks_of_a_constant_series_put_it_inside_the_plot():
    """A flat 100 % curve (the split robustness rows) used to get the axis 100-200, drawn on the bottom edge."""
    from torch4dtree.evaluate.figures import nice_ticks

    for v in (100.0, 0.0, -3.0, 1e-4):
        ticks = nice_ticks(v, v)
        assert ticks[0] < v < ticks[-1], (v, ticks)
