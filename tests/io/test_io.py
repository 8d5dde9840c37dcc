import json
import os
import warnings

import numpy as np
import pytest
import torch
from conftest import pheno4d, random_tree_branches

from torch4dtree.curves import project_on_polyline
from torch4dtree.io import (
    DatasetError,
    LoadOptions,
    MatTreeError,
    SWCError,
    read_dataset,
    read_mat_tree,
    read_sequence,
    read_swc,
    read_swc_skeleton,
    time_from_name,
    write_swc,
)
from torch4dtree.trees.skeleton import skeleton_to_branches
from torch4dtree.trees.structures import TreeError, Trees

GOOD = """# a small tree
1 0 0 0 0 1 -1
2 0 0 0 1 1 1
3 0 0 0 2 1 2
4 0 0 0 5 1 3
5 0 1 0 2.2 1 3
6 0 2 0 2.5 1 5
"""


def write(tmp_path, text, name="t.swc"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------------------------------- SWC
def test_read_small_swc(tmp_path):
    t = read_swc(write(tmp_path, GOOD), T=8)
    assert t.num_branches.tolist() == [2]
    assert t.branches_per_layer() == [[1, 1]]
    assert t.s[1].item() == pytest.approx(0.4)  # branch point at z=2 on a main branch of length 5
    torch.testing.assert_close(t.points[1, 0], torch.tensor([0.0, 0.0, 2.0]))


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "empty file"),
        ("# only comments\n\n", "empty file"),
        ("1 0 0 0 0 1\n", r":1: expected 7 columns"),
        ("1 0 0 0 0 1 -1\n2 0 0 x 1 1 1\n", r":2: non-numeric"),
        ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 7\n", r":2: node 2 has parent 7, which does not exist"),
        ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 -1\n", "2 roots"),
        ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 3\n3 0 0 1 1 1 2\n", "cycle through node"),
        ("1 0 0 0 0 1 -1\n2 0 nan 0 1 1 1\n", r":2: node 2 has NaN"),
        ("1 0 0 0 0 1 -1\n2 0 inf 0 1 1 1\n", r":2: node 2 has NaN or infinite"),
        ("1 0 0 0 0 1 -1\n1 0 0 0 1 1 1\n", r":2: duplicate node id 1 \(first on line 1\)"),
        ("1 0 0 0 0 1 -1\n", "single node"),
    ],
)
def test_bad_swc_names_file_and_line(tmp_path, text, message):
    p = write(tmp_path, text, "bad.swc")
    with pytest.raises(SWCError, match=message) as err:
        read_swc(p)
    assert "bad.swc" in str(err.value)


def test_main_branch_named_explicitly(tmp_path):
    p = write(tmp_path, GOOD)
    t = read_swc(p, T=8, main_path=[1, 2, 3, 5, 6])
    torch.testing.assert_close(t.points[0, -1], torch.tensor([2.0, 0.0, 2.5]))
    assert t.branches_per_layer() == [[1, 1]]
    # the side branch keeps its shape (nodes 3 -> 4: straight up, 3 long), moved onto the coarse main branch
    torch.testing.assert_close(t.points[1, -1] - t.points[1, 0], torch.tensor([0.0, 0.0, 3.0]))
    torch.testing.assert_close(t.attachment_points()[1], t.points[1, 0])
    with pytest.raises(SWCError, match="names node 9"):
        read_swc(p, main_path=[1, 9])
    with pytest.raises(TreeError, match="not a chain"):
        read_swc(p, main_path=[1, 3])


def test_degenerate_branch_is_an_error(tmp_path):
    text = "1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 1 1 2\n"  # the only branch has zero length at the end
    text_zero = "1 0 0 0 0 1 -1\n2 0 0 0 0 1 1\n"
    read_swc(write(tmp_path, text, "ok.swc"))  # a repeated node inside a branch is fine
    with pytest.raises(TreeError, match="zero.swc: branch 0 is degenerate"):
        read_swc(write(tmp_path, text_zero, "zero.swc"))


def test_repair_mends_a_cycle_cut_off_from_the_root(tmp_path):
    # nodes 4-5-6 form a cycle that does not reach the root; node 6 sits on top of node 3
    text = "1 0 0 0 0 1 -1\n2 0 0 0 1 1 1\n3 0 0 0 2 1 2\n4 0 0 0 3 1 6\n5 0 0 0 4 1 4\n6 0 0 0 2 1 5\n"
    p = write(tmp_path, text)
    with pytest.raises(SWCError, match="repair"):
        read_swc(p)
    with pytest.warns(UserWarning, match="joined node 6 to node 3"):
        t = read_swc(p, repair=True, T=8)
    assert t.height().item() == pytest.approx(4.0)


