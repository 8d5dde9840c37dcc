"""Synthetic growing plants: determinism, growth, label stability, geometry, SWC round trip, ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from torch4dtree.data import (
    evaluate_warp,
    label_layer,
    label_parts,
    plant_seed,
    read_ground_truth,
    relative_warp,
    run_synth,
    sample_growth_warp,
    synthetic_dataset,
    synthetic_plant,
    write_dataset,
)
from torch4dtree.io import LoadOptions, read_dataset, read_sequence
from torch4dtree.trees.structures import Trees

KINDS = ("tomato", "maize")


@pytest.fixture(scope="module")
def plants():
    """Two plants per kind (module-scoped: generation is the slow part)."""
    return {kind: synthetic_dataset(kind, 2, seed=11, n_frames=8) for kind in KINDS}


def _labels(frames: Trees) -> list[list[int]]:
    ptr = frames.ptr.tolist()
    lab = frames.label.tolist()
    return [lab[a:b] for a, b in zip(ptr[:-1], ptr[1:])]


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_identical_different_seed_different(kind):
    a = synthetic_plant(kind, seed=3, n_frames=4)
    b = synthetic_plant(kind, seed=3, n_frames=4)
    c = synthetic_plant(kind, seed=4, n_frames=4)
    fa, fb = a.sequence.frames, b.sequence.frames
    assert torch.equal(fa.points, fb.points) and torch.equal(fa.label, fb.label) and torch.equal(fa.s, fb.s)
    assert torch.equal(a.sequence.times, b.sequence.times) and torch.equal(a.growth_warp, b.growth_warp)
    fc = c.sequence.frames
    assert fc.points.shape != fa.points.shape or not torch.allclose(fc.points, fa.points)
    assert not torch.equal(a.growth_warp, c.growth_warp)


def test_dataset_plants_are_reproducible_alone(plants):
    p = plants["maize"][1]
    alone = synthetic_plant("maize", plant_seed(11, 1), times=p.times)
    assert p.seed == plant_seed(11, 1)
    assert torch.equal(alone.sequence.frames.points, p.sequence.frames.points)


@pytest.mark.parametrize("kind", KINDS)
def test_growth_over_time(plants, kind):
    for p in plants[kind]:
        f = p.sequence.frames
        h = f.height()
        assert (torch.diff(h) > -3 * p.settings["noise"]).all(), h  # noise may jitter a flat stretch
        assert (torch.diff(f.total_length()) > 0).all()
        counts = [sum(layer) for layer in f.branches_per_layer()]
        assert all(x <= y for x, y in zip(counts[:-1], counts[1:])), counts
        layers = f.branches_per_layer()
        if kind == "tomato":
            assert h[-1] > 2 * h[0]
            assert 35 < h[0] < 70 and 170 < h[-1] < 290, h  # Pheno4D tomato: ~45 -> ~230 mm
            assert 6 <= layers[-1][1] <= 20 and len(layers[-1]) in (3, 4), layers[-1]
        else:
            assert 35 < h[0] < 80 and 280 < h[-1] < 430, h  # Pheno4D maize: up to ~360 mm
            assert len(layers[-1]) == 2 and 3 <= layers[-1][1] <= 7, layers[-1]
            assert layers[0][1] >= 1


@pytest.mark.parametrize("kind", KINDS)
def test_heights_strictly_monotone_without_noise(kind):
    p = synthetic_plant(kind, seed=2, n_frames=6, noise=0.0)
    assert (torch.diff(p.sequence.frames.height()) > 0).all()


@pytest.mark.parametrize("kind", KINDS)
def test_labels_stable(plants, kind):
    label_sets = []
    for p in plants[kind]:
        per_frame = _labels(p.sequence.frames)
        for labs in per_frame:
            assert len(set(labs)) == len(labs) and min(labs) >= 0 and labs[0] == 0  # stem first, unique
        for earlier, later in zip(per_frame[:-1], per_frame[1:]):
            assert set(earlier) <= set(later)
        label_sets.append(set(per_frame[-1]))
        # a label's layer is its depth in the tree
        f = p.sequence.frames
        assert [label_layer(x) for x in f.label.tolist()] == f.depth.tolist()
    common = set.intersection(*label_sets)
    assert len(common) >= 0.5 * min(len(s) for s in label_sets)


def test_label_parts():
    assert label_parts(0) == () and label_parts(7) == (7,) and label_parts(305) == (3, 5)
    assert label_parts(30502) == (3, 5, 2) and label_layer(30502) == 3
    with pytest.raises(ValueError):
        label_parts(-1)


@pytest.mark.parametrize("kind", KINDS)
def test_branches_hang_off_parents_and_are_not_degenerate(plants, kind):
    for p in plants[kind]:
        f = p.sequence.frames
        side = f.parent >= 0
        gap = (f.points[:, 0] - f.attachment_points()).norm(dim=-1)
        assert gap[side].max() < 1e-3
        assert (f.s[side] > 0).all() and (f.s[side] < 1).all()
        assert f.branch_lengths().min() > 0.5 * p.settings["min_length"]
        steps = torch.diff(f.points, dim=1).norm(dim=-1)
        assert (steps > 0).all()
        assert torch.isfinite(f.points).all()
        assert (f.points[..., 2] > -1.0).all()  # nothing below the root


def _longest_continuation_ok(f: Trees) -> bool:
    """Every side branch is shorter than the rest of its parent (what the longest-path rule needs)."""
    L = f.branch_lengths()
    gp = f.global_parent
    side = gp >= 0
    rest = (1 - f.s[side]) * L[gp[side]]
    return bool((L[side] < rest).all())


@pytest.mark.parametrize("kind", KINDS)
def test_hierarchy_is_the_longest_path_one(plants, kind):
    for p in plants[kind]:
        assert _longest_continuation_ok(p.sequence.frames)


@pytest.mark.parametrize("kind", KINDS)
def test_write_read_round_trip(plants, kind, tmp_path):
    out = write_dataset(plants[kind], tmp_path / "ds")
    back = read_dataset(out, LoadOptions(labels_from_type=True, dtype=torch.float64))
    assert [b.sequence.name for b in back] == [f"{kind}_00", f"{kind}_01"]
    for p, b in zip(plants[kind], back):
        a, r = p.sequence, b.sequence
        assert len(r) == len(a)
        assert torch.allclose(r.times.float(), a.times)
        for la, lb, fa, fb in zip(_labels(a.frames), _labels(r.frames), a.frames.split(), r.frames.split()):
            assert sorted(la) == sorted(lb)
            pa = dict(zip(la, fa.points))
            pb = dict(zip(lb, fb.points.float()))
            for lab in la:  # same branch, same points (up to float text precision and resampling)
                assert (pa[lab] - pb[lab]).norm(dim=-1).max() < 0.05, (lab, (pa[lab] - pb[lab]).norm(dim=-1).max())
    meta = read_ground_truth(out)
    assert meta["kind"] == kind and meta["seed"] == 11 and len(meta["plants"]) == 2
    rec = meta["plants"][0]
    assert rec["times"] == plants[kind][0].times.tolist() and rec["folder"] == f"{kind}_00"
    assert rec["labels_per_frame"] == plants[kind][0].labels_per_frame()
    assert np.allclose(rec["growth_warp"]["values"], plants[kind][0].growth_warp.numpy())
    # one sequence folder alone reads the same way
    one = read_sequence(out / f"{kind}_01", LoadOptions(labels_from_type=True)).sequence
    assert torch.equal(one.frames.label, back[1].sequence.frames.label)


def test_write_refuses_to_overwrite(tmp_path):
    plants = synthetic_dataset("maize", 2, seed=1, n_frames=3)
    out = tmp_path / "ds"
    write_dataset(plants, out)
    with pytest.raises(FileExistsError):
        write_dataset(plants[:1], out)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError):
        run_synth("maize", 1, 0, str(tmp_path / "other"), frames=3)
    assert (tmp_path / "other" / "notes.txt").read_text() == "mine"
    # with overwrite: one plant now, the stale second plant folder is gone, user files stay
    (out / "readme.txt").write_text("keep")
    run_synth("maize", 1, 5, str(out), frames=3, overwrite=True)
    assert (out / "readme.txt").read_text() == "keep"
    assert [p.sequence.name for p in read_dataset(out)] == ["maize_00"]
    assert json.loads((out / "dataset.json").read_text())["seed"] == 5


def test_run_synth_into_new_folder(tmp_path):
    out = run_synth("tomato", 1, 4, str(tmp_path / "new" / "ds"), frames=3)
    seq = read_sequence(out / "tomato_00", LoadOptions(labels_from_type=True)).sequence
    assert len(seq) == 3 and seq.frames.label.max() > 0


def test_growth_warps_monotone_with_fixed_ends(plants):
    for kind in KINDS:
        for p in plants[kind]:
            h = p.growth_warp
            assert h[0] == 0 and h[-1] == 1 and (torch.diff(h) > 0).all()
            assert torch.allclose(p.warp(p.sequence.normalized_times().double()), p.bio_times)
            assert p.warp(0.0) == 0 and p.warp(1.0) == 1
    rng = np.random.default_rng(0)
    warps = [sample_growth_warp(rng)[1] for _ in range(20)]
    assert max(np.abs(w - np.linspace(0, 1, len(w))).max() for w in warps) > 0.08  # not all identities
    grid, h = sample_growth_warp(rng, grid_size=11)
    assert len(grid) == 11 and (np.diff(h) > 0).all()
    flat = synthetic_plant("maize", 0, n_frames=3, warp_strength=0.0)
    assert torch.allclose(flat.growth_warp, flat.growth_grid)
    assert torch.allclose(evaluate_warp(torch.tensor([0.0, 1.0]), torch.tensor([0.0, 1.0]), 0.25),
                          torch.tensor(0.25, dtype=torch.float64))


def test_given_times_and_bad_arguments():
    p = synthetic_plant("maize", 0, times=[3.0, 4.5, 9.0])
    assert p.times.tolist() == [3.0, 4.5, 9.0] and len(p.sequence) == 3
    assert p.bio_times[0] == 0 and p.bio_times[-1] == 1
    with pytest.raises(ValueError, match="kind"):
        synthetic_plant("oak", 0)
    with pytest.raises(ValueError, match="increasing"):
        synthetic_plant("maize", 0, times=[1.0, 1.0, 2.0])
    with pytest.raises(ValueError):
        synthetic_dataset("maize", 0, seed=0)


def test_relative_warp_is_the_developmental_correspondence(plants):
    a, b = plants["tomato"]
    t = torch.linspace(0, 1, 33, dtype=torch.float64)
    xi = relative_warp(a, b, t)
    assert xi[0] == 0 and xi[-1] == 1 and (torch.diff(xi) > 0).all()
    assert torch.allclose(b.warp(xi), a.warp(t), atol=1e-12)
    assert torch.allclose(relative_warp(a, a, t), t, atol=1e-12)
    assert torch.allclose(a.warp_inverse(a.warp(t)), t, atol=1e-12)


def test_read_ground_truth_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_ground_truth(tmp_path)
    (tmp_path / "dataset.json").write_text("{not json")
    with pytest.raises(ValueError, match="JSON"):
        read_ground_truth(tmp_path)
    (tmp_path / "dataset.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(ValueError, match="synthetic"):
        read_ground_truth(tmp_path)
