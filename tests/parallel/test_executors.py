"""Executors and tasks: inline, local processes, bad executors, transport (torch4dtree.parallel)."""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor

import pytest
import torch

from torch4dtree.parallel import InlineExecutor, local_executor, make_executor, move, run_tasks
from torch4dtree.trees.pairwise import pairwise_distances
from torch4dtree.trees.structures import Trees


def stems(n: int) -> Trees:
    t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
    return Trees.cat([Trees.from_branches([[torch.cat([b * t ** 2, 0 * t, t], 1)]], [[-1]], T=8,
                                          dtype=torch.float64) for b in torch.linspace(0, 1, n).tolist()])


def fail_on(x: int) -> int:
    if x == 2:
        raise RuntimeError("task 2 failed")
    return x


def test_make_executor_kinds():
    assert isinstance(make_executor(), InlineExecutor) and isinstance(make_executor(1), InlineExecutor)
    with make_executor(2) as ex:
        assert isinstance(ex, ProcessPoolExecutor) and ex._max_workers == 2
    with pytest.raises(ValueError, match="positive integer"):
        local_executor(0)


def test_make_executor_without_dask_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ImportError, match=r"torch4dtree\[distributed\]"):
        make_executor(scheduler="tcp://127.0.0.1:1")


def test_a_bad_executor_is_a_clear_error():
    with pytest.raises(TypeError, match="concurrent.futures.Executor"):
        pairwise_distances(stems(3), executor=object(), progress=False)
    with pytest.raises(TypeError, match="concurrent.futures.Executor"):
        run_tasks(abs, [(1,)], executor="local")


def test_run_tasks_order_errors_and_callbacks():
    seen = []
    assert run_tasks(divmod, [(7, 2), (9, 4)], done=lambda i, r: seen.append(i)) == [(3, 1), (2, 1)]
    with InlineExecutor() as ex:
        assert run_tasks(divmod, [(7, 2), (9, 4)], ex, done=lambda i, r: seen.append(i)) == [(3, 1), (2, 1)]
        with pytest.raises(RuntimeError, match="task 2 failed"):
            run_tasks(fail_on, [(1,), (2,), (3,)], ex)
    assert seen == [0, 1, 0, 1]


class Scattering(InlineExecutor):
    """An inline executor with a ``scatter`` method (as Dask's), recording what it was given."""

    def __init__(self) -> None:
        self.scattered: list[bytes] = []

    def scatter(self, data: bytes) -> bytes:
        self.scattered.append(data)
        return data


def test_a_shared_argument_is_packed_once_and_sent_once():
    assert run_tasks(pow, [(2,), (3,)], shared=10) == [100, 1000]
    with Scattering() as ex:
        assert run_tasks(pow, [(2,), (3,), (4,)], ex, shared=10) == [100, 1000, 10000]
        assert len(ex.scattered) == 1
    with InlineExecutor() as ex:  # no scatter: the packed bytes travel with each task
        assert run_tasks(pow, [(2,), (3,)], ex, shared=10) == [100, 1000]


def test_move_rebuilds_containers():
    x = {"a": [torch.zeros(2, dtype=torch.float64)], "b": (1, "s")}
    y = move(x, "cpu")
    assert y["b"] == (1, "s") and torch.equal(y["a"][0], x["a"][0])
    tree = move(stems(2), "cpu")
    assert isinstance(tree, Trees) and tree.num_trees == 2


class FakeRay:
    """The part of Ray's API the adapter uses: init, remote functions whose calls give object references with a
    ``future()``, shutdown."""

    def __init__(self) -> None:
        self.address, self.down = "unset", False

    def init(self, address=None, ignore_reinit_error=False):
        self.address = address

    def remote(self, fn):
        from concurrent.futures import Future

        class Ref:
            def __init__(self, value):
                self.value = value

            def future(self):
                f = Future()
                f.set_result(self.value)
                return f

        class Remote:
            def remote(self, *args, **kwargs):
                return Ref(fn(*args, **kwargs))

        return Remote()

    def shutdown(self):
        self.down = True


def test_the_ray_adapter_on_a_stand_in(monkeypatch):
    fake = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", fake)
    with make_executor(scheduler="ray://head:10001") as ex:
        assert fake.address == "ray://head:10001"
        assert run_tasks(divmod, [(7, 2)], ex) == [(3, 1)]
        assert torch.equal(pairwise_distances(stems(3), executor=ex, progress=False),
                           pairwise_distances(stems(3), processes=1, progress=False))
    assert fake.down
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match="pip install ray"):
        make_executor(scheduler="ray")
