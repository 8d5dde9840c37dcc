"""The reference MATLAB ``.mat`` trees of the paper's code (``compTrees`` / ``all_compTrees``).

Each tree node is a struct with ``beta0`` (3 x T0, its main branch), ``beta`` (cell of K side
branches, 3 x Tk each, starting at their attachment point) and ``beta_children`` (cell of K
structs of the same form, whose ``beta0`` is that side branch), to any depth. The stored
``tk_sideLocs`` are node-index fractions; we recompute the bifurcation parameters as arc-length
fractions of the attachment point's projection (docs/method.md §2), so they are not read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import scipy.io

from ..settings import DEFAULT_T
from ..trees.structures import TreeError, Trees

TREE_VARIABLES = ("compTrees", "all_compTrees")


class MatTreeError(TreeError):
    """A ``.mat`` file that does not hold a reference tree; the message names the file and field."""


def _as_list(cell: Any) -> list[Any]:
    """A MATLAB cell array as a list (``squeeze_me`` turns 1-element cells into scalars)."""
    if cell is None:
        return []
    if isinstance(cell, np.ndarray) and cell.dtype == object:
        return list(cell.ravel())
    if isinstance(cell, np.ndarray) and cell.size == 0:
        return []
    return [cell]


def _points(arr: Any, where: str) -> np.ndarray:
    """MATLAB's 3 x n point arrays as (n, 3).

    ``squeeze_me`` leaves a single point as (3,); some deep subtrees of the published files have
    ``dimension = 4`` and a fourth row holding the radius, which we drop.
    """
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 1 and a.size in (3, 4):
        a = a[:, None]
    if a.ndim != 2 or a.shape[0] not in (3, 4):
        raise MatTreeError(f"{where}: expected a 3 x n (or 4 x n with radii) array, got shape {a.shape}")
    a = a[:3]
    if not np.isfinite(a).all():
        raise MatTreeError(f"{where}: NaN or infinite coordinates")
    return a.T


def load_mat_struct(path: str | Path) -> Any | None:
    """The tree struct of a reference file, or ``None`` for an empty frame (a 0 x 0 variable)."""
    path = Path(path)
    try:
        data = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    except Exception as e:  # scipy raises several types for foreign or corrupt files
        raise MatTreeError(f"{path}: not a readable MATLAB file ({e})") from None
    names = [k for k in TREE_VARIABLES if k in data]
    if not names:
        found = [k for k in data if not k.startswith("__")]
        raise MatTreeError(f"{path}: no variable {' or '.join(TREE_VARIABLES)} (found {found})")
    value = data[names[0]]
    if isinstance(value, np.ndarray) and value.size == 0:
        return None
    if isinstance(value, np.ndarray):  # a struct array: take its single element
        if value.size != 1:
            raise MatTreeError(f"{path}: {names[0]} holds {value.size} trees, expected one")
        value = value.ravel()[0]
    return value


def is_empty_mat_frame(path: str | Path) -> bool:
    """True for the placeholder files of removed days (a 0 x 0 tree variable)."""
    return load_mat_struct(path) is None


def mat_to_branches(node: Any, where: str) -> tuple[list[np.ndarray], list[int]]:
    """Flatten a reference tree struct into polylines and parent indices (depth-first)."""
    polylines: list[np.ndarray] = []
    parents: list[int] = []
    stack: list[tuple[Any, np.ndarray | None, int, str]] = [(node, None, -1, "beta0")]
    while stack:
        struct, own_points, parent, field = stack.pop()
        if not hasattr(struct, "beta0") and own_points is None:
            raise MatTreeError(f"{where}: {field} is not a tree struct (no beta0)")
        pts = _points(struct.beta0, f"{where}: {field}") if own_points is None else own_points
        index = len(polylines)
        polylines.append(pts)
        parents.append(parent)
        sides = _as_list(getattr(struct, "beta", None)) if struct is not None else []
        subtrees = _as_list(getattr(struct, "beta_children", None)) if struct is not None else []
        for k, side in enumerate(sides):
            name = f"{field}.beta{{{k + 1}}}"
            child = subtrees[k] if k < len(subtrees) and hasattr(subtrees[k], "beta0") else None
            stack.append((child, _points(side, f"{where}: {name}"), index, name))
    return polylines, parents


def read_mat_tree(path: str | Path, T: int = DEFAULT_T) -> Trees | None:
    """Read a reference ``.mat`` tree as a single-tree :class:`Trees`; ``None`` for an empty frame.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> import numpy as np, scipy.io
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> sides = np.empty(1, dtype=object)
        >>> sides[0] = leaf.T  # a cell array of 3 x n side branches
        >>> path = Path(tempfile.mkdtemp()) / "03_05.mat"
        >>> scipy.io.savemat(path, {"compTrees": {"beta0": stem.T, "beta": sides}})
        >>> read_mat_tree(path, T=8).parent.tolist()
        [-1, 0]
    """
    struct = load_mat_struct(path)
    if struct is None:
        return None
    polylines, parents = mat_to_branches(struct, str(path))
    return Trees.from_branches([polylines], [parents], T=T, names=[str(path)])
