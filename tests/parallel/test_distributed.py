"""The same numbers inline, on local processes and on a Dask LocalCluster; a killed worker changes nothing."""

from __future__ import annotations

import os
import sys
from concurrent.futures import Executor
from pathlib import Path

import pytest
import torch

from torch4dtree.data import synthetic_plant
from torch4dtree.evaluate.generative_metrics import CHUNK, distance4d, distance_matrix
from torch4dtree.io import read_dataset, write_sequence
from torch4dtree.io.dataset import LoadOptions
from torch4dtree.model import FourDTreeModel
from torch4dtree.parallel import local_executor, make_executor, pair_matrix
from torch4dtree.settings import ModelSettings
from torch4dtree.temporal import register4d
from torch4dtree.trees.pairwise import pairwise_distances
from torch4dtree.trees.structures import Trees

distributed = pytest.importorskip("distributed")  # the [distributed] extra (installed by the dev extra)


@pytest.fixture(scope="module")
def cluster():
    """One Dask cluster of 2 single-threaded worker processes for the module; this module's functions travel by
    value (the workers cannot import a test module)."""
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as c:
        yield c
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module")
def processes():
    with local_executor(2) as pool:
        yield pool


@pytest.fixture(scope="module")
def sequences():
    return [synthetic_plant("maize", i, n_frames=3, T=8, dtype=torch.float64).sequence for i in range(4)]


def same_state(a: dict, b: dict) -> bool:
    """Equal state dicts: every tensor bit for bit, every extra state but the timings."""
    if a.keys() != b.keys():
        return False
    for k in a:
        if isinstance(a[k], torch.Tensor):
            if not torch.equal(a[k], b[k]):
                return False
        elif {x: y for x, y in a[k].items() if x != "report"} != {x: y for x, y in b[k].items() if x != "report"}:
            return False
    return True


def die_once(marker: str, fn, *args):
    """Kill this worker process the first time any task runs it (marker file), else run ``fn(*args)``."""
    if not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return fn(*args)


class DieOnce(Executor):
    """Submits the ``which``-th task wrapped in :func:`die_once`."""

    def __init__(self, inner: Executor, marker: Path, which: int = 2) -> None:
        self.inner, self.marker, self.which, self.count = inner, marker, which, 0

    def submit(self, fn, /, *args, **kwargs):
        self.count += 1
        if self.count == self.which:
            return self.inner.submit(die_once, str(self.marker), fn, *args)
        return self.inner.submit(fn, *args)


def test_pairwise_distances_everywhere(cluster, processes, sequences, tmp_path):
    trees = Trees.cat([s.frames[2] for s in sequences])
    inline = pairwise_distances(trees, processes=1, progress=False, tile=2)
    assert torch.equal(pairwise_distances(trees, progress=False, tile=2, executor=processes), inline)
    with make_executor(scheduler=cluster.scheduler_address) as ex:
        assert torch.equal(pairwise_distances(trees, progress=False, tile=2, executor=ex), inline)
        killer = DieOnce(ex, tmp_path / "died")
        assert torch.equal(pairwise_distances(trees, progress=False, tile=2, executor=killer), inline)
    assert (tmp_path / "died").exists()  # a worker did die, and its tile was computed again elsewhere


def test_the_fit_and_encoding_everywhere(cluster, processes, sequences, tmp_path):
    settings = ModelSettings(n_t=4, medoid_candidates=2)
    inline = FourDTreeModel(settings).fit(sequences)
    z = inline.encode_many(sequences)
    assert torch.equal(z, torch.stack([inline.encode(s) for s in sequences]))
    with make_executor(scheduler=cluster.scheduler_address) as ex:
        runs = {"processes": processes, "dask": ex, "dask, a worker killed": DieOnce(ex, tmp_path / "died", 3)}
        for name, executor in runs.items():
            model = FourDTreeModel(settings).fit(sequences, executor=executor)
            assert same_state(model.state_dict(), inline.state_dict()), name
            assert torch.equal(model.encode_many(sequences, executor=executor), z), name
    assert (tmp_path / "died").exists()


def test_register4d_and_reading_everywhere(cluster, sequences, tmp_path):
    inline = register4d(sequences[0], sequences[1], n_t=4)
    for k, s in enumerate(sequences[:3]):
        write_sequence(tmp_path / "data" / f"plant_{k}", s)
    opts = LoadOptions(T=8)
    read = read_dataset(tmp_path / "data", opts)
    with make_executor(scheduler=cluster.scheduler_address) as ex:
        spread = register4d(sequences[0], sequences[1], n_t=4, executor=ex)
        names = []
        remote = read_dataset(tmp_path / "data", opts, progress=names.append, executor=ex)
    assert spread.distance_after_temporal == inline.distance_after_temporal
    assert torch.equal(spread.layout.features(), inline.layout.features())
    assert sorted(names) == ["plant_0", "plant_1", "plant_2"]
    assert [r.files for r in remote] == [r.files for r in read]
    assert all(torch.equal(a.sequence.frames.points, b.sequence.frames.points) for a, b in zip(remote, read))


def test_distance_matrix_everywhere(cluster, processes):
    g = torch.Generator().manual_seed(1)
    x = torch.randn(6, 8, 3, generator=g, dtype=torch.float64).cumsum(1)
    y = torch.randn(2, 8, 3, generator=g, dtype=torch.float64).cumsum(1)
    with make_executor(scheduler=cluster.scheduler_address) as ex:
        for executor in (processes, ex):
            assert torch.equal(pair_matrix(distance4d, x, chunk=CHUNK, executor=executor), distance_matrix(x))
            assert torch.equal(pair_matrix(distance4d, x, y, chunk=CHUNK, executor=executor), distance_matrix(x, y))
