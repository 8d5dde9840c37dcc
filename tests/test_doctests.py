"""The ``>>>`` examples in the package's docstrings run, and there are enough of them to guide a newcomer."""

from __future__ import annotations

import doctest
import importlib
import os
import pkgutil

import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # the render examples draw offscreen

import torch4dtree  # noqa: E402

MODULES = sorted(m.name for m in pkgutil.walk_packages(torch4dtree.__path__, "torch4dtree.")
                 if not m.name.endswith("__main__"))
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
MIN_EXAMPLES = 25  # public entry points with a runnable example


def _examples(module: object) -> list[doctest.DocTest]:
    return [t for t in doctest.DocTestFinder(exclude_empty=True).find(module) if t.examples]


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name: str) -> None:
    module = importlib.import_module(name)
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in _examples(module):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (output above)"


def test_public_entry_points_have_examples() -> None:
    documented = {t.name for name in MODULES for t in _examples(importlib.import_module(name))
                  if not t.name.rsplit(".", 1)[-1].startswith("_")}
    assert len(documented) >= MIN_EXAMPLES, sorted(documented)
