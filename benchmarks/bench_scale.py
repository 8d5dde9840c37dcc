"""Scaling benchmark (docs/scaling.md): time and peak memory of reading a dataset, fitting the organ model and the
paper's model, and all-pairs distances on 1 and 2 workers, for synthetic tomatoes at several sizes; each stage in a
fresh process; growth exponents (log-log slopes) and the all-pairs speed-up.

    python benchmarks/bench_scale.py [--sizes 25 50 100 200] [--frames 3] [--T 16] [--workers 1 2]
                                     [--stages read fit_organs fit_paper pairs] [--keep DIR] [--json]

The same as ``torch4dtree benchmark scale`` with every knob; 25-100 plants take about 18 minutes on 2 idle
cores, 200 about 30 more.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from torch4dtree.bench.scale import DEFAULT_FRAMES, DEFAULT_SIZES, DEFAULT_T, STAGES, benchmark_scale, format_table


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=list(DEFAULT_SIZES))
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES)
    p.add_argument("--T", type=int, default=DEFAULT_T)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--stages", nargs="+", default=list(STAGES), choices=STAGES)
    p.add_argument("--keep", type=Path, default=None, help="write (and reuse) the datasets in this folder")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    result = benchmark_scale(a.sizes, a.frames, a.T, a.workers, a.stages, keep=a.keep,
                             log=lambda line: print(line, file=sys.stderr, flush=True))
    print(json.dumps(result) if a.json else format_table(result))


if __name__ == "__main__":
    main()
