"""Small helpers every experiment shares: summary statistics and Markdown tables."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

__all__ = ["fmt", "md_table", "summary"]


def summary(values: Iterable[float]) -> dict[str, float | int]:
    """``{"n", "mean", "median", "std", "min", "max"}`` of finite values (population std, as the paper's tables;
    NaN entries when there are none): the one summary of every report and benchmark.

    Example:
        >>> summary([3.0, 1.0, 2.0, 10.0, float("nan")])
        {'n': 4, 'mean': 4.0, 'median': 2.5, 'std': 3.5355339059327378, 'min': 1.0, 'max': 10.0}
    """
    x = np.asarray([float(v) for v in values], dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        nan = float("nan")
        return {"n": 0, "mean": nan, "median": nan, "std": nan, "min": nan, "max": nan}
    return {"n": int(x.size), "mean": float(x.mean()), "median": float(np.median(x)), "std": float(x.std()),
            "min": float(x.min()), "max": float(x.max())}


def fmt(x: Any, digits: int = 3, percent: bool = False) -> str:
    """A number for a table: ``digits`` significant digits, ``percent`` for fractions (0.0094 -> ``0.94 %``);
    ``-`` for missing or non-finite values.

    Example:
        >>> fmt(0.0094, percent=True), fmt(1234.5678), fmt(None), fmt(7)
        ('0.94 %', '1.23e+03', '-', '7')
    """
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, (int, np.integer)) and not percent:
        return str(int(x))
    if percent:
        return f"{100 * float(x):.{max(digits - 1, 0)}f} %"
    return f"{float(x):.{digits}g}"


def md_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A Markdown table (cells already formatted, or numbers formatted with :func:`fmt`).

    Example:
        >>> for line in md_table(["kind", "mean"], [["tomato", 0.1234]]):
        ...     print(line)
        | kind | mean |
        |---|---|
        | tomato | 0.123 |
    """
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        lines.append("| " + " | ".join(c if isinstance(c, str) else fmt(c) for c in row) + " |")
    return lines
