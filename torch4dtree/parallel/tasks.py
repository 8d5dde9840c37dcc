"""Run independent tasks on an executor: arguments shipped on the CPU, results back on the driver's device.

A task is a top-level function and a tuple of picklable arguments: tensors and the package's tensor containers
(``Trees``, ``TreeSequence``, ``AlignedSequence``, ...: anything with ``.to(device)`` that returns a copy),
NamedTuples, lists, tuples and dicts of them. Without an executor the tasks run inline, untouched (no copies).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from typing import Any

import torch

from .executors import check_executor

__all__ = ["IN_FLIGHT", "move", "run_tasks"]

# tasks submitted ahead of the finished ones: every worker stays busy while the driver holds a bounded number of
# shipped arguments and results
IN_FLIGHT = 64


def move(obj: Any, device: torch.device | str) -> Any:  # noqa: ANN401 - any nesting of tensor containers
    """``obj`` with every tensor it holds on ``device`` (containers rebuilt, other values kept).

    Example:
        >>> move({"a": (torch.zeros(1), 2)}, "cpu")
        {'a': (tensor([0.]), 2)}
    """
    if isinstance(obj, torch.Tensor):
        return obj.to(device)
    if isinstance(obj, torch.nn.Module):  # .to would move the caller's module in place: pickling copies it anyway
        return obj
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):
        return type(obj)(*(move(x, device) for x in obj))
    if isinstance(obj, (list, tuple)):
        return type(obj)(move(x, device) for x in obj)
    if isinstance(obj, dict):
        return {k: move(v, device) for k, v in obj.items()}
    if callable(getattr(obj, "to", None)) and not isinstance(obj, type):
        return obj.to(device)
    return obj


def _on_cpu(fn: Callable[..., Any], args: tuple) -> Any:  # noqa: ANN401
    """Worker side: ``fn(*args)`` with the result on the CPU (for transport)."""
    return move(fn(*args), "cpu")


def run_tasks(fn: Callable[..., Any], tasks: Iterable[tuple], executor: Executor | None = None,
              device: torch.device | str | None = None,
              done: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(*task) for task in tasks]``, on ``executor`` if given (``fn`` top-level, so it pickles).

    Each task's arguments are shipped on the CPU and its result moved to ``device`` (default: the CPU) on return;
    at most ``IN_FLIGHT`` tasks are submitted ahead. ``done(index, result)`` is called on the driver as each task
    finishes (in completion order), e.g. for progress or to save it. Inline (``executor=None``) the tasks run in
    order on the arguments as given. A task's error is raised here.

    Example:
        >>> run_tasks(divmod, [(7, 2), (9, 4)])
        [(3, 1), (2, 1)]
    """
    executor = check_executor(executor)
    tasks = list(tasks)
    out: list[Any] = [None] * len(tasks)
    if executor is None:
        for i, task in enumerate(tasks):
            out[i] = fn(*task)
            if done is not None:
                done(i, out[i])
        return out
    target = torch.device(device) if device is not None else torch.device("cpu")
    pending: dict[Future, int] = {}
    queue = iter(enumerate(tasks))

    def top_up() -> None:
        for i, task in queue:
            pending[executor.submit(_on_cpu, fn, move(task, "cpu"))] = i
            if len(pending) >= IN_FLIGHT:
                return

    top_up()
    try:
        while pending:
            finished, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for future in finished:
                i = pending.pop(future)
                out[i] = move(future.result(), target)
                if done is not None:
                    done(i, out[i])
            top_up()
    finally:
        for future in pending:
            future.cancel()
    return out


