"""Rooting SWC skeletons at the stem base (torch4dtree.io.rooting)."""

import warnings

import numpy as np
import pytest
from conftest import pheno4d

from torch4dtree.io import LoadOptions, SWCError, read_sequence, read_swc, read_swc_skeleton, reroot, write_swc
from torch4dtree.io.rooting import ROOTS, main_branch_rise, stem_base
from torch4dtree.trees.structures import TreeError


def plant() -> tuple[np.ndarray, np.ndarray]:
    """A stem (0 -> 100 mm, up) with a leaf that arches out from 20 mm and hangs to 10 mm below the base, and an
    upper leaf; rooted at the stem base (node 0)."""
    xyz = [[0.0, 0.0, 2.0 * k] for k in range(51)]  # nodes 0..50, node 10 at z = 20
    parent = [-1, *range(50)]
    t = np.linspace(0.0, 1.0, 21)[1:]
    prev = 10
    for x, z in zip(40 * t, 20 + 25 * np.sin(np.pi * t) - 30 * t**2):  # out 40 mm, up, then down to z = -10
        xyz.append([x, 0.0, z])
        parent.append(prev)
        prev = len(xyz) - 1
    prev = 30
    for k in range(1, 11):  # an upper leaf, rising
        xyz.append([0.0, 3.0 * k, 60 + 1.5 * k])
        parent.append(prev)
        prev = len(xyz) - 1
    return np.array(xyz), np.array(parent)


def write_skeleton(path, xyz, parent, ids, types, radius):
    index = {i: int(n) for i, n in enumerate(ids)}
    lines = [f"{ids[i]} {types[i]} {x:.6f} {y:.6f} {z:.6f} {radius[i]:.3f} {index[p] if p >= 0 else -1}"
             for i, ((x, y, z), p) in enumerate(zip(xyz, parent))]
    path.write_text("\n".join(lines[::-1]) + "\n")  # rows in any order
    return path


def by_id(sk):
    """The skeleton's parent links as indices in the order of its node ids."""
    order = np.argsort(sk.ids)
    p = sk.parent[order]
    return np.where(p >= 0, np.argsort(order)[np.maximum(p, 0)], -1)


def edges(parent):
    return {frozenset((v, int(p))) for v, p in enumerate(parent) if p >= 0}


def test_a_plant_rooted_at_a_hanging_leaf_tip_is_read_rooted_at_its_base(tmp_path):
    xyz, parent = plant()
    tip = len(parent) - 11  # the hanging leaf's tip, the lowest node
    assert xyz[tip, 2] == xyz[:, 2].min() < 0
    n = len(parent)
    ids, types, radius = 1000 + 3 * np.arange(n), np.arange(n) % 4, 0.5 + np.arange(n) / n
    path = write_skeleton(tmp_path / "leaf_rooted.swc", xyz, reroot(parent, tip), ids, types, radius)
    with pytest.warns(UserWarning, match=rf"leaf_rooted.swc: rooted at the stem base, node 1000 .* node {ids[tip]}"):
        sk = read_swc_skeleton(path)
    order = np.argsort(sk.ids)  # the file's rows are reversed
    back = by_id(sk)
    assert back[0] == -1 and (back == -1).sum() == 1  # rooted at the base
    assert edges(back) == edges(parent)  # the same edges, no node lost
    assert (back == parent).all()  # the base-rooted tree itself
    assert np.allclose(sk.xyz[order], xyz) and (sk.types[order] == types).all()
    assert np.allclose(sk.radius[order], radius, atol=1e-3)
    kept = read_swc_skeleton(path, root="file")
    assert kept.ids[kept.parent == -1].tolist() == [ids[tip]]
    assert main_branch_rise(kept.xyz, kept.parent) < 0.3 < 0.9 < main_branch_rise(sk.xyz, sk.parent)
    with pytest.warns(UserWarning, match="rooted at the stem base"):
        tree = read_swc(path, T=16)  # the main branch is the stem
    assert tree.points[0, 0, 2] == pytest.approx(0.0, abs=1e-5) and tree.points[0, -1, 2] > 90


