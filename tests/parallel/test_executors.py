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


def test_move_rebuilds_containers():
    x = {"a": [torch.zeros(2, dtype=torch.float64)], "b": (1, "s")}
    y = move(x, "cpu")
    assert y["b"] == (1, "s") and torch.equal(y["a"][0], x["a"][0])
    tree = move(stems(2), "cpu")
    assert isinstance(tree, Trees) and tree.num_trees == 2
