"""Run independent tasks on an executor: arguments shipped on the CPU, results back on the driver's device.

A task is a top-level function and a tuple of picklable arguments: tensors and the package's tensor containers
(``Trees``, ``TreeSequence``, ``AlignedSequence``, ...: anything with ``.to(device)`` that returns a copy),
NamedTuples, lists, tuples and dicts of them. Without an executor the tasks run inline, untouched (no copies).
"""

from __future__ import annotations

import hashlib
import pickle
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from typing import Any

import torch

from .executors import check_executor

__all__ = ["IN_FLIGHT", "move", "pack", "run_packed", "run_shared", "run_tasks", "unpack"]

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


def _pickler() -> Any:  # noqa: ANN401 - a module with dumps / loads
    """cloudpickle where installed (closures and interactively defined functions travel too), else pickle."""
    try:
        import cloudpickle

        return cloudpickle
    except ImportError:  # pragma: no cover - dask[distributed] brings cloudpickle
        return pickle


def pack(obj: Any) -> bytes:  # noqa: ANN401
    """``obj`` as bytes, its tensors moved to the CPU and copied in (no shared memory).

    A process pool hands arguments to a feeder thread that moves tensors to shared memory in place while the
    caller may still read them (a crash); bytes made on the caller's thread are independent of the caller's tensors.

    Example:
        >>> unpack(pack((torch.ones(2), "a")))
        (tensor([1., 1.]), 'a')
    """
    return _pickler().dumps(move(obj, "cpu"), protocol=pickle.HIGHEST_PROTOCOL)


def unpack(data: bytes) -> Any:  # noqa: ANN401
    """The object :func:`pack` made."""
    return pickle.loads(data)


def run_packed(data: bytes) -> bytes:
    """Worker side of a task: ``fn(*args)`` of the packed ``(fn, args)``, its result packed."""
    fn, args = unpack(data)
    return pack(fn(*args))


# the shared argument a worker process unpacked last (run_shared): (digest of its bytes, the object)
_SHARED: dict[str, Any] = {}


def run_shared(shared: bytes, data: bytes) -> bytes:
    """Worker side of a task with a shared first argument: ``fn(obj, *args)``, ``obj`` unpacked from ``shared``
    once per worker process (kept by the digest of its bytes; one object at a time), its result packed."""
    key = hashlib.blake2b(shared, digest_size=16).hexdigest()
    if key not in _SHARED:
        _SHARED.clear()
        _SHARED[key] = unpack(shared)
    fn, args = unpack(data)
    return pack(fn(_SHARED[key], *args))


def run_tasks(fn: Callable[..., Any], tasks: Iterable[tuple], executor: Executor | None = None,
              device: torch.device | str | None = None,
              done: Callable[[int, Any], None] | None = None, keep: bool = True, shared: Any = None) -> list[Any]:
    """``[fn(*task) for task in tasks]``, on ``executor`` if given (``fn`` top-level, so it pickles); with
    ``shared``, ``[fn(shared, *task) ...]``.

    Each task's function and arguments are shipped as bytes (:func:`pack`: tensors on the CPU) and its result moved
    to ``device`` (default: the CPU) on return;
    ``tasks`` is read lazily and at most ``IN_FLIGHT`` tasks are submitted ahead. ``done(index, result)`` is called
    on the driver as each task finishes (the finished ones in submission order; each before the next task is
    submitted), e.g. for progress or to save it. ``keep=False``: results are dropped after ``done`` (an empty list
    is returned; memory stays bounded). Inline (``executor=None``) the tasks run in order on the arguments as
    given. A task's error is raised here. ``shared`` (e.g. a fitted model every task needs) is packed once; an
    executor with a ``scatter`` method (:class:`~torch4dtree.parallel.DaskExecutor`) sends it to every worker once
    and the tasks refer to it, others ship its bytes with each task; a worker unpacks it once.

    Example:
        >>> run_tasks(divmod, [(7, 2), (9, 4)])
        [(3, 1), (2, 1)]
    """
    executor = check_executor(executor)
    out: dict[int, Any] = {}

    def finish(i: int, result: Any) -> None:  # noqa: ANN401
        if done is not None:
            done(i, result)
        if keep:
            out[i] = result

    if executor is None:
        for i, task in enumerate(tasks):
            finish(i, fn(*task) if shared is None else fn(shared, *task))
        return [out[i] for i in range(len(out))]
    target = torch.device(device) if device is not None else torch.device("cpu")
    pending: dict[Future, int] = {}
    common: Any = None
    if shared is not None:
        common = pack(shared)
        scatter = getattr(executor, "scatter", None)
        common = scatter(common) if callable(scatter) else common

    def submit(task: tuple) -> Future:
        if shared is None:
            return executor.submit(run_packed, pack((fn, task)))
        return executor.submit(run_shared, common, pack((fn, task)))

    def collect(finished: Iterable[Future]) -> None:
        for future in sorted(finished, key=pending.__getitem__):  # in submission order among the finished
            i = pending.pop(future)
            finish(i, move(unpack(future.result()), target))

    try:
        for i, task in enumerate(tasks):  # every finished task is stored before the next is submitted
            if len(pending) >= IN_FLIGHT:
                collect(wait(list(pending), return_when=FIRST_COMPLETED)[0])
            pending[submit(task)] = i
            collect([f for f in pending if f.done()])
        while pending:
            collect(wait(list(pending), return_when=FIRST_COMPLETED)[0])
    finally:
        for future in pending:
            future.cancel()
    return [out[i] for i in range(len(out))]


