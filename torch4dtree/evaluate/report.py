"""``report.json`` and ``report.md`` of an evaluation (and its figures), written without replacing anything, and
where the numbers were measured (:func:`machine`)."""

from __future__ import annotations

import importlib
import json
import math
import platform
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..io.files import write_text_safely
from .data import EvalData, EvalSettings
from .stats import fmt, md_table

PAPER = "Khanam et al., ECCV 2024"


def _commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def machine() -> dict[str, Any]:
    """Where the numbers were measured (stated with them)."""
    import os

    import torch

    from .. import __version__

    return {"torch4dtree": __version__, "commit": _commit(), "python": platform.python_version(),
            "torch": torch.__version__, "cpus": os.cpu_count(), "threads": torch.get_num_threads(),
            "platform": platform.platform(), "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg")
            else None}


def dumps(report: dict[str, Any]) -> str:
    """The report as JSON (NaN written as null: strict JSON).

    Example:
        >>> print(dumps({"mean": float("nan"), "pairs": (1, 2)}))
        {
         "mean": null,
         "pairs": [
          1,
          2
         ]
        }
    """
    def clean(x: Any) -> Any:
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(report), indent=1)


def markdown(report: dict[str, Any], sections: Sequence[str]) -> str:
    """The whole report as Markdown: header (data, settings, machine), each section's tables, timings, figures."""
    m, s = report["machine"], report["settings"]
    lines = ["# torch4dtree evaluation", "",
             f"Data: `{report['data']['path']}` ("
             + "; ".join(f"{src}: {len(v['plants'])} plants, {v['frames']} frames, {', '.join(v['kinds'])}"
                         for src, v in report["data"]["sources"].items()) + ").",
             f"Settings: {', '.join(f'{k} = {v}' for k, v in s.items())}.",
             f"Machine: torch4dtree {m['torch4dtree']} (commit {m['commit']}), torch {m['torch']}, {m['cpus']} CPUs, "
             f"{m['threads']} torch threads, load average at start {m['load_average']}.",
             f"Paper figures: {PAPER}. Error rates in %; distances in each source's units (mm-based SRVF norms), "
             "so compare our after / before ratios with the paper's, not absolute values.", ""]
    for name in sections:
        mod = importlib.import_module(f".{name}", __package__)
        lines += mod.markdown(report) + [""]
    lines += ["## Timings", "", *md_table(
        ["stage", "ours (s)", "paper (s)", "paper / ours", "what"],
        [[k, fmt(v["seconds"]), fmt(v.get("paper_seconds")),
          fmt(v["paper_seconds"] / v["seconds"]) + "x" if v.get("paper_seconds") and v["seconds"] > 0 else "-",
          v.get("what", "")] for k, v in report["timings"].items()]), ""]
    if report.get("figures"):
        lines += ["## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in report["figures"]]
    return "\n".join(lines) + "\n"


def write_report(report: dict[str, Any], out: Path, datas: dict[str, EvalData], settings: EvalSettings,
                 sections: Sequence[str]) -> list[str]:
    """Write the figures (when ``settings.figures``), ``report.json`` and ``report.md`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    if settings.figures:
        from .figures import write_figures

        report["figures"] = write_figures(report, datas, settings, out)
    files = list(report.get("figures", []))
    files.append(str(write_text_safely(out / "report.json", dumps(report))))
    files.append(str(write_text_safely(out / "report.md", markdown(report, sections))))
    return files
