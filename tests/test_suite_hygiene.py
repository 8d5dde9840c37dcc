"""The suite itself: an import error in the package must fail, never turn into a skip."""

from __future__ import annotations

import re
from pathlib import Path


def test_no_importorskip_of_the_package() -> None:
    """``pytest.importorskip("torch4dtree...")`` hides a broken import of our own code as a skip; import
    the package's modules directly (optional third-party packages may still be skipped)."""
    offenders = []
    for path in sorted(p for p in Path(__file__).parent.glob("*.py") if p.name != Path(__file__).name):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"importorskip\(\s*[\"']torch4dtree", line):
                offenders.append(f"{path.name}:{n}")
    assert not offenders, offenders
