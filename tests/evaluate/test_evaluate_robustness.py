"""The robustness section of ``torch4dtree evaluate`` (torch4dtree.evaluate.robustness)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import pheno4d

from torch4dtree.evaluate import EvalSettings, dumps, load_eval_data, robustness
from torch4dtree.evaluate.robustness import (
    drop_branches,
    frame_nodes,
    from_polylines,
    perturb,
    split_edges,
    to_trees,
)
from torch4dtree.io import LoadOptions, read_tree
from torch4dtree.trees.registration import register_trees

T = 16


@pytest.fixture(scope="module")
def tiny(synthetic_folder):
    """What ``torch4dtree synth --kind tomato --plants 3 --frames 4`` writes, loaded as the evaluation loads it."""
    return load_eval_data(synthetic_folder(3, 0, 4), "synthetic", T=T)


@pytest.fixture(scope="module")
def skeleton(tiny):
    """The rule-mode nodes of a mid-season synthetic tomato (a few hundred nodes, a dozen branches)."""
    return frame_nodes(tiny.plants[0].files[2])[0]


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_quick_run_zero_and_split_levels(tiny):
    """No perturbation: identities exact and distance ~0 in both modes; every edge split (the geometry unchanged):
    the same, within 1e-9 of a day's growth (float64 resampling noise is ~1e-15 of it)."""
    res = robustness.run({"synthetic": tiny}, EvalSettings(T=T, quick=True))
    assert set(res) == {"robustness", "timings"}
    rob = res["robustness"]
    assert rob["frames_per_kind"] == 1 and rob["levels"] == {k: list(v) for k, v in robustness.QUICK_LEVELS.items()}
    kind = rob["sources"]["synthetic"]["tomato"]
    (frame,) = kind["frames"]
    assert frame["modes"] == ["rule", "fixed"] and frame["day_distance"] > 0 and frame["height"] > 0
    for mode in ("rule", "fixed"):
        curves = kind["curves"][mode]
        assert set(curves) == {"noise", "drop", "split"}
        for name, points in curves.items():
            assert [p["level"] for p in points] == list(robustness.QUICK_LEVELS[name])
            for p in points:
                assert 0 <= p["precision"] <= 1 and 0 <= p["recall"] <= 1 and p["frames"] == 1
        zero, split = curves["noise"][0], curves["split"][-1]
        assert split["level"] == 1.0
        for p in (zero, split):
            assert p["precision"] == 1.0 and p["recall"] == 1.0
            assert p["ratio"]["max"] < 1e-9 and p["branches_mean"] == frame["branches"]
        assert zero["index_precision"] == 1.0 and zero["distance"]["max"] < 1e-9
        assert split["nodes_mean"] > frame["nodes"]  # the nodes were really inserted
        noisy = curves["noise"][-1]
        assert noisy["ratio"]["median"] > 0.05 and noisy["length_ratio_mean"] > 1.0
        assert curves["drop"][-1]["branches_mean"] < frame["branches"]
    json.loads(dumps(res))
    md = robustness.markdown(res)
    assert md[0].startswith("## Robustness") and sum(line.startswith("| synthetic |") for line in md) == 12


def _parent_labels(tree) -> list[int]:
    """Per label (in label order), the label of its parent branch (-1 for the main one)."""
    lab, par = tree.label.tolist(), tree.parent.tolist()
    return [lab[par[i]] if par[i] >= 0 else -1 for i in sorted(range(len(lab)), key=lab.__getitem__)]


def test_labels_are_the_reference_branches(tiny, skeleton):
    ref = to_trees(skeleton, T)  # packed depth-first: the labels are a permutation of the branch indices
    assert sorted(ref.label.tolist()) == list(range(len(skeleton.branch_parent)))
    assert _parent_labels(ref) == list(skeleton.branch_parent)
    # both modes of a skeleton file rebuild this very tree (the fixed one from the branches the rule found)
    rule, fixed = frame_nodes(tiny.plants[0].files[2])
    assert (rule.mode, fixed.mode) == ("rule", "fixed") and fixed.branch_parent == skeleton.branch_parent
    tree = to_trees(fixed, T)
    assert tree.label.tolist() == ref.label.tolist()
    torch.testing.assert_close(tree.points, ref.points, atol=1e-12, rtol=0)
    # a forest of polylines: one chain per branch, labelled by its index
    forest = from_polylines([np.zeros((3, 3)), np.ones((2, 3))], [-1, 0])
    assert forest.parent.tolist() == [-1, 0, 1, -1, 3] and forest.label.tolist() == [0, 0, 0, 1, 1]


