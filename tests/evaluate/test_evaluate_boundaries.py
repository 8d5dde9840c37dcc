"""The measurement code's boundaries: ``evaluate`` imports neither ``bench`` nor ``cli``; ``bench`` does not import
``cli``. Read from the sources (every import, also those inside functions)."""

from __future__ import annotations

import ast
from pathlib import Path

import torch4dtree

PACKAGE = Path(torch4dtree.__file__).parent


def imported_subpackages(folder: str) -> dict[str, set[str]]:
    """Per module of ``torch4dtree/<folder>``, the top-level subpackages of torch4dtree it imports."""
    out = {}
    for path in sorted((PACKAGE / folder).glob("*.py")):
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 2 and node.module:
                found.add(node.module.split(".")[0])  # from ..bench.x import y
            elif isinstance(node, ast.ImportFrom) and node.level == 2:
                found.update(alias.name for alias in node.names)  # from .. import cli
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("torch4dtree."):
                found.add(node.module.split(".")[1])
            elif isinstance(node, ast.Import):
                found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("torch4dtree."))
        out[path.name] = found
    return out


def test_evaluate_imports_neither_bench_nor_cli():
    offenders = {m: s & {"bench", "cli"} for m, s in imported_subpackages("evaluate").items() if s & {"bench", "cli"}}
    assert not offenders, offenders


def test_bench_does_not_import_cli():
    offenders = {m: s for m, s in imported_subpackages("bench").items() if "cli" in s}
    assert not offenders, offenders
    assert any("evaluate" in s for s in imported_subpackages("bench").values())  # the detector sees imports
