"""Scaling benchmark: time and peak memory of reading a dataset, fitting both generative models and all-pairs
distances, against the number of plants (docs/scaling.md).

Each (stage, size) runs in a fresh Python process (``python -m torch4dtree.bench.scale STAGE ...``), so its peak
resident memory (``ru_maxrss``) is the stage's own and nothing is cached between stages; the worker processes of a
parallel all-pairs report their own peak separately (``children_peak_mb``). The dataset is synthetic growing tomatoes
(:func:`torch4dtree.data.synthetic_dataset`) written once per size as SWC folders (not timed). The growth exponent of
a stage is the least-squares slope of log(time) (or log(peak memory)) against log(plants).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_SIZES", "STAGES", "benchmark_scale", "format_table", "growth_exponent", "run_stage",
           "write_dataset"]

# plants per run of the default benchmark (25-100 plants took 18 minutes on 2 idle cores; 200 add about 30)
DEFAULT_SIZES = (25, 50, 100, 200)
# frames per plant and points per branch: small, so that the largest size stays within minutes
DEFAULT_FRAMES = 3
DEFAULT_T = 16
# stages, in the order they run; "pairs" runs once per worker count
STAGES = ("read", "fit_organs", "fit_paper", "pairs")
# the settings of the synthetic tomatoes (the repository's config of that dataset)
CONFIG = Path(__file__).resolve().parents[2] / "configs" / "synthetic_tomato.json"


def write_dataset(root: Path, plants: int, frames: int = DEFAULT_FRAMES, T: int = DEFAULT_T, seed: int = 0) -> Path:
    """Write ``plants`` synthetic tomatoes of ``frames`` frames as SWC sequence folders under ``root``; returns root.

    Example:
        >>> import tempfile
        >>> root = write_dataset(Path(tempfile.mkdtemp()) / "d", plants=1, frames=2, T=8)
        >>> sorted(p.name for p in root.iterdir())
        ['tomato_00']
    """
    from ..data import synthetic_dataset
    from ..io import write_sequence

    for p in synthetic_dataset("tomato", plants=plants, seed=seed, n_frames=frames, T=T):
        write_sequence(root / p.name, p.sequence)
    return root


def _config(T: int) -> Any:
    """The synthetic tomatoes' config (defaults if the repository's configs/ is not there) at ``T`` points."""
    from ..config import Config, load_config

    cfg = load_config(CONFIG) if CONFIG.is_file() else Config()
    return dataclasses.replace(cfg, T=T)


def _read(root: Path, T: int) -> list:
    """The dataset's 4D trees, read as ``torch4dtree fit`` reads them."""
    import torch

    from ..io import read_dataset

    opts = dataclasses.replace(_config(T).load_options(), dtype=torch.float64)
    return [s.sequence for s in read_dataset(root, opts)]


def _pairs(seqs: list, T: int, workers: int) -> int:
    """All-pairs distances of the plants' last frames on ``workers`` processes (1: inline); returns the pair count."""
    from ..trees import Trees
    from ..trees.pairwise import pairwise_distances

    trees = Trees.cat([s.frames[s.frames.num_trees - 1] for s in seqs])
    cfg = _config(T)
    kwargs = {"rotation": cfg.rotation, "neighbourhood": cfg.neighbourhood, "lambdas": cfg.lambdas}
    executor = None
    try:  # the package's executors where they exist, else pairwise_distances' own pool
        from ..parallel import local_executor  # type: ignore[attr-defined]

        executor = local_executor(workers) if workers > 1 else None
    except ImportError:
        pass
    try:
        pairwise_distances(trees, processes=workers, progress=False, executor=executor, **kwargs)
    finally:
        if executor is not None:
            executor.shutdown()
    n = trees.num_trees
    return n * (n - 1) // 2


