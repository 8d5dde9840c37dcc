"""Where heavy work runs: inline, on local processes or on a Dask cluster, behind one ``concurrent.futures.Executor``.

Every heavy entry point (reading a dataset, all-pairs distances, the population fit's registrations, encoding many
plants, the evaluation's distance matrices) takes an optional ``executor``: anything with ``submit`` (and ``map``)
as :class:`concurrent.futures.Executor` defines it. :func:`make_executor` builds one from a worker count or a Dask
scheduler address (what the CLI's ``--workers`` / ``--scheduler`` give); :func:`local_executor` is the local process
pool. Tasks are top-level functions of picklable arguments (tensors on the CPU), so they run the same wherever they
run, and results do not depend on the executor (docs/distributed.md).
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from typing import Any

__all__ = ["DISTRIBUTED_HINT", "DaskExecutor", "InlineExecutor", "RayExecutor", "check_executor", "local_executor",
           "make_executor", "single_thread"]

DISTRIBUTED_HINT = "pip install torch4dtree[distributed]"


class InlineExecutor(Executor):
    """Runs every task at once in the calling thread (no pickling): what running without an executor means.

    Example:
        >>> with InlineExecutor() as ex:
        ...     ex.submit(pow, 2, 10).result(), list(ex.map(abs, [-1, 2]))
        (1024, [1, 2])
    """

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:  # noqa: ANN401
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as e:  # the task's error is the future's, as on any executor
            future.set_exception(e)
        return future


def single_thread() -> None:
    """Worker initializer: one compute thread per process (the processes are the parallelism)."""
    import torch

    torch.set_num_threads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # pragma: no cover - numba missing or already single-threaded
        pass


def local_executor(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned, single-threaded processes on this machine (spawn: forking after torch / numba
    threads started is unsafe). Each worker pays seconds of start-up (torch import, kernel cache load).

    Example:
        >>> local_executor(2)._max_workers
        2
    """
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=single_thread)


class DaskExecutor(Executor):
    """A Dask ``distributed`` client's executor that also closes the client on shutdown. Its workers compute on
    one thread each (torch, numba: :func:`single_thread`; run one worker thread a core). Tasks are impure (never
    deduplicated by hashing their arguments); a task whose worker dies is re-run elsewhere by the scheduler
    (up to its ``distributed.scheduler.allowed-failures``)."""

    def __init__(self, client: Any) -> None:  # noqa: ANN401 - distributed.Client, imported lazily
        from distributed.diagnostics.plugin import WorkerPlugin

        class SingleThread(WorkerPlugin):
            """Every worker, also one started later, computes on one thread per task thread."""

            name = "torch4dtree-single-thread"

            def setup(self, worker: Any) -> None:  # noqa: ANN401
                single_thread()

        self.client = client
        client.register_plugin(SingleThread())
        self._executor = client.get_executor(pure=False)

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:  # noqa: ANN401
        return self._executor.submit(fn, *args, **kwargs)

    def scatter(self, data: Any) -> Any:  # noqa: ANN401 - any picklable value; a distributed.Future
        """``data`` sent once to every worker (``Client.scatter``, broadcast); the returned future, passed to
        :meth:`submit` in place of ``data``, is ``data`` in the task (a fitted model many tasks need travels once)."""
        return self.client.scatter(data, broadcast=True, hash=False)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._executor.shutdown(wait=wait and not cancel_futures)
        self.client.close()


class RayExecutor(Executor):
    """Tasks as Ray remote calls (``ray.init(address)``; a crashed worker's task is retried, Ray's
    ``max_retries``). Each ``submit`` returns the ``concurrent.futures.Future`` of the call's object reference.
    Needs ``pip install ray`` (not an extra of this package: the tests run on Dask)."""

    def __init__(self, address: str | None = None) -> None:
        try:
            import ray
        except ImportError as e:
            raise ImportError("a Ray cluster needs ray: pip install ray") from e
        ray.init(address=address, ignore_reinit_error=True)
        self._ray, self._call = ray, ray.remote(_call)

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:  # noqa: ANN401
        return self._call.remote(fn, *args, **kwargs).future()

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._ray.shutdown()


def _call(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:  # noqa: ANN401
    """A Ray task running ``fn(*args, **kwargs)`` (Ray's remote functions are wrapped functions)."""
    return fn(*args, **kwargs)


def make_executor(workers: int | None = None, scheduler: str | None = None) -> Executor:
    """The executor for ``workers`` local processes or a Dask scheduler; use it as a context manager.

    Args:
        workers: ``None`` or 1: :class:`InlineExecutor` (no processes); ``N > 1``: :func:`local_executor` of ``N``.
        scheduler: a Dask scheduler address (``"tcp://host:8786"``): its cluster's workers run the tasks
            (``workers`` is then ignored). Needs ``pip install torch4dtree[distributed]``. ``"ray"`` (this machine's
            Ray cluster) or a ``"ray://host:10001"`` address: :class:`RayExecutor`.

    Example:
        >>> with make_executor() as ex:
        ...     list(ex.map(len, ["ab", "c"]))
        [2, 1]
    """
    if scheduler is not None and (scheduler == "ray" or scheduler.startswith("ray://")):
        return RayExecutor(None if scheduler == "ray" else scheduler)
    if scheduler is not None:
        try:
            from distributed import Client
        except ImportError as e:
            raise ImportError(f"a Dask scheduler needs dask[distributed]: {DISTRIBUTED_HINT}") from e
        return DaskExecutor(Client(scheduler))
    if workers is None or workers == 1:
        return InlineExecutor()
    return local_executor(workers)


def check_executor(executor: object) -> Executor | None:
    """``executor`` if it can run tasks (has ``submit``), ``None`` stays ``None``; anything else is a TypeError.

    Example:
        >>> check_executor(None) is None
        True
    """
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError(f"executor must be a concurrent.futures.Executor (with submit), got {type(executor).__name__}")
    return executor  # type: ignore[return-value]
