"""``report.json`` and ``report.md`` of an evaluation (and its figures), written without replacing anything."""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..io.files import write_text_safely
from .data import EvalData, EvalSettings
from .stats import fmt, md_table

PAPER = "Khanam et al., ECCV 2024"


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
    from .run import dumps

    out.mkdir(parents=True, exist_ok=True)
    if settings.figures:
        from .figures import write_figures

        report["figures"] = write_figures(report, datas, settings, out)
    files = list(report.get("figures", []))
    files.append(str(write_text_safely(out / "report.json", dumps(report))))
    files.append(str(write_text_safely(out / "report.md", markdown(report, sections))))
    return files