def test_split_edges_keeps_the_geometry(skeleton):
    out = split_edges(skeleton, 0.5, _gen())
    n_edges = int((skeleton.parent >= 0).sum())
    assert len(out.xyz) - len(skeleton.xyz) == pytest.approx(0.5 * n_edges, abs=1)
    assert out.xyz[: len(skeleton.xyz)].tolist() == skeleton.xyz.tolist()  # old nodes untouched
    ref, tree = to_trees(skeleton, T), to_trees(out, T)
    a, b = torch.argsort(ref.label), torch.argsort(tree.label)  # the new nodes may reorder siblings
    assert tree.label[b].tolist() == ref.label[a].tolist() and _parent_labels(tree) == _parent_labels(ref)
    torch.testing.assert_close(tree.points[b], ref.points[a], atol=1e-9, rtol=0)
    torch.testing.assert_close(tree.s[b], ref.s[a], atol=1e-9, rtol=0)


def test_drop_branches_leaf_most(skeleton):
    side = sum(p >= 0 for p in skeleton.branch_parent)
    for share in (0.3, 1.0):
        out = drop_branches(skeleton, share, _gen(1))
        kept = set(np.unique(out.label).tolist())
        dropped = set(range(len(skeleton.branch_parent))) - kept
        assert len(dropped) == pytest.approx(share * side, abs=1)
        assert all(skeleton.branch_parent[b] not in dropped for b in kept)  # leaf-most: no orphans
        tree = to_trees(out, T)  # a valid skeleton: the rule derives a tree from it
        assert set(tree.label.tolist()) <= kept
    assert set(np.unique(drop_branches(skeleton, 1.0, _gen()).label).tolist()) == {0}  # only the main branch left


def test_noise_size_and_stochastic_rounding(skeleton):
    assert perturb(skeleton, "noise", 0.0, 100.0, _gen()) is skeleton
    noisy = perturb(skeleton, "noise", 0.01, 100.0, _gen())
    assert np.std(noisy.xyz - skeleton.xyz) == pytest.approx(1.0, rel=0.1)  # sigma = 1 % of 100 mm
    counts = [robustness._count(0.05, 10, _gen(s)) for s in range(400)]
    assert set(counts) == {0, 1} and np.mean(counts) == pytest.approx(0.5, abs=0.1)
    with pytest.raises(ValueError, match="unknown perturbation"):
        perturb(skeleton, "twist", 0.1, 1.0, _gen())


def test_mat_frames_keep_their_hierarchy():
    path = pheno4d("mat", "maize04_seq", "03_17.mat")
    (nodes,) = frame_nodes(path)
    assert nodes.mode == "fixed"
    tree, file_tree = to_trees(nodes, T), read_tree(path, LoadOptions(T=T))
    torch.testing.assert_close(tree.points.float(), file_tree.points, atol=1e-3, rtol=0)
    assert tree.parent.tolist() == file_tree.parent.tolist()
    dropped = to_trees(drop_branches(nodes, 0.5, _gen()), T)  # kept branches keep their parents' identities
    lab, bp = dropped.label.tolist(), nodes.branch_parent
    assert len(lab) < len(bp)
    assert all(bp[lab[i]] == (lab[p] if p >= 0 else -1) for i, p in enumerate(dropped.parent.tolist()))


def test_rule_mode_split_invariance_on_a_young_pheno4d_plant():
    """Every edge split: the same tree (it was 10.7 when the straightest rule's window had a floor of 3 median edges,
    which halved)."""
    path = pheno4d("swc", "tomato_1", "T01_0305_a_seg.swc")
    nodes = frame_nodes(path)[0]
    ref = to_trees(nodes, T)
    tree = to_trees(split_edges(nodes, 1.0, _gen()), T)
    assert float(register_trees(tree, ref).distance) < 1e-9
