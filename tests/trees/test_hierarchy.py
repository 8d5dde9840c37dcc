"""Branch hierarchies that survive growth (skeleton -> tree rules) and trees that do not depend on node spacing."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import PHENO4D, pheno4d

from torch4dtree.io import read_swc_skeleton
from torch4dtree.settings import DEFAULT_HIERARCHY, HIERARCHIES
from torch4dtree.trees.registration import register_trees
from torch4dtree.trees.skeleton import skeleton_to_branches, skeleton_to_trees


def stem_with_long_top_leaf(step: float = 1.0):
    """A 10-long vertical stem; at height 3 a 4-long leaf, at height 8 a 20-long leaf leaving at 60 degrees
    (longer than the 2 of stem above it, as young apex leaves are), and a 0.3 spur at height 5."""
    pts, par = [np.zeros(3)], [-1]

    def chain(start: int, direction: np.ndarray, length: float) -> None:
        n = int(round(length / step))
        prev = start
        for k in range(1, n + 1):
            pts.append(pts[start] + direction * (k * length / n))
            par.append(prev)
            prev = len(pts) - 1

    up = np.array([0.0, 0.0, 1.0])
    chain(0, up, 10.0)
    node = {round(float(p[2]), 6): i for i, p in enumerate(pts)}
    side = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    chain(node[3.0], np.array([0.0, -1.0, 0.0]), 4.0)
    chain(node[8.0], side, 20.0)
    chain(node[5.0], np.array([1.0, 0.0, 0.0]), 0.3)
    return np.array(pts), np.array(par)


def main_branch_top(xyz, parent, **kw):
    polys, _, _ = skeleton_to_branches(xyz, parent, **kw)
    return polys[0][-1]


def test_rules_on_a_stem_with_a_long_apex_leaf():
    xyz, parent = stem_with_long_top_leaf()
    # longest path (the paper's rule) and heaviest subtree run into the apex leaf; straightest keeps the stem
    assert main_branch_top(xyz, parent, hierarchy="longest")[2] == pytest.approx(8 + 20 * np.cos(np.pi / 3))
    assert main_branch_top(xyz, parent, hierarchy="heaviest")[2] == pytest.approx(18.0)
    np.testing.assert_allclose(main_branch_top(xyz, parent, hierarchy="straightest"), [0, 0, 10.0], atol=1e-12)


def test_unknown_rule_and_bad_window_are_errors():
    xyz, parent = stem_with_long_top_leaf()
    with pytest.raises(ValueError, match="plant.swc: hierarchy must be one of .* got 'tallest'"):
        skeleton_to_branches(xyz, parent, hierarchy="tallest", where="plant.swc")
    with pytest.raises(ValueError, match="window must be positive"):
        skeleton_to_branches(xyz, parent, window=0.0)


def split_every_segment(xyz: np.ndarray, parent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same skeleton with a node added in the middle of every segment (same geometry, twice the nodes)."""
    n = len(xyz)
    new_xyz, new_parent = list(xyz), list(parent)
    for v in range(n):
        p = parent[v]
        if p >= 0:
            new_xyz.append((xyz[v] + xyz[p]) / 2)
            new_parent.append(p)
            new_parent[v] = len(new_xyz) - 1
    return np.array(new_xyz), np.array(new_parent)


@pytest.mark.parametrize("hierarchy", HIERARCHIES)
def test_hierarchy_and_tree_do_not_depend_on_node_spacing(hierarchy):
    xyz, parent = stem_with_long_top_leaf(step=1.0)
    a = skeleton_to_trees(xyz, parent, T=32, hierarchy=hierarchy, dtype=torch.float64)
    b = skeleton_to_trees(*split_every_segment(xyz, parent), T=32, hierarchy=hierarchy, dtype=torch.float64)
    assert torch.equal(a.parent, b.parent)
    torch.testing.assert_close(a.s, b.s, atol=1e-12, rtol=0)
    torch.testing.assert_close(a.points, b.points, atol=1e-9, rtol=0)


