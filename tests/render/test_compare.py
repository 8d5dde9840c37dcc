"""Generated and real plants side by side (render_comparison): one camera, one scale, the same ages."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("pyrender")

from torch4dtree import Trees, TreeSequence  # noqa: E402
from torch4dtree.render.compare import nearest_frames, render_comparison, round_length  # noqa: E402

CELL = 96


def line(a, b, n: int = 16) -> np.ndarray:
    return np.linspace(np.asarray(a, float), np.asarray(b, float), n)


def growing(height: float, offset=(0.0, 0.0, 0.0), name: str = "p", times=(0.0, 1.0, 2.0)) -> TreeSequence:
    """A stem with one leaf that grow linearly to ``height`` at the last time, rooted at ``offset``."""
    o = np.asarray(offset, float)
    frames = []
    for k in range(len(times)):
        h = height * (k + 1) / len(times)
        frames.append([line(o, o + [0, 0, h]), line(o + [0, 0, h / 2], o + [h / 2, 0, h * 0.8])])
    trees = Trees.from_branches(frames, [[-1, 0]] * len(times), T=16)
    return TreeSequence(trees, torch.tensor(times, dtype=torch.float64), name)


def plant_mask(img: np.ndarray) -> np.ndarray:
    return (img < 240).any(-1)


def test_nearest_frames_keeps_every_age():
    assert nearest_frames([0.0, 1.0, 10.0], [0.0, 0.25, 0.5, 1.0]) == [0, 1, 1, 2]  # 1 serves two ages
    assert round_length(99.0) == 50.0 and round_length(1.0) == 1.0


def test_one_scale_twice_as_tall_is_twice_as_tall_in_pixels():
    """A real plant twice the size of a generated one is drawn twice as tall, and a plant far from the origin is
    drawn where it would be at the origin (each plant is moved to its own root)."""
    small, big = growing(10.0, name="small"), growing(20.0, offset=(500.0, -300.0, 40.0), name="big")
    img = render_comparison([small], [big], ages=(1.0,), layout="columns", cell=CELL, fog=0.0)
    heights = [m.shape[0] for m in plants(img, 2)]
    assert heights[1] == pytest.approx(2 * heights[0], rel=0.2)


def plants(img: np.ndarray, n: int) -> list[np.ndarray]:
    """The ``n`` largest connected drawings of ``img`` (the plants; letters are small), as masks cropped to their
    boxes, left to right."""
    from scipy import ndimage

    mask = plant_mask(img)
    lab, count = ndimage.label(ndimage.binary_dilation(mask, iterations=2))
    boxes = ndimage.find_objects(lab)
    sizes = ndimage.sum(np.ones_like(lab), lab, range(1, count + 1))
    big = sorted(np.argsort(sizes)[-n:], key=lambda i: boxes[i][1].start)
    return [mask[boxes[i]] & (lab[boxes[i]] == i + 1) for i in big]


def test_same_plant_as_generated_and_real_gives_the_same_pixels():
    """One camera: the same 4D tree, shown as generated and as real, is drawn alike in its two cells."""
    p = growing(10.0)
    a, b = plants(render_comparison([p], [p], ages=(1.0,), layout="rows", cell=CELL), 2)
    assert a.shape == b.shape and (a != b).sum() <= 0.02 * a.sum()


def test_layouts_swap_rows_and_columns():
    p, q = growing(10.0, name="a"), growing(12.0, name="b")
    rows = render_comparison([p], [q], ages=(0.0, 0.5, 1.0), layout="rows", cell=CELL)
    cols = render_comparison([p], [q], ages=(0.0, 0.5, 1.0), layout="columns", cell=CELL)
    assert rows.shape[1] > rows.shape[0] * 0.8 and cols.shape[0] > cols.shape[1] * 0.8
    with pytest.raises(ValueError):
        render_comparison([p], [q], layout="diagonal")


def test_scale_bar_is_drawn_below_the_grid():
    p = growing(10.0)
    img = render_comparison([p], [], ages=(1.0,), cell=CELL, unit="mm")
    bottom = plant_mask(img[-30:])
    assert bottom.sum() > 20  # the bar and its label
    left = np.nonzero(bottom.any(0))[0]
    assert left.min() < img.shape[1] // 3
