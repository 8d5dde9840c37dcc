"""All-pairs in tiles and pair chunks: independent of the tiling, resumable on disk, clear errors on bad records."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch4dtree.data import synthetic_plant
from torch4dtree.evaluate.generative_metrics import CHUNK, distance4d, distance_matrix
from torch4dtree.parallel import InlineExecutor, TileRecordError, pair_matrix, tiled_matrix
from torch4dtree.trees.pairwise import pairwise_distances
from torch4dtree.trees.registration import register_to_reference
from torch4dtree.trees.structures import Trees


def plants(n: int, T: int = 12) -> Trees:
    return Trees.cat([synthetic_plant("tomato", seed=i, n_frames=2, T=T, dtype=torch.float64).sequence.frames[1]
                      for i in range(n)])


class Counting(InlineExecutor):
    """Inline, counting the tasks; raises instead of running task number ``fail_at`` (1-based) if given."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.count, self.fail_at = 0, fail_at

    def submit(self, fn, /, *args, **kwargs):
        self.count += 1
        if self.count == self.fail_at:
            raise KeyboardInterrupt("interrupted")
        return super().submit(fn, *args, **kwargs)


def outer_sum(i0: int, i1: int, j0: int, j1: int) -> tuple:
    return np.add.outer, (np.arange(i0, i1, dtype=float), 10.0 * np.arange(j0, j1, dtype=float))


@pytest.fixture(scope="module")
def five():
    return plants(5)


def test_pairwise_does_not_depend_on_the_tiling(five):
    """A pair's registered distance has the same bits whatever pairs share its batch: tiles of any size give the
    matrix of rows registered one batch each (and of single pairs)."""
    split = five.split()
    rows = torch.zeros(5, 5, dtype=torch.float64)
    for i in range(4):
        d = [float(r.distance) for r in register_to_reference(Trees.cat(split[i + 1:]), split[i])]
        rows[i, i + 1:] = rows[i + 1:, i] = torch.tensor(d, dtype=torch.float64)
    for tile in (1, 2, 3, 64):
        assert torch.equal(pairwise_distances(five, processes=1, progress=False, tile=tile), rows), tile
    assert float(register_to_reference(split[4], split[1])[0].distance) == float(rows[1, 4])


def test_an_interrupted_run_resumes_without_recomputing(five, tmp_path):
    full = pairwise_distances(five, processes=1, progress=False, tile=2)  # 6 tiles: 3 diagonal, 3 above
    with pytest.raises(KeyboardInterrupt):
        pairwise_distances(five, progress=False, tile=2, path=tmp_path, executor=Counting(fail_at=4))
    assert np.load(tmp_path / "done.npy").sum() == 3
    again = Counting()
    resumed = pairwise_distances(five, progress=False, tile=2, path=tmp_path, executor=again)
    assert again.count == 3 and torch.equal(resumed, full)
    done = Counting()
    assert torch.equal(pairwise_distances(five, progress=False, tile=2, path=tmp_path, executor=done), full)
    assert done.count == 0
    on_disk = np.load(tmp_path / "distances.npy")
    assert np.array_equal(on_disk, full.numpy())


def test_tiled_matrix_interrupted_by_its_callback(tmp_path):
    seen = []

    def stop_after_two(a: int, b: int, pairs: int) -> None:
        seen.append((a, b))
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tiled_matrix((5, 4), outer_sum, symmetric=False, tile=2, path=tmp_path, on_tile=stop_after_two)
    seen.clear()
    out = tiled_matrix((5, 4), outer_sum, symmetric=False, tile=2, path=tmp_path,
                       on_tile=lambda a, b, p: seen.append((a, b)))
    assert seen == [(1, 0), (1, 1), (2, 0), (2, 1)]  # the first two blocks were not computed again
    assert np.array_equal(out, np.add.outer(np.arange(5.0), 10.0 * np.arange(4.0)))


def test_bad_tile_records_are_clear_errors(five, tmp_path):
    pairwise_distances(five, progress=False, processes=1, tile=2, path=tmp_path)
    with pytest.raises(TileRecordError, match="other inputs or settings"):
        pairwise_distances(five, progress=False, processes=1, tile=3, path=tmp_path)
    with pytest.raises(TileRecordError, match="other inputs or settings"):
        pairwise_distances(plants(5, T=10), progress=False, processes=1, tile=2, path=tmp_path)
    (tmp_path / "done.npy").write_bytes(b"not an array")
    with pytest.raises(TileRecordError, match="unreadable tile record"):
        pairwise_distances(five, progress=False, processes=1, tile=2, path=tmp_path)
    np.save(tmp_path / "done.npy", np.zeros(2, dtype=bool))
    with pytest.raises(TileRecordError, match="corrupt tile record"):
        pairwise_distances(five, progress=False, processes=1, tile=2, path=tmp_path)


def test_pair_matrix_is_the_distance_matrix():
    """In the serial computation's own chunks, the trajectories' ground distances are the same bits."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn(7, 10, 4, generator=g, dtype=torch.float64).cumsum(1)
    y = torch.randn(3, 10, 4, generator=g, dtype=torch.float64).cumsum(1)
    assert torch.equal(pair_matrix(distance4d, x, chunk=CHUNK), distance_matrix(x))
    assert torch.equal(pair_matrix(distance4d, x, y, chunk=CHUNK), distance_matrix(x, y))
    assert torch.equal(pair_matrix(distance4d, x, chunk=5, executor=InlineExecutor()),
                       pair_matrix(distance4d, x, chunk=5))
