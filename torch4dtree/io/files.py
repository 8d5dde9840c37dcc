"""Writing files without ever destroying existing data."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_bytes_safely(path: Path, data: bytes, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; refuse to replace an existing file unless ``overwrite``.

    The data goes to a temporary file in the same folder first, so a failure half-way never
    leaves a truncated file where a good one was.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        if not overwrite and path.exists():  # appeared while we were writing
            raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_text_safely(path: Path, text: str, overwrite: bool = False) -> Path:
    """Text version of :func:`write_bytes_safely` (UTF-8)."""
    return write_bytes_safely(path, text.encode("utf-8"), overwrite)
