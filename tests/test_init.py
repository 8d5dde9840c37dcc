"""The package's lazy imports: every public name and every subpackage is reachable from ``import torch4dtree``."""

from __future__ import annotations

import importlib
import pkgutil

import torch4dtree


def test_every_subpackage_and_module_is_an_attribute():
    names = {m.name for m in pkgutil.iter_modules(torch4dtree.__path__)}
    assert {"evaluate", "bench", "cli"} <= names
    for name in sorted(names):
        assert getattr(torch4dtree, name) is importlib.import_module(f"torch4dtree.{name}"), name


def test_public_names_resolve():
    for name in torch4dtree.__all__:
        assert getattr(torch4dtree, name) is not None, name
    assert torch4dtree.evaluate.evaluate is importlib.import_module("torch4dtree.evaluate.run").evaluate
