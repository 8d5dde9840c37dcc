"""The suite and the package's structure: an import error in the package must fail, never turn into a skip, and no
module reaches into another module's private names."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).parent
PACKAGE = TESTS.parent / "torch4dtree"

# known imports of private names outside the curves / trees subpackages, to be made public by their owners
ALLOWED_PRIVATE_IMPORTS: set[tuple[str, str]] = set()


def test_no_importorskip_of_the_package() -> None:
    """``pytest.importorskip("torch4dtree...")`` hides a broken import of our own code as a skip; import
    the package's modules directly (optional third-party packages may still be skipped)."""
    offenders = []
    for path in sorted(p for p in TESTS.rglob("*.py") if p != Path(__file__)):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"importorskip\(\s*[\"']torch4dtree", line):
                offenders.append(f"{path.relative_to(TESTS)}:{n}")
    assert not offenders, offenders


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(dotted: str) -> bool:
    """Whether ``dotted`` names a module or subpackage of torch4dtree (not a class or function in one)."""
    path = PACKAGE.parent.joinpath(*dotted.split("."))
    return dotted.startswith("torch4dtree") and (path.with_suffix(".py").is_file() or (path / "__init__.py").is_file())


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_imports(source: str, module: str, is_package: bool = False) -> list[tuple[str, int]]:
    """``(private name, line)`` for every ``from X import _y`` of a torch4dtree module and every ``X._y`` read on an
    imported torch4dtree module ``X`` in ``source``, the code of ``module`` (a package's ``__init__`` if
    ``is_package``; relative imports are resolved against it)."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    tree = ast.parse(source)
    modules: dict[str, str] = {}  # local name -> the dotted name it is bound to
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            origin = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:
                modules[alias.asname or alias.name] = f"{origin}.{alias.name}"
                if _private(alias.name) and origin.startswith("torch4dtree"):
                    found.append((f"{origin}.{alias.name}", node.lineno))
        elif isinstance(node, ast.Import):
            for alias in node.names:  # "import a.b" binds a, "import a.b as c" binds c to a.b
                top = alias.name.split(".")[0]
                modules[alias.asname or top] = alias.name if alias.asname else top
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and _private(node.attr)
                and node.value.id in modules and _is_module(modules[node.value.id])):
            found.append((f"{modules[node.value.id]}.{node.attr}", node.lineno))
    return found


def test_private_imports_are_found() -> None:
    """The checker sees both forms, relative and absolute, and leaves classes and other packages alone."""
    source = ("from .warps import _band\nfrom torch4dtree.curves import srvf as S\nfrom ..trees import Trees\n"
              "import numpy\nS._x\nnumpy._y\nTrees._z\n")
    found = {name for name, _ in private_imports(source, "torch4dtree.curves.probe")}
    assert found == {"torch4dtree.curves.warps._band", "torch4dtree.curves.srvf._x"}


def test_no_module_imports_another_modules_private_names() -> None:
    """A ``_name`` is private to its module: what another module needs is public. Known offenders outside curves /
    trees are listed in ``ALLOWED_PRIVATE_IMPORTS``."""
    found = {(_module_name(path), name, line) for path in sorted(PACKAGE.rglob("*.py"))
             for name, line in private_imports(path.read_text(), _module_name(path), path.name == "__init__.py")}
    offenders = [f"{here}:{line} uses {name}" for here, name, line in sorted(found)
                 if (here, name) not in ALLOWED_PRIVATE_IMPORTS]
    assert not offenders, "\n".join(offenders)
    stale = ALLOWED_PRIVATE_IMPORTS - {(here, name) for here, name, _ in found}
    assert not stale, f"fixed, remove from ALLOWED_PRIVATE_IMPORTS: {sorted(stale)}"