@pytest.mark.skipif(not PHENO4D.is_dir(), reason="Pheno4D skeletons not available")
def test_split_segment_copy_of_a_real_plant_registers_to_zero():
    """A split-segment copy (same geometry) registers to < 0.1 % of a day-to-day distance (it was 0.7-2.8 %
    when a child's first point was projected on the resampled parent and joined to its raw second node)."""
    day, next_day = (read_swc_skeleton(pheno4d("swc", "Tomato_3", f"T03_03{d}_a_seg.swc")) for d in ("17", "19"))
    a = skeleton_to_trees(day.xyz, day.parent, T=64, dtype=torch.float64)
    b = skeleton_to_trees(*split_every_segment(day.xyz, day.parent), T=64, dtype=torch.float64)
    c = skeleton_to_trees(next_day.xyz, next_day.parent, T=64, dtype=torch.float64)
    self_distance = float(register_trees(b, a).distance)
    day_distance = float(register_trees(c, a).distance)
    assert self_distance < 1e-3 * day_distance, (self_distance, day_distance)


def resample_edges(xyz: np.ndarray, parent: np.ndarray, rng: np.random.Generator,
                   pieces: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The same skeleton with every segment cut into 1 to ``pieces`` parts at random fractions (new nodes last)."""
    pts, par = list(xyz), parent.copy()
    new_parent: list[int] = []
    for v in np.nonzero(parent >= 0)[0]:
        prev = int(parent[v])
        for t in np.sort(rng.uniform(0.02, 0.98, rng.integers(0, pieces))):
            pts.append(xyz[parent[v]] + t * (xyz[v] - xyz[parent[v]]))
            new_parent.append(prev)
            prev = len(pts) - 1
        par[v] = prev
    return np.array(pts), np.concatenate([par, np.array(new_parent, dtype=np.int64)])


def drop_collinear(xyz: np.ndarray, parent: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The skeleton without the nodes that have one child in line with their own segment (same geometry).
    Returns ``(xyz, parent, kept)``: ``kept`` the original index of every remaining node."""
    kids = np.bincount(parent[parent >= 0], minlength=len(xyz))
    only_child = np.full(len(xyz), -1)
    only_child[parent[parent >= 0]] = np.nonzero(parent >= 0)[0]
    drop = np.zeros(len(xyz), dtype=bool)
    for v in np.nonzero((parent >= 0) & (kids == 1))[0]:
        a, b = xyz[v] - xyz[parent[v]], xyz[only_child[v]] - xyz[v]
        drop[v] = np.linalg.norm(np.cross(a, b)) <= tol * np.linalg.norm(a) * np.linalg.norm(b) and a @ b > 0
    up = parent.copy()
    for v in range(len(xyz)):
        while up[v] >= 0 and drop[up[v]]:
            up[v] = parent[up[v]]
    kept = np.nonzero(~drop)[0]
    index = np.cumsum(~drop) - 1
    return xyz[kept], np.where(up[kept] >= 0, index[np.maximum(up[kept], 0)], -1), kept


def hierarchy_of(xyz: np.ndarray, parent: np.ndarray, original: np.ndarray, hierarchy: str = "straightest") -> set:
    """The branches as ``(own original nodes, parent branch's own original nodes)``; ``original (n,)`` maps every
    node to its index in the original skeleton, ``-1`` for a node not to compare (inserted or removed)."""
    _, parents, paths = skeleton_to_branches(xyz, parent, hierarchy=hierarchy)
    own = [frozenset(int(original[v]) for v in (p if i == 0 else p[1:]) if original[v] >= 0)
           for i, p in enumerate(paths)]
    return {(own[i], own[k] if k >= 0 else None) for i, k in enumerate(parents)}


def density_frames() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Young and older Pheno4D skeletons (among them every one whose hierarchy changed when the window had a floor
    of 3 median edges) and synthetic frames (two of which changed then)."""
    from torch4dtree.data import synthetic_plant

    out = []
    for plant, name in [("tomato_1", "T01_0305"), ("tomato_1", "T01_0313"), ("Tomato_3", "T03_0313"),
                        ("Tomato_5", "T05_0307"), ("Tomato_5", "T05_0311"), ("Tomato_3", "T03_0324"),
                        ("Maize01", "M01_0313"), ("Maize02", "M02_0325")]:
        sk = read_swc_skeleton(pheno4d("swc", plant, f"{name}_a_seg.swc"))
        out.append((name, sk.xyz.astype(np.float64), sk.parent.astype(np.int64)))
    for kind, seed, frame in [("tomato", 2, 3), ("maize", 0, 0), ("bean", 1, 8)]:
        xyz, parent, _ = synthetic_plant(kind, seed, n_frames=10, T=8).skeletons[frame]
        out.append((f"{kind} {seed} frame {frame}", xyz, parent))
    return out


def test_hierarchy_survives_random_splits_and_collinear_node_removal():
    """Cutting segments at random fractions (1-3 pieces each) and then removing the collinear nodes again, on
    real and synthetic frames: the same branches with the same parents, node for node."""
    rng = np.random.default_rng(0)
    for name, xyz, parent in density_frames():
        n = len(xyz)
        ref = hierarchy_of(xyz, parent, np.arange(n))
        dense, dense_parent = resample_edges(xyz, parent, rng)
        assert len(dense) > 1.5 * n
        inserted = np.r_[np.arange(n), np.full(len(dense) - n, -1)]
        assert hierarchy_of(dense, dense_parent, inserted) == ref, name
        sparse, sparse_parent, kept = drop_collinear(dense, dense_parent)
        assert len(sparse) == n and hierarchy_of(sparse, sparse_parent, inserted[kept]) == ref, name


def test_straight_stems_merged_into_long_segments_keep_the_hierarchy():
    """The test plant's stems are exactly straight: without their collinear nodes, the stem is a few long segments
    (what broke a window counted in collinear runs), and the hierarchy is the same."""
    xyz, parent = stem_with_long_top_leaf()
    sparse, sparse_parent, kept = drop_collinear(xyz, parent)
    assert len(sparse) < 0.7 * len(xyz)
    kept_only = np.where(np.isin(np.arange(len(xyz)), kept), np.arange(len(xyz)), -1)
    for rule in HIERARCHIES:
        assert hierarchy_of(sparse, sparse_parent, kept, rule) == hierarchy_of(xyz, parent, kept_only, rule), rule
    np.testing.assert_allclose(main_branch_top(sparse, sparse_parent), [0, 0, 10.0], atol=1e-12)


@pytest.mark.skipif(not PHENO4D.is_dir(), reason="Pheno4D skeletons not available")
def test_randomly_resampled_young_plant_registers_to_zero():
    """tomato_1 March 5 (a young plant, where the window's old floor of 3 median edges changed the hierarchy: 10.7)
    cut at random fractions: < 0.1 % of the distance to the next scan."""
    day, next_day = (read_swc_skeleton(pheno4d("swc", "tomato_1", f"T01_03{d}_a_seg.swc")) for d in ("05", "07"))
    xyz, parent = resample_edges(day.xyz, day.parent, np.random.default_rng(1))
    a, b, c = (skeleton_to_trees(x, p, T=64, dtype=torch.float64)
               for x, p in ((day.xyz, day.parent), (xyz, parent), (next_day.xyz, next_day.parent)))
    self_distance, day_distance = float(register_trees(b, a).distance), float(register_trees(c, a).distance)
    assert self_distance < 1e-3 * day_distance, (self_distance, day_distance)


@pytest.mark.skipif(not PHENO4D.is_dir(), reason="Pheno4D skeletons not available")
def test_rotation_search_never_ends_worse_than_no_rotation():
    """tomato_2 March 19 -> 21: with the identity start dropped by the ranking on the top layers, the vertical search
    ended at 32.33 against 32.30 without rotation (the identity start now always runs in full)."""
    from torch4dtree.io import LoadOptions, read_tree

    a, b = (read_tree(pheno4d("swc", "tomato_2", f"T02_03{d}_a_seg.swc"), LoadOptions(T=64, dtype=torch.float64))
            for d in ("19", "21"))
    none = float(register_trees(a, b, rotation="none").distance)
    for rotation in ("vertical", "so3"):
        assert float(register_trees(a, b, rotation=rotation).distance) <= none * (1 + 1e-12)


# ------------------------------------------------------------------ identities on realistic synthetic plants
# (the generator's apex leaves outgrow the stem above them, tomato grows basal side shoots, maize's two-ranked
# leaves look alike, bean has true side shoots: the longest path leaves the stem in every frame; organ labels
# per skeleton node are the truth, a branch's label is the majority organ of its nodes)


# the default rule, passed on to the joint hierarchy (torch4dtree.trees.growth)
DEFAULT_RULE = {"hierarchy": DEFAULT_HIERARCHY}

# identities are chained by within-sequence registration, whose default weighs positions at 0.9 x L
IDENTITY_LAMBDAS = (1.0, 1.0, 9.0)


def pooled_scores(pairs, lambdas=IDENTITY_LAMBDAS, **kw):
    from torch4dtree.data import score_registration

    hit_p = tot_p = hit_r = tot_r = 0.0
    for mov, ref, rotation in pairs:
        sc = score_registration(register_trees(mov, ref, lambdas, rotation=rotation, **kw), mov, ref)
        hit_p += sc.precision * sc.n_matched
        tot_p += sc.n_matched
        hit_r += sc.recall * sc.n_common
        tot_r += sc.n_common
    return hit_p / tot_p, hit_r / tot_r


@pytest.mark.parametrize("kind", ["tomato", "maize", "bean", "almond"])
def test_identities_survive_growth_between_consecutive_frames(kind):
    from torch4dtree.data import synthetic_plant

    frames = [synthetic_plant(kind, seed, n_frames=10, T=24, dtype=torch.float64, hierarchy_kwargs=DEFAULT_RULE
                              ).sequence.frames for seed in (0, 1)]
    precision, recall = pooled_scores([(f[j], f[j + 1], "none") for f in frames for j in range(len(f) - 1)])
    # the almond's buds break at random over two flushes, so laterals appear between older ones and shift the
    # positions of those above: the default rule measures 0.971 / 0.948 on these 18 pairs, so for the almond's
    # recall this guards the measured level, just under the goal of 0.95
    assert precision >= 0.95 and recall >= (0.94 if kind == "almond" else 0.95), (precision, recall)


@pytest.mark.parametrize("kind", ["tomato", "maize", "bean", "almond"])
def test_library_defaults_keep_identities_between_consecutive_frames(kind):
    """``register_trees(a, b)`` with nothing set, as a user calls it on two days of one plant: children compared by
    node rank (the default positions) keep organs between frames. Maize fails with the paper's warped positions at
    the default lp (similar leaves two nodes apart swap: 93.9 % on these 36 pairs)."""
    from torch4dtree.data import score_registration, synthetic_plant

    frames = [synthetic_plant(kind, seed, n_frames=10, T=24, dtype=torch.float64, hierarchy_kwargs=DEFAULT_RULE
                              ).sequence.frames for seed in range(4)]

    def pooled(**kw: object) -> tuple[float, float]:
        scores = [score_registration(register_trees(f[j], f[j + 1], **kw), f[j], f[j + 1])
                  for f in frames for j in range(len(f) - 1)]
        return (sum(s.precision * s.n_matched for s in scores) / sum(s.n_matched for s in scores),
                sum(s.recall * s.n_common for s in scores) / sum(s.n_common for s in scores))

    precision, recall = pooled()
    # almond: laterals break between older ones and shift the ranks of those above; the goal is 0.95 and the
    # default rule measures 0.954 / 0.931 on these 36 pairs ("continuation": 0.959 / 0.959), so for the almond
    # this guards against regressions only (docs/experiments.md, woody trees)
    least = 0.92 if kind == "almond" else 0.98
    assert precision >= least and recall >= least, (precision, recall)
    if kind == "maize":
        assert pooled(positions="warped", order_tol=None)[0] < 0.95  # with any matching


def test_library_defaults_keep_maize_identities_across_sparse_frames():
    """Four snapshots over the growth period (a plant doubles between them): with node ranks the default still pairs
    most maize leaves with themselves (92.0 % measured); the paper's warped positions pair the old leaves with the
    new long ones (61.3 %)."""
    from torch4dtree.data import score_registration, synthetic_plant

    frames = [synthetic_plant("maize", seed, n_frames=4, T=24, dtype=torch.float64).sequence.frames
              for seed in range(6)]

    def precision(**kw: object) -> float:
        scores = [score_registration(register_trees(f[j], f[j + 1], **kw), f[j], f[j + 1])
                  for f in frames for j in range(len(f) - 1)]
        return sum(s.precision * s.n_matched for s in scores) / sum(s.n_matched for s in scores)

    assert precision() >= 0.9
    assert precision(positions="warped") < 0.75


@pytest.mark.parametrize("kind", ["tomato", "maize", "bean"])
def test_identities_across_plants_of_a_kind(kind):
    """With the cross-plant settings (:func:`torch4dtree.bench.hierarchy.registration_settings`: children compared
    by node rank, ordered along their parents). Bean needs them: its plants at one calendar day differ by a
    trifoliate, and with positions that move with the stem's warp (or arc length) the metric rather registers the
    plant ahead one node shifted and turned by 180 degrees (docs/experiments.md, "Cross-plant identities")."""
    from torch4dtree.bench.hierarchy import registration_settings
    from torch4dtree.data import synthetic_dataset

    # the last frame (the most organs, the plants' stages furthest apart) of 6 plants: 15 pairs; with 3 plants one
    # plant's side shoot in an axil no other plant has (matched to another shoot: a whole subtree wrong) weighs
    # too much
    plants = [p.sequence.frames[9] for p in synthetic_dataset(kind, 6, 0, n_frames=10, T=24, dtype=torch.float64)]
    pairs = [(plants[a], plants[b], "vertical") for a in range(6) for b in range(a + 1, 6)]
    kw = registration_settings()
    precision, recall = pooled_scores(pairs, kw.pop("lambdas"), **kw)
    assert precision >= 0.85 and recall >= 0.85, (precision, recall)


def test_longest_path_rule_loses_identities_on_the_same_plants():
    """The same measurement with the paper's longest-path rule: the realistic plants are not built to suit it."""
    from torch4dtree.data import synthetic_plant

    f = synthetic_plant("tomato", 0, n_frames=10, T=24, dtype=torch.float64,
                        hierarchy_kwargs={"hierarchy": "longest"}).sequence.frames
    precision, recall = pooled_scores([(f[j], f[j + 1], "none") for j in range(len(f) - 1)])
    assert precision < 0.9 and recall < 0.9, (precision, recall)


# ------------------------------------------------------------------ a woody tree: a leader overtaken by a scaffold


def young_tree(leader_turn_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 100 mm vertical trunk; at its top a 40 mm leader bending ``leader_turn_deg`` from vertical and a scaffold
    leaving at 12 degrees on the other side, 80 mm long, carrying three 25 mm laterals at 60 degrees (20, 40, 60 mm
    along it). Returns ``(xyz, parent, organ)``: trunk and leader 0, scaffold 51, laterals 5151-5153."""
    pts, par, org = [np.zeros(3)], [-1], [0]

    def chain(start: int, direction: np.ndarray, length: float, label: int) -> list[int]:
        nodes, prev = [start], start
        for k in range(1, int(length) + 1):
            pts.append(pts[start] + direction * k)
            par.append(prev)
            org.append(label)
            prev = len(pts) - 1
            nodes.append(prev)
        return nodes

    def tilt(deg: float, azimuth: float) -> np.ndarray:
        a = np.radians(deg)
        return np.array([np.sin(a) * np.cos(azimuth), np.sin(a) * np.sin(azimuth), np.cos(a)])

    top = chain(0, tilt(0, 0), 100, 0)[-1]
    chain(top, tilt(leader_turn_deg, 0.0), 40, 0)
    scaffold = chain(top, tilt(12, np.pi), 80, 51)
    for j, at in enumerate((20, 40, 60), 1):
        chain(scaffold[at], tilt(60, np.pi + (-1) ** j), 25, 5150 + j)
    return np.array(pts), np.array(par), np.array(org)


def test_an_overtaking_scaffold_continues_the_tree_whichever_way_the_leader_bends():
    """The leader turns 8 degrees at one scan and 18 at the next, the scaffold that overtakes it 12 degrees at both:
    ``"straightest"`` runs the main branch into the leader, then into the scaffold, and the scaffold's laterals
    change parent between the scans (identities lost); ``"continuation"`` follows the scaffold that carries them at
    both scans, and the registration keeps every organ."""
    from torch4dtree.data import score_registration
    scans = [young_tree(8.0), young_tree(18.0)]
    scaffold_tip = scans[0][0][np.nonzero(scans[0][2] == 51)[0][-1]]

    def scores(rule: str) -> tuple[float, float, list[bool]]:
        trees = [skeleton_to_trees(xyz, parent, T=16, node_labels=organ, hierarchy=rule, dtype=torch.float64)
                 for xyz, parent, organ in scans]
        tops = [bool(np.allclose(main_branch_top(xyz, parent, hierarchy=rule), scaffold_tip)) for xyz, parent, _ in
                scans]
        sc = score_registration(register_trees(trees[1], trees[0]), trees[1], trees[0])
        return sc.precision, sc.recall, tops

    precision, recall, tops = scores("straightest")
    assert tops == [False, True] and min(precision, recall) < 0.9, (precision, recall, tops)
    precision, recall, tops = scores("continuation")
    assert tops == [True, True] and precision == recall == 1.0, (precision, recall, tops)