def run_stage(stage: str, root: Path, T: int = DEFAULT_T, workers: int = 1) -> dict[str, Any]:
    """Run one stage in this process: ``{"seconds", "cpu_seconds", "peak_mb", "base_mb", "children_peak_mb", ...}``.

    ``base_mb`` is the peak resident memory after the imports and (for the fits and all-pairs) after reading the
    dataset, before the stage: ``peak_mb - base_mb`` is what the stage itself adds. Call it in a fresh process
    (:func:`benchmark_scale` does) for an honest peak.
    """
    import torch

    from ..model import FourDTreeModel, OrganModel

    torch.set_num_threads(1)
    try:
        import numba

        numba.set_num_threads(1)
        from ..curves.dp_numba import warm_up

        warm_up()
    except ImportError:  # pragma: no cover - torch backend
        pass
    if stage not in STAGES:
        raise ValueError(f"unknown stage {stage!r}; expected one of {STAGES}")
    seqs = [] if stage == "read" else _read(root, T)
    cfg = _config(T)
    base = _peak_mb(resource.RUSAGE_SELF)
    cpu0 = _cpu_seconds(resource.RUSAGE_SELF) + _cpu_seconds(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out: dict[str, Any] = {}
    if stage == "read":
        seqs = _read(root, T)
    elif stage == "fit_organs":
        OrganModel(cfg.organ_settings()).fit(seqs)
    elif stage == "fit_paper":
        report = FourDTreeModel(cfg.model_settings()).fit(seqs, progress=False).report_
        out.update(slots=report["population"]["slots"], dropped_share=report["population"].get("dropped_share", 0.0),
                   parts=report["seconds"])
    else:
        out["pairs"] = _pairs(seqs, T, workers)
    cpu = _cpu_seconds(resource.RUSAGE_SELF) + _cpu_seconds(resource.RUSAGE_CHILDREN) - cpu0
    out.update(seconds=time.perf_counter() - t0, cpu_seconds=cpu, peak_mb=_peak_mb(resource.RUSAGE_SELF),
               base_mb=base, children_peak_mb=_peak_mb(resource.RUSAGE_CHILDREN), plants=len(seqs),
               frames=sum(s.frames.num_trees for s in seqs), workers=workers)
    return out


def _peak_mb(who: int) -> float:
    """Peak resident memory (MB) of this process or of its finished children (Linux reports KiB)."""
    return resource.getrusage(who).ru_maxrss / 1024.0


def _cpu_seconds(who: int) -> float:
    """User + system CPU seconds of this process or of its finished children (robust to a loaded machine)."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def _subprocess_stage(stage: str, root: Path, T: int, workers: int) -> dict[str, Any]:
    """:func:`run_stage` in a fresh interpreter; its JSON result."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    cmd = [sys.executable, "-m", "torch4dtree.bench.scale", stage, str(root), "--T", str(T), "--workers", str(workers)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"stage {stage} on {root} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def growth_exponent(sizes: Sequence[float], values: Sequence[float]) -> float | None:
    """Least-squares slope of ``log(values)`` against ``log(sizes)`` (``None`` with fewer than 2 usable points).

    Example:
        >>> round(growth_exponent([10, 20, 40], [1.0, 4.0, 16.0]), 6)
        2.0
    """
    pts = [(math.log(s), math.log(v)) for s, v in zip(sizes, values) if s > 0 and v > 0]
    if len(pts) < 2:
        return None
    mx = sum(x for x, _ in pts) / len(pts)
    my = sum(y for _, y in pts) / len(pts)
    sxx = sum((x - mx) ** 2 for x, _ in pts)
    if sxx == 0:
        return None
    return sum((x - mx) * (y - my) for x, y in pts) / sxx


def benchmark_scale(sizes: Sequence[int] = DEFAULT_SIZES, frames: int = DEFAULT_FRAMES, T: int = DEFAULT_T,
                    workers: Sequence[int] = (1, 2), stages: Sequence[str] = STAGES,
                    log: Callable[[str], None] | None = None, keep: Path | None = None) -> dict[str, Any]:
    """Every stage at every size, each in a fresh process; returns ``{"rows", "exponents", "speedup", ...}``.

    ``rows``: one dict per (stage, size, workers) with ``seconds``, ``cpu_seconds``, ``peak_mb``, ``base_mb``,
    ``children_peak_mb`` (the paper model's fit also ``slots``, ``dropped_share`` and its ``parts``' seconds).
    ``exponents[name] = {"seconds": slope, "cpu_seconds": slope, "peak_mb": slope, "stage_mb": slope}`` (log-log,
    over ``sizes``; ``stage_mb`` is ``peak_mb - base_mb``), with ``name`` the stage (``pairs_wN`` for all-pairs on N
    workers).
    ``speedup[size]``: all-pairs seconds on ``min(workers)`` over seconds on ``max(workers)``. ``keep``: write the
    datasets there (default: a temporary folder, removed).

    Example:
        >>> r = benchmark_scale(sizes=[2, 3], frames=2, T=8, workers=[1], stages=["read"])  # doctest: +SKIP
    """
    say = log or (lambda line: None)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="torch4dtree-scale-") as tmp:
        base = Path(keep) if keep is not None else Path(tmp)
        for n in sizes:
            root = base / f"tomato_{n}x{frames}_T{T}"
            if not root.is_dir():
                write_dataset(root, n, frames, T)
            for stage in stages:
                for w in (workers if stage == "pairs" else [1]):
                    name = f"pairs_w{w}" if stage == "pairs" else stage
                    r = {"stage": name, "size": n, **_subprocess_stage(stage, root, T, w)}
                    rows.append(r)
                    say(f"{name} {n} plants: {r['seconds']:.2f} s ({r['cpu_seconds']:.2f} CPU s), "
                        f"peak {r['peak_mb']:.0f} MB "
                        f"(+{r['peak_mb'] - r['base_mb']:.0f} MB over {r['base_mb']:.0f})")
    names = list(dict.fromkeys(r["stage"] for r in rows))
    exponents = {}
    for name in names:
        mine = [r for r in rows if r["stage"] == name]
        ns = [r["size"] for r in mine]
        exponents[name] = {"seconds": growth_exponent(ns, [r["seconds"] for r in mine]),
                           "cpu_seconds": growth_exponent(ns, [r.get("cpu_seconds", 0.0) for r in mine]),
                           "peak_mb": growth_exponent(ns, [r["peak_mb"] for r in mine]),
                           "stage_mb": growth_exponent(ns, [r["peak_mb"] - r["base_mb"] for r in mine])}
    speedup = {}
    if "pairs" in stages and len(set(workers)) > 1:
        lo, hi = min(workers), max(workers)
        for n in sizes:
            t = {r["stage"]: r["seconds"] for r in rows if r["size"] == n}
            speedup[n] = t[f"pairs_w{lo}"] / t[f"pairs_w{hi}"]
    return {"sizes": list(sizes), "frames": frames, "T": T, "workers": list(workers), "cpus": os.cpu_count(),
            "rows": rows, "exponents": exponents, "speedup": speedup}


