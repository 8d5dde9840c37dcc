"""The numba driver: threads chosen by batch size (same results either way) and the compile notice."""

import os

import numpy as np
import pytest
import torch

from torch4dtree.curves import dp_numba, register_curves

pytestmark = pytest.mark.skipif(not dp_numba.HAVE_NUMBA, reason="numba not installed")


def curves(n: int, T: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(n, T, 3, generator=g, dtype=torch.float64).cumsum(1)


def test_small_batches_stay_on_the_calling_thread(monkeypatch):
    monkeypatch.setattr(dp_numba, "idle_cores", lambda: 64)
    assert dp_numba.pair_threads(1) == 1
    assert dp_numba.pair_threads(2 * dp_numba.PARALLEL_MIN_PAIRS - 1) == 1
    big = dp_numba.pair_threads(64 * dp_numba.PARALLEL_MIN_PAIRS)
    import numba

    assert big == numba.get_num_threads()
    # a single pair and a small batch never touch the thread pool
    monkeypatch.setattr(dp_numba, "_pool", lambda: pytest.fail("small batches must not use threads"))
    register_curves(curves(1, 20, 0)[0], curves(1, 20, 1)[0], rotation="so3")
    register_curves(curves(5, 20, 0), curves(5, 20, 1), rotation="so3")


def test_threads_change_no_result(monkeypatch):
    import numba

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread")
    x, y = curves(12, 30, 2), curves(12, 30, 3)
    monkeypatch.setattr(dp_numba, "PARALLEL_MIN_PAIRS", 10**6)  # serial
    serial = register_curves(y, x, rotation="vertical")
    used = []
    real_pool = dp_numba._pool
    monkeypatch.setattr(dp_numba, "_pool", lambda: used.append(1) or real_pool())
    monkeypatch.setattr(dp_numba, "PARALLEL_MIN_PAIRS", 3)  # 4 threads' worth of pairs
    monkeypatch.setattr(dp_numba, "idle_cores", lambda: 64)
    threaded = register_curves(y, x, rotation="vertical")
    assert used, "the threaded path did not run"
    for a, b in zip(serial, threaded):
        assert torch.equal(a, b)


def test_compile_notice_once_with_the_time(capsys):
    """The listener prints one notice when a compile starts (nested compiles add nothing) and the time at the end;
    hooked to numba's compile event, a real compile triggers it and a second call (no compile) does not."""
    import numba
    import numba.core.event as ev

    notice = dp_numba._CompileNotice()
    notice.on_start(None)
    notice.on_start(None)  # a callee compiled inside
    notice.on_end(None)
    assert capsys.readouterr().err.count("compiling the registration kernels") == 1
    notice.on_end(None)
    err = capsys.readouterr().err
    assert err.startswith("torch4dtree: kernels compiled in ") and notice.seconds is not None

    @numba.njit  # no cache: compiles on its first call
    def twice(x: float) -> float:
        return 2.0 * x

    notice = dp_numba._CompileNotice()
    with ev.install_listener("numba:compile", notice):
        assert twice(1.5) == 3.0
        first = capsys.readouterr().err
        assert twice(2.5) == 5.0
    assert first.count("compiling the registration kernels") == 1 and "kernels compiled in" in first
    assert capsys.readouterr().err == ""


def test_warm_up_then_no_notice(capsys):
    dp_numba.warm_up()  # loads from the cache (or compiles, with the notice)
    capsys.readouterr()
    assert dp_numba.warm_up() is None
    register_curves(curves(2, 16, 4), curves(2, 16, 5))
    assert capsys.readouterr().err == ""
    out = dp_numba.run_pairs(False, np.zeros((0, 7, 3)), np.zeros((0, 7, 3)), False,
                             dp_numba.step_arrays(2) * 2, np.zeros(9, np.int64), np.zeros(3), 0.0)
    assert [o.shape for o in out] == [(0,), (0,), (0, 8), (0, 3, 3), (0, 1, 0), (0, 0, 0)]


@pytest.mark.parametrize("chunk", [1, 3, 64])
def test_chunked_threads_equal_single_calls(monkeypatch, chunk):
    """A batch shared between threads in chunks (any chunk size) gives every pair bit for bit what a single call
    gives: registrations with a rotation and the tree solver's DP warps."""
    import numba

    from torch4dtree.curves import dp_warp, srvf

    x, y = curves(11, 40, 4), curves(11, 40, 5)
    singles = [register_curves(y[b], x[b], rotation="so3") for b in range(11)]
    warps = [dp_warp(srvf(x[b]), srvf(y[b]), neighbourhood=4) for b in range(11)]
    monkeypatch.setattr(dp_numba, "PARALLEL_MIN_PAIRS", 2)
    monkeypatch.setattr(dp_numba, "THREAD_CHUNK", chunk)
    monkeypatch.setattr(dp_numba, "idle_cores", lambda: 64)
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        batch = register_curves(y, x, rotation="so3")
        dp = dp_warp(srvf(x), srvf(y), neighbourhood=4)
    finally:
        numba.set_num_threads(before)
    for b in range(11):
        for one, many in zip(singles[b], batch):
            assert torch.equal(one, many[b])
        assert torch.equal(warps[b].gamma, dp.gamma[b]) and torch.equal(warps[b].energy, dp.energy[b])


def test_busy_cores_keep_a_batch_on_the_calling_thread(monkeypatch):
    """No idle core: a big batch stays on the calling thread (a woken thread would only queue for a busy core)."""
    import numba

    monkeypatch.setattr(dp_numba, "idle_cores", lambda: 0)
    assert dp_numba.pair_threads(64 * dp_numba.PARALLEL_MIN_PAIRS) == 1
    monkeypatch.setattr(dp_numba, "idle_cores", lambda: 1)
    assert dp_numba.pair_threads(64 * dp_numba.PARALLEL_MIN_PAIRS) == min(2, numba.get_num_threads())
    assert 0 <= dp_numba.idle_cores() < (os.cpu_count() or 1)
