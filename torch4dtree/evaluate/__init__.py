"""``torch4dtree evaluate DATA_DIR``: the paper's experiments (docs/method.md §7) and the generative model's
quality, one command.

Each experiment is one module with the same two functions:

* ``run(datas: dict[str, EvalData], settings: EvalSettings, progress: bool) -> dict``: ``datas`` maps each source of
  the folder (``mat`` / ``swc`` / ``synthetic``, :mod:`.data`) to its plants; the result is JSON-safe, keyed by the
  report's top-level names (``table1``, ``table2``, ``table3``, ``generative``, ``synthetic``, ``robustness``) and may
  hold ``timings``: ``{stage: {"seconds": ours, "paper_seconds": theirs or None, "what": "..."}}``.
* ``markdown(result: dict) -> list[str]``: the report's lines for that result.

:func:`evaluate` (:mod:`.run`) runs them in order and writes ``report.json`` and ``report.md`` (:mod:`.report`)
with the figures (:mod:`.figures`). Error rates are fractions (0.0094 for 0.94 %).

Shared by every measurement of the package (the benchmarks of :mod:`torch4dtree.bench` too): :mod:`.stats` (the
summary statistics and table helpers), :mod:`.paper` (the paper's timings), :mod:`.oracle` (the organ-label
layout), :func:`.report.machine`. :mod:`.model_report` is the report of a fitted model (``torch4dtree fit``).
"""

from __future__ import annotations

from .data import EvalData, EvalSettings, Plant4D, load_eval_data, sources_of
from .report import dumps
from .run import SECTIONS, evaluate

__all__ = ["SECTIONS", "EvalData", "EvalSettings", "Plant4D", "dumps", "evaluate", "load_eval_data", "sources_of"]
