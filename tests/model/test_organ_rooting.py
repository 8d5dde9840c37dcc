"""OrganModel on plants with a frame rooted off the stem (a skeleton rooted at a drooping leaf tip, its lowest node,
as in some Pheno4D scans): that frame's main branch lies flat, and samples copying it collapsed."""

from __future__ import annotations

import torch

from torch4dtree.data.synthetic import synthetic_plant
from torch4dtree.model.organ_table import MIN_RISE, rooted_frames
from torch4dtree.model.organs import OrganModel
from torch4dtree.settings import OrganSettings
from torch4dtree.trees.structures import Trees, TreeSequence


def rise(frames: Trees) -> torch.Tensor:
    """``(n,)`` each frame's main branch chord's vertical share."""
    main = frames.points[frames.ptr[:-1]]
    chord = main[:, -1] - main[:, 0]
    return chord[:, 2] / chord.norm(dim=-1)


def laid_down(seq: TreeSequence, frame: int) -> TreeSequence:
    """``seq`` with frame ``frame`` turned on its side (its main branch horizontal, as a frame rooted at a leaf
    tip reads)."""
    pts = seq.frames.points.clone()
    lo, hi = int(seq.frames.ptr[frame]), int(seq.frames.ptr[frame + 1])
    y, z = pts[lo:hi, :, 1].clone(), pts[lo:hi, :, 2].clone()
    pts[lo:hi, :, 1], pts[lo:hi, :, 2] = z, -y
    return TreeSequence(seq.frames.with_points(pts), seq.times, seq.name)


def plants() -> list[TreeSequence]:
    return [synthetic_plant(kind="tomato", seed=i, n_frames=4, T=16).sequence.to(torch.float64) for i in range(3)]


def test_rooted_frames_leave_out_a_lying_main_branch() -> None:
    seq = plants()[0]
    assert bool((rise(seq.frames) >= MIN_RISE).all())
    assert rooted_frames(seq) == [0, 1, 2, 3]
    assert rooted_frames(laid_down(seq, 3)) == [0, 1, 2]
    lying = laid_down(laid_down(laid_down(seq, 1), 2), 3)
    assert rooted_frames(lying) == [0, 1, 2, 3]  # fewer than two left: all kept


def test_samples_stand_where_a_training_frame_was_rooted_off_the_stem() -> None:
    train = plants()
    train[0] = laid_down(train[0], 3)
    model = OrganModel(OrganSettings(bandwidth=2.0, n_ages=4)).fit(train)
    samples = model.sample(40, generator=torch.Generator().manual_seed(0))
    last = torch.stack([rise(s.frames)[-1] for s in samples])
    assert bool((last >= MIN_RISE).all()), last.min()
    assert abs(float(model.ages[-1]) - 1.0) < 1e-12 and len(samples[0]) == 4


def test_frames_kept_keep_their_ages_on_the_whole_period() -> None:
    from torch4dtree.model.organ_table import plant_organs

    seq = plants()[0]
    u = seq.normalized_times().to(torch.float64)
    organs = plant_organs(laid_down(seq, 3), u[:3])  # the last frame left out, not the time it was taken
    stem = next(o for o in organs if o["key"] == ())
    lengths = seq.frames.branch_lengths()[seq.frames.ptr[:3]]
    expected = (lengths / lengths.max()).to(torch.float64)
    assert torch.allclose(stem["growth"], expected, atol=1e-6), (stem["growth"], expected)
