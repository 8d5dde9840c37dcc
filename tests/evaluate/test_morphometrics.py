"""Morphometrics of populations: agreement with the independent yardstick, and properties that could fail."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from torch4dtree.evaluate import EvalData, generative, load_eval_data
from torch4dtree.evaluate.data import QUICK_MORPHO_DRAWS, EvalSettings
from torch4dtree.evaluate.morphometrics import (
    AGES,
    FEATURES,
    compare_populations,
    folder_curve,
    population_curves,
    summary_line,
)
from torch4dtree.io import read_dataset, write_sequence
from torch4dtree.trees.structures import Trees, TreeSequence

# the yardstick lives beside the repository (../shared/tools), as the real data does
YARDSTICK = Path(__file__).resolve().parents[2].parent / "shared" / "tools" / "morpho_eval.py"


@pytest.fixture(scope="module")
def folders(synthetic_folder: Callable[..., Path]) -> tuple[Path, Path]:
    """Two small synthetic dataset folders of different kinds (the package's synth writer)."""
    return synthetic_folder(4, 0, 5), synthetic_folder(5, 1, 4, kind="bean")


def scaled_copy(src: Path, dst: Path, scale: float) -> Path:
    """A dataset folder whose SWC coordinates are ``scale`` times ``src``'s (times manifests copied)."""
    for seq in sorted(p for p in src.iterdir() if p.is_dir()):
        (dst / seq.name).mkdir(parents=True)
        for f in seq.iterdir():
            if f.suffix == ".swc":
                rows = []
                for line in f.read_text().splitlines():
                    c = line.split()
                    if c and not line.startswith("#"):
                        c[2:5] = [repr(float(v) * scale) for v in c[2:5]]
                    rows.append(" ".join(c))
                (dst / seq.name / f.name).write_text("\n".join(rows) + "\n")
            elif f.name == "times.json":
                (dst / seq.name / f.name).write_text(f.read_text())
    return dst


def test_agrees_with_the_yardstick(folders: tuple[Path, Path], tmp_path: Path) -> None:
    if not YARDSTICK.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{YARDSTICK} not found (CI must have ../shared beside the repository)")
        pytest.skip(f"{YARDSTICK} not found")
    real, samples = folders
    out = tmp_path / "yardstick.json"
    run = subprocess.run([sys.executable, str(YARDSTICK), str(real), str(samples), "--json", str(out)],
                         capture_output=True, text=True, check=True)
    theirs = json.loads(out.read_text())
    ours = compare_populations(population_curves(real), population_curves(samples))
    assert (ours["real_plants"], ours["samples"]) == (theirs["real_plants"], theirs["samples"]) == (4, 5)
    assert set(ours["features"]) == set(theirs["features"]) == {f"{f}@{u}" for f in FEATURES for u in AGES}
    for key, t in theirs["features"].items():
        for k, v in t.items():
            assert ours["features"][key][k] == pytest.approx(v, rel=1e-12, abs=1e-12), (key, k)
    assert ours["one_nna"] == theirs["one_nna"]
    assert summary_line(ours) == run.stdout.strip().splitlines()[-1]
    # and the populations do differ (the comparison is not vacuous)
    assert ours["ks_max"] > 0.5 and ours["worst_ratio"] < 0.9


def test_a_population_against_itself(folders: tuple[Path, Path]) -> None:
    curves = population_curves(folders[0])
    r = compare_populations(curves, curves)
    assert all(v["ratio"] == 1.0 and v["ks"] == 0.0 for v in r["features"].values())
    assert (r["worst_ratio"], r["ks_max"]) == (1.0, 0.0)
    assert r["one_nna"] == 0.0  # every plant's nearest neighbour is its copy in the other set


def test_a_scaled_copy(folders: tuple[Path, Path], tmp_path: Path) -> None:
    real = folders[0]
    big = population_curves(scaled_copy(real, tmp_path / "big", 2.5))
    r = compare_populations(population_curves(real), big)
    for u in AGES:
        for f in ("length", "height", "spread"):
            assert r["features"][f"{f}@{u}"]["ratio"] == pytest.approx(2.5, rel=1e-9), (f, u)
        for f in ("tips", "branchpoints"):
            assert r["features"][f"{f}@{u}"]["ratio"] == 1.0 and r["features"][f"{f}@{u}"]["ks"] == 0.0
    assert r["worst_ratio"] == pytest.approx(1 / 2.5)
    assert r["one_nna"] == 1.0  # the sizes separate the sets


def test_trees_read_as_their_written_skeletons(folders: tuple[Path, Path], tmp_path: Path) -> None:
    """A 4D tree's curve is the curve of the folder write_sequence makes of it (what ``sample`` writes)."""
    seqs = [s.sequence for s in read_dataset(folders[1])][:2]
    for i, s in enumerate(seqs):
        write_sequence(tmp_path / f"p{i}", s)
    from_trees = population_curves(seqs)
    from_files = np.stack([folder_curve(tmp_path / f"p{i}") for i in range(len(seqs))])
    np.testing.assert_allclose(from_trees, from_files, rtol=1e-5, atol=1e-4)
    # a plant's curve grows with it: more length and organs at the end than at the start
    assert (from_trees[:, -1, [0, 3]] > from_trees[:, 0, [0, 3]]).all()


def test_ages_are_read_on_normalised_time(tmp_path: Path) -> None:
    """Two frames at days 10 and 30 of a one-branch plant growing from 10 to 50: length at u = 0.5 is 30."""
    folder = tmp_path / "p"
    folder.mkdir()
    for day, h in ((10, 10.0), (30, 50.0)):
        (folder / f"d{day}.swc").write_text(f"1 0 0 0 0 1 -1\n2 0 0 0 {h / 2} 1 1\n3 0 0 0 {h} 1 2\n")
    (folder / "times.json").write_text(json.dumps({"d30.swc": 30, "d10.swc": 10}))
    c = folder_curve(folder)
    np.testing.assert_allclose(c[:, 0], [10, 20, 30, 40, 50])
    np.testing.assert_allclose(c[:, 3:], [[1, 0]] * 5)


def test_a_lost_organ_shows(folders: tuple[Path, Path]) -> None:
    """Samples whose plants lost their side branches: tips and length ratios fall below 1."""
    seqs = [s.sequence for s in read_dataset(folders[0])]
    pruned = []
    for s in seqs:
        f = s.frames
        keep = f.parent < 0  # main branches only
        frames = Trees(f.points[keep], f.parent[keep], f.s[keep], torch.ones(len(s), dtype=torch.long),
                       f.label[keep])
        pruned.append(TreeSequence(frames, s.times, s.name))
    r = compare_populations(population_curves(seqs), population_curves(pruned))
    assert r["features"]["tips@1.0"]["ratio"] < 0.5 and r["features"]["length@1.0"]["ratio"] < 0.9
    assert r["features"]["height@0.0"]["ratio"] <= 1.0


def test_the_generative_section_reports_morphometrics(synthetic_folder: Callable[..., Path]) -> None:
    """``evaluate --sections generative --heldout DIR``: each generator's samples compared with the held-out plants,
    over draws of as many samples as held-out plants; the training plants (one draw) are the scale."""
    data = load_eval_data(synthetic_folder(5, 0, 5), "synthetic", T=16)
    train = EvalData(data.root, data.source, data.plants[:3])
    held = EvalData(data.root, data.source, data.plants[3:])
    out = generative.run({"synthetic": train}, EvalSettings(T=16, quick=True), False, heldout=held)["generative"]
    kind = out["kinds"]["tomato"]
    assert kind["split"] == "held-out folder" and len(kind["folds"]) == 1 and kind["plants"] == 5
    assert kind["folds"][0]["held_out"] == [p.name for p in held.plants]
    assert kind["folds"][0]["train"] == [p.name for p in train.plants]
    fold = kind["folds"][0]["morphometrics"]
    assert set(fold) == set(kind["morphometrics"]) == set(generative.MORPHO_GENERATORS)  # the organ model too
    draws = QUICK_MORPHO_DRAWS
    for name, rs in fold.items():
        assert len(rs) == (1 if name in ("memorise", "mean") else draws) == kind["morphometrics"][name]["draws"], name
        for r in rs:
            assert 0 <= r["ks_max"] <= 1 and 0 <= r["one_nna"] <= 1 and 0 <= r["worst_ratio"] <= 1
            assert r["worst_ratio"] == min(r["worst_by_age"].values()), name
        s = kind["morphometrics"][name]
        assert s["worst_ratio"]["min"] <= s["worst_ratio"]["median"] and s["one_nna"]["n"] == len(rs)
    # the memorised training plants are real plants of the same kind: their sizes are near the held-out ones
    assert fold["memorise"][0]["worst_ratio"] > 0.4
    # real plants are read from their files, as the yardstick reads the folders: the same numbers
    folder = {n: np.stack([folder_curve(p.files[0].parent) for p in d.plants]) for n, d in (("t", train), ("h", held))}
    c = compare_populations(folder["h"], folder["t"])
    assert {k: fold["memorise"][0][k] for k in ("worst_ratio", "one_nna", "ks_max")} == {
        k: c[k] for k in ("worst_ratio", "one_nna", "ks_max")}
    md = "\n".join(generative.markdown({"generative": out}))
    assert "Morphometrics" in md and "| @ 0.25 |" in md and "held-out folder" in md
