"""Main branches chosen jointly over a growing plant's frames (torch4dtree.trees.growth)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch4dtree.trees.growth import alternative_main_paths, consistent_frames
from torch4dtree.trees.skeleton import skeleton_to_trees


def _stem_with_leaves(forks: list[tuple[int, tuple[float, float, float]]], height: int = 30):
    """A straight stem of ``height`` unit edges up z; at node ``z`` a straight 8-node leaf in ``direction``."""
    xyz = [np.array([0.0, 0.0, float(z)]) for z in range(height + 1)]
    parent = [-1] + list(range(height))
    leaves = {}
    for z, direction in forks:
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        first = len(xyz)
        for i in range(1, 9):
            xyz.append(xyz[z] + i * d)
            parent.append(z if i == 1 else len(xyz) - 2)
        leaves[z] = first
    return np.array(xyz), np.array(parent), leaves


def test_alternatives_leave_the_rules_main_path_at_its_topmost_forks():
    xyz, parent, leaves = _stem_with_leaves([(10, (1, 0, 1)), (20, (-1, 0, 1)), (25, (0, 1, 1))])
    assert len(alternative_main_paths(xyz, parent)) == 4  # the default: the three topmost forks
    paths = alternative_main_paths(xyz, parent, top=2)
    main = paths[0]
    assert main == list(range(31))  # the rule runs up the straight stem
    assert len(paths) == 3  # one other child at each of the forks at z = 25 and z = 20, none at z = 10
    for z, path in zip((25, 20), paths[1:]):  # topmost fork first
        assert path[: z + 1] == main[: z + 1] and path[z + 1] == leaves[z] and len(path) == z + 1 + 8
    assert alternative_main_paths(xyz, parent, top=0) == [main]
    assert len(alternative_main_paths(xyz, parent, top=3)) == 4


def test_without_alternatives_the_frames_are_the_rules():
    from torch4dtree.data import synthetic_plant

    plant = synthetic_plant("maize", 0, n_frames=4, T=12, joint_hierarchy=False)
    joint = consistent_frames(plant.skeletons, T=12, top=0)
    for tree, (xyz, parent, organ) in zip(joint, plant.skeletons):
        alone = skeleton_to_trees(xyz, parent, T=12, node_labels=organ)
        assert torch.equal(tree.points, alone.points) and torch.equal(tree.parent, alone.parent)
        assert torch.equal(tree.label, alone.label)


@pytest.mark.parametrize(("kind", "seed"), [("tomato", 2), ("tomato", 3), ("bean", 1)])
def test_the_main_branch_stays_on_the_stem_over_time(kind, seed):
    """Plants on which the rule alone sends a young frame's main branch into an apex leaf (organ != 0, the stem);
    chosen jointly with the next frames, every frame's main branch ends on the stem."""
    from torch4dtree.data import synthetic_plant
    from torch4dtree.data.truth import main_branch_organs

    alone = main_branch_organs(synthetic_plant(kind, seed, n_frames=10, T=16, joint_hierarchy=False))
    joint = main_branch_organs(synthetic_plant(kind, seed, n_frames=10, T=16))
    assert any(o != 0 for o in alone), alone  # the data is unkind to the rule alone
    assert joint == [0] * len(joint), joint


def test_a_leaf_with_leaflets_at_the_top_does_not_hide_the_stem_fork():
    """Frame 2 of this bean plant: the rule runs up the stem into trifoliate 3, whose two leaflet forks are then the
    main path's two topmost forks, so with ``top=2`` the stem's own fork below them is never reconsidered and the stem
    tip is left as a second branch of the stem (organ 0 names two branches). Three forks reach it."""
    from torch4dtree.data import synthetic_dataset

    def stem_branches(top: int) -> list[int]:
        plant = synthetic_dataset("bean", 1, 0, n_frames=10, T=16, hierarchy_kwargs={"top": top})[0]
        return [int((frame.label == 0).sum()) for frame in plant.sequence.frames]

    assert stem_branches(2)[2] == 2  # the data is unkind to two forks
    assert stem_branches(3) == [1] * 10


def test_reading_a_sequence_folder_chooses_jointly(tmp_path):
    """read_sequence gives an SWC folder's frames as consistent_frames makes them by default, and each file's own tree
    (read_tree) with joint_hierarchy=False."""
    from torch4dtree.data import run_synth
    from torch4dtree.io import LoadOptions, read_sequence, read_swc_skeleton, read_tree

    run_synth(kind="tomato", plants=1, seed=3, out=str(tmp_path / "d"), frames=6)
    folder = next(p for p in (tmp_path / "d").iterdir() if p.is_dir())
    opts = LoadOptions(T=16, labels_from_type=True)
    loaded = read_sequence(folder, opts)
    files = [folder / name for name in loaded.files]
    sks = [read_swc_skeleton(f) for f in files]
    expected = consistent_frames([(sk.xyz, sk.parent, sk.types) for sk in sks], T=16)
    for k, tree in enumerate(expected):
        assert torch.equal(loaded.sequence.frames[k].points, tree.points)
        assert torch.equal(loaded.sequence.frames[k].label, tree.label)
    alone = read_sequence(folder, LoadOptions(T=16, labels_from_type=True, joint_hierarchy=False)).sequence
    for k, f in enumerate(files):
        assert torch.equal(alone.frames[k].points, read_tree(f, opts).points)
