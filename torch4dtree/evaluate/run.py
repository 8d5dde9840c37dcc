"""The evaluation driver: load every source of a data folder once, run each experiment module, write the report."""

from __future__ import annotations

import importlib
import inspect
import time
from collections.abc import Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from .data import EvalData, EvalSettings, load_eval_data, sources_of
from .report import machine, write_report

# experiment modules, in report order (see the package doc for their contract)
SECTIONS = ("spatial", "temporal", "generative", "truth", "robustness")


def evaluate(data_dir: str | Path, out: str | Path | None = None, settings: EvalSettings | None = None,
             sections: Sequence[str] = SECTIONS, progress: bool = False, executor: Executor | None = None
             ) -> dict[str, Any]:
    """Run the experiments of ``sections`` on a data folder; write ``report.json`` / ``report.md`` (and figures) to
    ``out`` when given (a new folder, or an existing empty one). Returns the report as a dict. ``executor``: where
    the sections whose ``run`` takes an ``executor`` run their heavy steps (:mod:`torch4dtree.parallel`); the
    numbers do not depend on it."""
    settings = settings or EvalSettings()
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown sections {unknown}; choose from {SECTIONS}")
    out_path = Path(out) if out is not None else None
    if out_path is not None and out_path.exists() and (not out_path.is_dir() or any(out_path.iterdir())):
        raise FileExistsError(f"{out_path} exists and is not an empty folder: not overwriting an earlier report")
    t0 = time.perf_counter()
    datas: dict[str, EvalData] = {s: load_eval_data(data_dir, s, settings.T) for s in sources_of(data_dir)}
    report: dict[str, Any] = {
        "data": {"path": str(data_dir), "sources": {s: {"plants": [p.name for p in d.plants], "kinds": d.kinds,
                                                        "frames": sum(len(p.sequence) for p in d.plants)}
                                                    for s, d in datas.items()}},
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
        "machine": machine(), "timings": {"load": {"seconds": time.perf_counter() - t0, "paper_seconds": None,
                                                    "what": "read every plant of every source"}},
    }
    for name in sections:
        mod = importlib.import_module(f".{name}", __package__)
        t1 = time.perf_counter()
        spread = {"executor": executor} if "executor" in inspect.signature(mod.run).parameters else {}
        result = mod.run(datas, settings, progress, **spread)
        report["timings"].update(result.pop("timings", {}))
        report["timings"][f"section_{name}"] = {"seconds": time.perf_counter() - t1, "paper_seconds": None,
                                                "what": f"the whole {name} section"}
        report.update(result)
    report["timings"]["total"] = {"seconds": time.perf_counter() - t0, "paper_seconds": None,
                                  "what": "the whole evaluation"}
    if out_path is not None:
        report["files"] = write_report(report, out_path, datas, settings, sections)
    return report
