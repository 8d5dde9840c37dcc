"""``torch4dtree warmup``: compile the registration kernels now (numba, cached on disk), so that the first
``register`` (or any registration from Python) starts at full speed."""

from __future__ import annotations

import argparse
import time


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = ("The kernels compile once after installing or updating the package and are then loaded from "
                "numba's cache (__pycache__ beside the sources) in about a second.")


def run(args: argparse.Namespace) -> int:
    from ..curves.dp_numba import HAVE_NUMBA, warm_up

    if not HAVE_NUMBA:
        print("numba is not installed: registration uses the torch backend, nothing to compile")
        return 0
    from ..trees.decode_numba import warm_up as warm_up_decode

    t0 = time.perf_counter()
    compiled = warm_up()
    warm_up_decode()  # the tree decoding kernels (small: seconds cold)
    seconds = time.perf_counter() - t0
    if compiled is None:
        print(f"registration kernels ready (loaded from the cache in {seconds:.1f} s)")
    else:
        print(f"registration kernels ready (compiled in {compiled:.0f} s; later runs load them from the cache)")
    return 0