def test_swc_round_trip(tmp_path, rng):
    branches, parents = random_tree_branches(rng, n_side=3, depth=3)
    tree = Trees.from_branches([branches], [parents], T=20, labels=[list(range(10, 10 + len(branches)))],
                               dtype=torch.float64)
    path = write_swc(tmp_path / "tree.swc", tree)
    # these random trees' side branches leave in random directions (one may run straighter on than its parent),
    # so the rule that recovers their hierarchy is the longest path (conftest.random_tree_branches)
    back = read_swc(path, T=20, labels_from_type=True, hierarchy="longest").to(torch.float64)
    assert back.num_branches.tolist() == tree.num_branches.tolist()
    # same branches, matched by their ground-truth labels; reading re-resamples the polylines, which
    # moves points along their curve by a small fraction of the node spacing
    order = [back.label.tolist().index(lab) for lab in tree.label.tolist()]
    spacing = tree.branch_lengths() / (tree.T - 1)
    err = (back.points[order] - tree.points).norm(dim=-1).amax(1)
    assert (err < 0.02 * spacing).all()
    torch.testing.assert_close(back.s[order], tree.s, atol=1e-3, rtol=0)
    torch.testing.assert_close(back.label[back.global_parent[order][1:]], tree.label[tree.global_parent[1:]])


def test_write_never_overwrites(tmp_path, rng):
    branches, parents = random_tree_branches(rng)
    tree = Trees.from_branches([branches], [parents], T=10)
    p = tmp_path / "a.swc"
    p.write_text("precious\n")
    with pytest.raises(FileExistsError, match="overwrite"):
        write_swc(p, tree)
    assert p.read_text() == "precious\n"
    write_swc(p, tree, overwrite=True)
    assert read_swc(p, T=10).num_branches.item() == tree.num_branches.item()
    assert not list(tmp_path.glob("*.tmp"))
    umask = os.umask(0)
    os.umask(umask)
    assert p.stat().st_mode & 0o777 == 0o666 & ~umask  # readable like any other file, not mkstemp's 0600


# ------------------------------------------------------------------------------- skeletons
def test_longest_path_rule_and_limits():
    # a main path of length 4 along z, a side branch of length 2 at z=1 carrying a twig, a short spur at z=3
    xyz = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 3], [0, 0, 4],  # 0-4 main
                    [1, 0, 1], [2, 0, 1],  # 5-6 side from node 1
                    [2, 0.5, 1],  # 7 twig from node 6 (length 0.5) ... and 8 continues the side
                    [2.8, 0, 1],
                    [0.1, 0, 3]], float)  # 9 spur from node 3
    parent = np.array([-1, 0, 1, 2, 3, 1, 5, 6, 6, 3])
    polylines, parents, paths = skeleton_to_branches(xyz, parent, hierarchy="longest")
    assert paths[0] == [0, 1, 2, 3, 4]
    assert [1, 5, 6, 8] in paths and [6, 7] in paths and [3, 9] in paths
    assert parents[paths.index([6, 7])] == paths.index([1, 5, 6, 8])
    _, _, p2 = skeleton_to_branches(xyz, parent, max_layers=2, hierarchy="longest")
    assert [6, 7] not in p2 and len(p2) == 3
    _, _, p3 = skeleton_to_branches(xyz, parent, min_branch_length=0.5, hierarchy="longest")
    assert [3, 9] not in p3
    _, _, p4 = skeleton_to_branches(xyz, parent, main_path=[0, 1, 5, 6, 8])
    assert p4[0] == [0, 1, 5, 6, 8] and [1, 2, 3, 4] in p4


# ------------------------------------------------------------------------------ real data
SWC_PLANTS = {"tomato_1": 9, "tomato_2": 11, "Tomato_3": 11, "Tomato_4": 11, "Tomato_5": 11,
              "Maize01": 7, "Maize02": 6, "Maize03": 7, "Maize04": 7}
MAT_PLANTS = {"tom_1_seq": 9, "tom_2_seq": 9, "tom_3_seq": 10, "tom_4_seq": 10, "tom_5_seq": 10,
              "maize01_seq": 7, "maize02_seq": 6, "maize03_seq": 7, "maize04_seq": 5}


def check_plant(seq, min_growth):
    h = seq.frames.height()
    assert h[-1] > min_growth * h[0]  # plants get taller
    assert (h[1:] >= 0.75 * h[:-1]).all()  # never shrink much from one day to the next
    side = seq.frames.parent >= 0
    gp = seq.frames.global_parent[side]
    _, dist = project_on_polyline(seq.frames.points[gp], seq.frames.points[side, 0])
    assert dist.max() < 1e-4  # every branch hangs off a real point of its parent
    counts = [sum(x) for x in seq.frames.branches_per_layer()]
    assert counts[-1] > counts[0]