def format_table(result: dict[str, Any]) -> str:
    """The benchmark as text: seconds and peak MB per stage and size, the growth exponents and the speed-ups.

    Example:
        >>> r = {"sizes": [10], "frames": 3, "T": 16, "cpus": 2, "rows": [], "exponents": {}, "speedup": {}}
        >>> format_table(r).splitlines()[0]
        'synthetic tomatoes, 3 frames, T = 16, 2 CPUs; each stage in a fresh process'
    """
    sizes = result["sizes"]
    names = list(result["exponents"])
    cell = {(r["stage"], r["size"]): r for r in result["rows"]}
    lines = [f"synthetic tomatoes, {result['frames']} frames, T = {result['T']}, {result['cpus']} CPUs; "
             f"each stage in a fresh process",
             f"{'stage':>11} {'':>8} " + " ".join(f"{n:>9}" for n in sizes) + f" {'exponent':>9}"]
    for name in names:
        ex = result["exponents"][name]
        for key, label, fmt in (("seconds", "s", "{:9.2f}"), ("cpu_seconds", "CPU s", "{:9.2f}"),
                                ("peak_mb", "peak MB", "{:9.0f}"),
                                ("stage_mb", "+MB", "{:9.0f}")):
            vals = []
            for n in sizes:
                r = cell.get((name, n))
                v = None if r is None else (r["peak_mb"] - r["base_mb"] if key == "stage_mb" else r.get(key))
                vals.append(" " * 9 if v is None else fmt.format(v))
            e = ex.get(key)
            lines.append(f"{name if key == 'seconds' else '':>11} {label:>8} " + " ".join(vals)
                         + (f" {e:9.2f}" if e is not None else f" {'-':>9}"))
    if result["speedup"]:
        lines.append("all-pairs speed-up (1 -> 2 workers): " + ", ".join(
            f"{n} plants {s:.2f}x" for n, s in result["speedup"].items()))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """One stage in this process (what :func:`benchmark_scale` spawns): prints one JSON line."""
    p = argparse.ArgumentParser(description="one stage of the scaling benchmark")
    p.add_argument("stage", choices=STAGES)
    p.add_argument("root", type=Path)
    p.add_argument("--T", type=int, default=DEFAULT_T)
    p.add_argument("--workers", type=int, default=1)
    a = p.parse_args(argv)
    print(json.dumps(run_stage(a.stage, a.root, a.T, a.workers)))


if __name__ == "__main__":
    main()
