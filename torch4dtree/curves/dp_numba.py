"""The numba backend of the DP warp and of curve registration (CPU, threads over pairs): the driver of the compiled
kernels of :mod:`.kernels_numba`.

See :mod:`torch4dtree.curves.register` for the energy and the lattice. ``nb_pairs`` is the only kernel called from
Python, so the whole engine is one compiled signature (a cold compile of each extra entry point would repeat most of
the work; compiled once and cached on disk). Batches of at least ``2 * PARALLEL_MIN_PAIRS`` pairs are shared between
threads (the kernel releases the GIL) in chunks of ``THREAD_CHUNK`` pairs handed out on demand; smaller ones run on the
calling thread alone. Every pair's result is computed alone, so it is the same whatever the batch, chunk or thread.
The first compile in a process prints a one-line notice.
"""

from __future__ import annotations

import itertools
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
from torch import Tensor

from .srvf import inverse_srvf
from .warps import step_arrays

try:  # numba is optional: without it the torch backend is used everywhere
    import numba
    import numba.core.event

    from .kernels_numba import nb_dp_serial, nb_pairs, nb_warp_energies
    from .refinement import nb_refine_finer

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False


# ----------------------------------------------------------------------------- threads
# Each thread gets at least this many pairs: a small batch runs on the calling thread alone, because
# waking a second thread costs more than it saves, and on a machine whose other cores are busy the
# woken thread can wait a whole scheduler time slice (milliseconds) for a core.
PARALLEL_MIN_PAIRS = 16
# Pairs a thread takes at a time from a shared batch (benchmarks/bench_batch.py, docs/experiments.md): the calling
# thread keeps taking chunks until none is left, so a helper thread that waits for a core (the other cores busy) holds
# up at most one chunk instead of a fixed share of the batch; large enough that the per-call overhead of the kernel
# (a few microseconds against about 0.3 ms a pair at T = 100) stays negligible.
THREAD_CHUNK = 4

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
_COMPILE_LOCK = threading.Lock()