def test_all_pheno4d_swc_plants():
    root = pheno4d("swc")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = read_dataset(root, LoadOptions(T=32, repair=True))
    assert {ls.sequence.name: len(ls.sequence) for ls in loaded} == SWC_PLANTS
    assert [str(w.message) for w in caught if "repaired" in str(w.message)][0].count("T01_0325") == 1
    for ls in loaded:
        check_plant(ls.sequence, 2.0)
        assert ls.sequence.times[0] >= 60 and (torch.diff(ls.sequence.times) >= 1).all()  # March dates, in days


@pytest.mark.parametrize("name, frames", MAT_PLANTS.items())
def test_pheno4d_mat_plants(name, frames):
    ls = read_sequence(pheno4d("mat", name), LoadOptions(T=32))
    assert len(ls.sequence) == frames and not ls.skipped
    check_plant(ls.sequence, 1.5)


def test_altered_sequences_skip_empty_frames():
    full = read_sequence(pheno4d("mat", "maize01_seq"), LoadOptions(T=16)).sequence
    alt = read_sequence(pheno4d("mat", "maize01_seq_alt"), LoadOptions(T=16))
    assert alt.skipped == ["03_15.mat", "03_21.mat", "03_24.mat"]
    assert set(alt.sequence.times.tolist()) < set(full.times.tolist())


def test_bad_mat_files(tmp_path):
    import scipy.io

    scipy.io.savemat(tmp_path / "other.mat", {"something": np.zeros(3)})
    with pytest.raises(MatTreeError, match=r"other.mat: no variable compTrees"):
        read_mat_tree(tmp_path / "other.mat")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all" * 10)
    with pytest.raises(MatTreeError, match="junk.mat: not a readable MATLAB file"):
        read_mat_tree(tmp_path / "junk.mat")
    scipy.io.savemat(tmp_path / "nan.mat", {"compTrees": {"beta0": np.full((3, 5), np.nan)}})
    with pytest.raises(MatTreeError, match="nan.mat: beta0: NaN"):
        read_mat_tree(tmp_path / "nan.mat")


# --------------------------------------------------------------------------- dataset folders
@pytest.mark.parametrize(
    "name, expected",
    [("03_05.mat", ("date", 65.0)), ("T03_0305_a_seg.swc", ("date", 65.0)), ("frame_7.swc", ("integer", 7.0)),
     ("012.swc", ("integer", 12.0)), ("plant.swc", None)],
)
def test_time_from_name(name, expected):
    assert time_from_name(name) == expected


def test_sequence_folder_manifest_and_errors(tmp_path):
    seq = tmp_path / "plant"
    seq.mkdir()
    for name in ("a.swc", "b.swc"):
        write(seq, GOOD, name)
    with pytest.raises(DatasetError, match="no time in the file name 'a.swc'"):
        read_sequence(seq)
    (seq / "times.json").write_text(json.dumps({"b.swc": 2.5, "a.swc": 0.5}))
    ls = read_sequence(seq, LoadOptions(T=8))
    assert ls.files == ["a.swc", "b.swc"] and ls.sequence.times.tolist() == [0.5, 2.5]
    (seq / "times.json").write_text(json.dumps({"a.swc": 1, "c.swc": 2}))
    with pytest.raises(DatasetError, match="lists c.swc"):
        read_sequence(seq)
    (seq / "times.json").write_text("[1, 2")
    with pytest.raises(DatasetError, match="times.json: expected a JSON object"):
        read_sequence(seq)
    (seq / "times.json").unlink()
    (seq / "a.swc").rename(seq / "0305.swc")
    (seq / "b.swc").rename(seq / "day_3.swc")
    with pytest.raises(DatasetError, match="mix dates"):
        read_sequence(seq)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DatasetError, match="no frame files"):
        read_sequence(empty)
    with pytest.raises(DatasetError, match="no sequence folders"):
        read_dataset(empty)


def test_skeleton_error_reaches_the_user_with_the_file(tmp_path):
    seq = tmp_path / "plant"
    seq.mkdir()
    write(seq, GOOD, "day_1.swc")
    write(seq, "1 0 0 0 0 1 -1\n2 0 0 0 1 1 9\n", "day_2.swc")
    with pytest.raises(SWCError, match=r"day_2.swc:2: node 2 has parent 9"):
        read_sequence(seq)
    assert read_swc_skeleton(seq / "day_1.swc").ids.tolist() == [1, 2, 3, 4, 5, 6]
