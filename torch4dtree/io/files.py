"""Writing files without ever destroying existing data."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _exists_error(path: Path) -> FileExistsError:
    return FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")


def about_target(err: OSError, path: Path) -> OSError:
    """``err`` (of the same class) about ``path`` instead of a hidden temporary file, whose name means nothing
    to the user (e.g. ``IsADirectoryError`` when ``path`` is a folder, a full disk, no write permission)."""
    text = err.strerror or str(err)
    return type(err)(err.errno, text, str(path)) if err.errno is not None else type(err)(f"{path}: {text}")


def publish_file(tmp: Path, path: Path, overwrite: bool = False) -> None:
    """Move a finished temporary file (same folder) to ``path``.

    Without ``overwrite`` an existing file is never replaced, even one that appears meanwhile: a hard
    link is an atomic "create only if absent" (with a checked rename where links are unsupported).
    """
    try:
        if overwrite:
            os.replace(tmp, path)
            return
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise _exists_error(path) from None
        except OSError:  # a file system without hard links
            if path.exists():
                raise _exists_error(path) from None
            os.replace(tmp, path)
            return
    except FileExistsError:
        raise
    except OSError as e:
        raise about_target(e, path) from None
    tmp.unlink()


def temporary_path(path: Path) -> Path:
    """A new empty temporary file beside ``path`` (the folder is created if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix or ".tmp")
    except OSError as e:
        raise about_target(e, path) from None
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600 files; outputs get the usual permissions
    return Path(tmp)


def write_bytes_safely(path: Path, data: bytes, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; refuse to replace an existing file unless ``overwrite``.

    The data goes to a temporary file in the same folder first, so a failure half-way never
    leaves a truncated file where a good one was.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "notes.bin"
        >>> write_bytes_safely(path, b"1") == path
        True
        >>> write_bytes_safely(path, b"2")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        FileExistsError: ... exists; pass overwrite=True (--overwrite) to replace it
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise _exists_error(path)
    tmp = temporary_path(path)
    try:
        try:
            tmp.write_bytes(data)
        except OSError as e:
            raise about_target(e, path) from None
        publish_file(tmp, path, overwrite)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_text_safely(path: Path, text: str, overwrite: bool = False) -> Path:
    """Text version of :func:`write_bytes_safely` (UTF-8).

    Example:
        >>> import tempfile
        >>> path = write_text_safely(Path(tempfile.mkdtemp()) / "notes.txt", "growth\\n")
        >>> path.read_text()
        'growth\\n'
    """
    return write_bytes_safely(path, text.encode("utf-8"), overwrite)