def test_a_neuron_keeps_its_soma_root(tmp_path):
    soma = "1 1 0 0 50 5 -1\n"  # a soma above three dendrites that hang down and one that rises
    rows = [soma]
    nid = 2
    for dx, dz in ((1, -1), (-1, -1), (0.3, -1.2), (0, 1)):
        prev = 1
        for k in range(1, 30):
            rows.append(f"{nid} 3 {dx * k:.3f} 0 {50 + dz * k * 1.7:.3f} 1 {prev}\n")
            prev, nid = nid, nid + 1
    path = tmp_path / "neuron.swc"
    path.write_text("".join(rows))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no re-rooting warning
        sk = read_swc_skeleton(path)
    assert sk.ids[sk.parent == -1].tolist() == [1]
    single = tmp_path / "soma_one_child.swc"  # a soma with one neurite: still its root under "auto"
    single.write_text(soma + "".join(f"{k} 3 {k:.1f} 0 {50 - 2.0 * k:.1f} 1 {k - 1}\n" for k in range(2, 40)))
    assert read_swc_skeleton(single).ids[read_swc_skeleton(single).parent == -1].tolist() == [1]


def test_round_trip_and_rooted_files_stay(tmp_path):
    xyz, parent = plant()
    n = len(parent)
    path = write_skeleton(tmp_path / "base.swc", xyz, parent, np.arange(1, n + 1), np.zeros(n, int), np.ones(n))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for root in ROOTS:  # a file rooted at its base is left as it is by every choice
            assert by_id(read_swc_skeleton(path, root=root)).tolist() == parent.tolist()
        tree = read_swc(path, T=16)
        again = read_swc(write_swc(tmp_path / "again.swc", tree), T=16)
    assert again.parent.tolist() == tree.parent.tolist()
    assert np.abs(again.points.numpy() - tree.points.numpy()).max() < 1.0  # resampled twice (2 mm nodes)


def test_reroot_keeps_edges_and_fails_clearly():
    _, parent = plant()
    for r in (0, 17, len(parent) - 1):
        p = reroot(parent, r)
        assert p[r] == -1 and (p == -1).sum() == 1 and edges(p) == edges(parent)
        assert (reroot(p, 0) == parent).all()
    with pytest.raises(TreeError, match="cannot root at node index 99"):
        reroot(np.array([-1, 0]), 99)
    with pytest.raises(TreeError, match="cycle"):
        reroot(np.array([-1, 2, 1]), 1)
    with pytest.raises(TreeError, match="root must be one of"):
        LoadOptions(root="lowest")
    with pytest.raises(TreeError, match="3D points"):
        stem_base(np.zeros((3, 2)), np.array([-1, 0, 1]))
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0]])  # drawn flat: nothing rises, the root stays
    assert stem_base(flat, np.array([-1, 0, 1, 1]))[0] == 0


@pytest.mark.parametrize("text, message", [
    ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 3\n3 0 0 0 2 1 2\n", "not connected"),  # a cycle
    ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 -1\n", "2 roots"),
    ("1 0 0 0 0 1 -1\n2 0 0 0 1 1 7\n", "does not exist"),  # cut off
])
def test_bad_files_still_fail_clearly(tmp_path, text, message):
    path = tmp_path / "bad.swc"
    path.write_text(text)
    for root in ROOTS:
        with pytest.raises(SWCError, match=message):
            read_swc_skeleton(path, root=root)


def test_pheno4d_frames_rooted_at_a_hanging_leaf_are_read_at_the_stem_base():
    day = pheno4d("swc", "tomato_2", "T02_0321_a_seg.swc")
    with pytest.warns(UserWarning, match="node 706 .* node 1 "):
        sk = read_swc_skeleton(day)
    assert sk.ids[sk.parent == -1].tolist() == [706]
    folder = pheno4d("swc", "Maize04")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = read_sequence(folder, LoadOptions(T=16)).sequence
    main = seq.frames.points[seq.frames.ptr[:-1]]
    chord = main[:, -1] - main[:, 0]
    assert (chord[:, 2] / chord.norm(dim=-1) > 0.8).all()  # every frame's main branch is the stem


def test_the_root_choice_reaches_the_config_and_the_command_line(tmp_path, capsys):
    import json

    from torch4dtree.cli import main
    from torch4dtree.config import Config

    xyz, parent = plant()
    tip = len(parent) - 11
    n = len(parent)
    path = write_skeleton(tmp_path / "leaf_rooted.swc", xyz, reroot(parent, tip), np.arange(1, n + 1),
                          np.zeros(n, int), np.ones(n))
    assert Config(root="file").load_options().root == "file" and Config().load_options().root == "auto"
    with pytest.raises(TreeError, match="root must be one of"):
        Config(root="soma")
    heights = {}
    for flag in ([], ["--root", "file"]):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert main(["info", str(path), "--T", "16", "--json", *flag]) == 0
        heights[bool(flag)] = json.loads(capsys.readouterr().out)
    # rooted at the base the main branch is the stem; at the hanging tip it is the leaf, so the outputs differ
    assert heights[False] != heights[True]
