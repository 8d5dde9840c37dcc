"""End to end: synth -> fit -> sample on a tiny synthetic dataset; the torch Dataset and collate."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from torch4dtree.cli.main import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> str:
    from torch4dtree.data import synthetic_dataset, write_dataset

    out = tmp_path_factory.mktemp("ds") / "tomato"
    write_dataset(synthetic_dataset("tomato", plants=3, seed=1, n_frames=4), out)
    return str(out)


def test_fit_then_sample(dataset: str, tmp_path) -> None:
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps({"model": "paper", "T": 12, "n_t": 8, "render_size": 64, "medoid_candidates": 1}))
    run = tmp_path / "run"
    assert main(["fit", dataset, "--config", str(cfg), "--out", str(run), "--quiet"]) == 0
    for name in ("model.pt", "report.json", "report.md", "fit.log", "mean.png", "modes.png", "samples.png"):
        assert (run / name).is_file(), name
    r = json.loads((run / "report.json").read_text())
    assert r["dataset"]["sequences"] == 3 and r["dataset"]["frames"] == 12
    reg = r["registration"]
    assert reg["cross_sequence"]["after"]["mean"] <= reg["cross_sequence"]["before"]["mean"] + 1e-9
    assert reg["temporal"]["after"]["max"] <= reg["temporal"]["before"]["max"] + 1e-9
    assert 0 < sum(r["modes"]["variance_ratio"]) <= 1 + 1e-9
    assert all(a >= b for a, b in zip(r["modes"]["variance"], r["modes"]["variance"][1:]))
    assert r["reconstruction"]["max"] >= 0 and r["seconds"]["fit"] > 0
    assert "## Modes" in (run / "report.md").read_text()
    space = r["tree_space"]  # the layout bound: 3 tiny plants stay under it, nothing dropped
    assert space["slots"] <= space["max_slots"] and space["dropped_share"] == 0.0
    assert space["slots_opened"] == space["slots"] and "Slots opened" in (run / "report.md").read_text()
    # an existing run directory is refused
    assert main(["fit", dataset, "--config", str(cfg), "--out", str(run), "--quiet", "--no-figures"]) == 2
    out = tmp_path / "samples"
    assert main(["sample", str(run / "model.pt"), "--n", "2", "--seed", "3", "--out", str(out), "--size", "64"]) == 0
    for k in range(2):
        folder = out / f"sample_{k:03d}"
        assert len(list(folder.glob("*.swc"))) == 8
        assert (out / f"sample_{k:03d}.gif").is_file()
    meta = json.loads((out / "samples.json").read_text())
    assert np.abs(np.array(meta["coefficients"])).max() <= meta["c"]
    import imageio.v3 as iio

    frames = iio.imread(out / "grid.gif", index=None)
    last = np.asarray(frames[-1])[..., :3].astype(int)
    ink = (np.abs(last - 255).sum(-1) > 60).mean()  # share of pixels that are not background
    assert 0.001 < ink < 0.5
    # the same seed writes the same trees
    out2 = tmp_path / "samples2"
    assert main(["sample", str(run / "model.pt"), "--n", "2", "--seed", "3", "--out", str(out2), "--video",
                 "none"]) == 0
    assert (out / "sample_001" / "frame_007.swc").read_text() == (out2 / "sample_001" / "frame_007.swc").read_text()
    # the forecast of a plant seen over its first two frames
    from torch4dtree.io import LoadOptions, read_sequence, sequence_folders, write_sequence

    plant = read_sequence(sequence_folders(dataset)[0], LoadOptions(T=12, dtype=torch.float64)).sequence
    write_sequence(tmp_path / "seen", plant[[0, 1]])
    until = float(plant.times[-1])
    assert main(["forecast", str(run / "model.pt"), str(tmp_path / "seen"), "--until", str(until), "--steps", "2",
                 "--n", "1", "--out", str(tmp_path / "forecast")]) == 0
    meta = json.loads((tmp_path / "forecast" / "forecast.json").read_text())
    assert meta["kind"] == "paper" and len(meta["times"]) == 2 and meta["times"][-1] == until
    assert len(read_sequence(tmp_path / "forecast" / "forecast").sequence) == 2


def test_dataset_and_collate(dataset: str) -> None:
    from torch.utils.data import DataLoader

    from torch4dtree.data.dataset import TreeSequenceDataset, collate_sequences

    ds = TreeSequenceDataset(dataset, T=12)
    assert len(ds) == 3
    batch = next(iter(DataLoader(ds, batch_size=2, collate_fn=collate_sequences)))
    seqs = [ds[0], ds[1]]
    N = max(int(torch.diff(s.frames.ptr).max()) for s in seqs)
    assert batch.points.shape == (2, 4, N, 12, 3)
    for b, s in enumerate(seqs):
        assert int(batch.branch_mask[b].sum()) == s.frames.points.shape[0]
        f, j = s.frames.tree_index, s.frames.local_index
        assert torch.equal(batch.points[b, f, j], s.frames.points)
        assert torch.equal(batch.times[b], s.times)
        assert bool((batch.points[b][~batch.branch_mask[b]] == 0).all())
    with pytest.raises(IndexError):
        ds[3]