def idle_cores() -> int:
    """Cores of this process's CPU set that no runnable thread holds right now, besides the caller's own: the
    kernel's count of runnable threads (``/proc/loadavg``, Linux; it includes the caller). Where that count is not
    available, every other core of the set counts as idle."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        with open("/proc/loadavg", encoding="ascii") as f:
            running = int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return cores - 1
    return max(cores - running, 0)


def pair_threads(n_pairs: int) -> int:
    """Threads used for a batch of ``n_pairs``: 1 below ``2 * PARALLEL_MIN_PAIRS`` pairs, else up to
    ``numba.get_num_threads()`` (which honours ``NUMBA_NUM_THREADS`` and ``numba.set_num_threads``), one per
    ``PARALLEL_MIN_PAIRS`` pairs, and the caller plus one per :func:`idle_cores` (a thread woken on a busy core only
    queues for it)."""
    if not HAVE_NUMBA or n_pairs < 2 * PARALLEL_MIN_PAIRS:
        return 1
    wanted = min(numba.get_num_threads(), n_pairs // PARALLEL_MIN_PAIRS)
    return max(1, min(wanted, 1 + idle_cores())) if wanted > 1 else 1


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=max(os.cpu_count() or 1, 1), thread_name_prefix="torch4dtree")
        return _POOL


# ----------------------------------------------------------------------------- compile notice
# what the first-compile notice announces (the cold compile of nb_pairs; cached on disk afterwards)
COMPILE_ESTIMATE = "about a minute on 2 cores"
_READY = False  # the kernels have been loaded (or compiled) in this process


def _note(text: str) -> None:
    print(f"torch4dtree: {text}", file=sys.stderr, flush=True)


class _CompileNotice(numba.core.event.Listener if HAVE_NUMBA else object):  # type: ignore[misc]
    """Says once, on stderr, that the kernels are being compiled (a numba cache miss), and how long it took."""

    def __init__(self, hint: bool = True) -> None:
        self.hint = hint  # point to ``torch4dtree warmup`` (not when that is what runs)
        self.depth = 0
        self.t0 = 0.0
        self.seconds: float | None = None

    def on_start(self, event: object) -> None:
        if self.depth == 0 and self.seconds is None:
            self.t0 = time.perf_counter()
            hint = "; `torch4dtree warmup` does it ahead of time" if self.hint else ""
            _note(f"compiling the registration kernels, once after installing or updating ({COMPILE_ESTIMATE}; "
                  f"cached for later runs{hint})...")
        self.depth += 1

    def on_end(self, event: object) -> None:
        self.depth -= 1
        if self.depth == 0 and self.seconds is None:
            self.seconds = time.perf_counter() - self.t0
            _note(f"kernels compiled in {self.seconds:.0f} s")


def _first_call(*args: object, hint: bool = True) -> float | None:
    """The first kernel call of the process, listening for a compile (instead of a load from the disk cache).
    Returns the compile time in seconds, or None if the kernels came from the cache."""
    global _READY
    with _COMPILE_LOCK:  # one thread compiles; the others wait for it
        if _READY:
            nb_pairs(*args)
            return None
        notice = _CompileNotice(hint)
        with numba.core.event.install_listener("numba:compile", notice):
            nb_pairs(*args)
            # the temporal registration's refinement on a finer moving trajectory (its real calls' argument types)
            nb_refine_finer(np.zeros((0, 2, 1)), np.zeros((0, 3, 1)), np.zeros((0, 3)), 0, np.ones(1, np.int64),
                             np.zeros(0, np.bool_))
            # the tree registration's energies of several warps of one parent pair
            nb_warp_energies(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((0, 2)), np.zeros(0))
        _READY = True
        return notice.seconds


def run_pairs(curves: bool, mov: np.ndarray, ref: np.ndarray, srvf_input: bool, steps: tuple[np.ndarray, ...],
              cfg: np.ndarray, up: np.ndarray, tol: float) -> tuple[np.ndarray, ...]:
    """Run :func:`nb_pairs` over a batch on :func:`pair_threads` threads (the calling thread takes chunks too).

    ``steps = (A, Bs, Af, Bf)``. Returns ``energy (B,), before (B,), gamma (B, T), O (B, d, d), registered
    (B, T, d), q_reg (B, T-1, d)``; the last two are empty ``(0, 0, 0)`` arrays unless ``curves``.
    """
    B, d = ref.shape[0], ref.shape[2]
    T = ref.shape[1] + (1 if (srvf_input or not curves) else 0)
    shape = (B, T, d) if curves else (0, 1, 0)
    outs = (np.empty(B), np.empty(B), np.empty((B, T)), np.empty((B, d, d)), np.empty(shape),
            np.empty((shape[0], shape[1] - 1, shape[2])))

    def pairs(a: int, b: int) -> None:  # pairs a..b-1 (views of contiguous rows: the same compiled signature)
        nb_pairs(bool(curves), mov[a:b], ref[a:b], bool(srvf_input), *steps, cfg, up, float(tol), 0, 1,
                 *(o[a:b] for o in outs))

    if not _READY:
        _first_call(bool(curves), mov[:0], ref[:0], bool(srvf_input), *steps, cfg, up, float(tol), 0, 1, *outs)
    threads = pair_threads(B)
    if threads == 1:
        pairs(0, B)
        return outs
    chunks = itertools.count()  # next() is atomic under the GIL: each chunk goes to exactly one thread

    def take() -> None:
        while (a := next(chunks) * THREAD_CHUNK) < B:
            pairs(a, min(a + THREAD_CHUNK, B))

    futures = [_pool().submit(take) for _ in range(1, threads)]
    take()
    for f in futures:  # a helper that has not started yet is not waited for
        if not f.cancel():
            f.result()
    return outs


def warm_up() -> float | None:
    """Load the kernels from the disk cache, or compile them (printing a notice) if the cache is cold.
    Returns the compile time in seconds, or None if nothing was compiled (or numba is missing)."""
    if not HAVE_NUMBA:
        return None
    global _READY
    if _READY:
        return None
    z = np.zeros((0, 8, 3))
    A, Bs = step_arrays(2)
    outs = (np.empty(0), np.empty(0), np.empty((0, 8)), np.empty((0, 3, 3)), np.empty((0, 8, 3)), np.empty((0, 7, 3)))
    # the same argument types as run_pairs, so this compiles (or loads) the one signature real calls use
    return _first_call(True, z, z, False, A, Bs, A, Bs, np.zeros(9, np.int64), np.zeros(3), 0.0, 0, 1, *outs,
                       hint=False)


def warp_energies_numba(q1: np.ndarray, q2: np.ndarray, gammas: np.ndarray) -> np.ndarray:
    """:func:`nb_warp_energies` on float64 arrays ``q1, q2 (M, d)``, ``gammas (n, M+1)``: ``(n,)``."""
    out = np.empty(gammas.shape[0])
    nb_warp_energies(q1, q2, np.ascontiguousarray(gammas, dtype=np.float64), out)
    return out


def banded_dp_numba(q1: Tensor, q2: Tensor, n: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Tensor, Tensor]:
    A, Bs = step_arrays(n)
    q1n = q1.detach().to("cpu", torch.float64).contiguous().numpy()
    beta2 = inverse_srvf(q2.detach().to("cpu", torch.float64)).contiguous().numpy()
    energy, gamma = nb_dp_serial(q1n, beta2, A, Bs, lo, hi)
    return torch.from_numpy(energy), torch.from_numpy(gamma)


# ----------------------------------------------------------------------------- torch backend

