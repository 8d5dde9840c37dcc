"""SWC skeleton files: 7 columns ``id type x y z radius parent``, ``#`` comments (docs/method.md §6)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..settings import DEFAULT_HIERARCHY, DEFAULT_ROOT, DEFAULT_T
from ..trees.skeleton import repair_skeleton, skeleton_to_trees, trees_to_skeleton, validate_skeleton
from ..trees.structures import TreeError, Trees
from .files import write_text_safely
from .rooting import choose_root, reroot


class SWCError(TreeError):
    """A malformed SWC file; the message names the file and the line or node."""


@dataclass(frozen=True)
class Skeleton:
    """A skeleton graph read from a file.

    Attributes:
        xyz: ``(n, 3)`` coordinates. parent: ``(n,)`` parent index (``-1`` root).
        ids: ``(n,)`` the file's node ids. types: ``(n,)`` the type column. radius: ``(n,)``.
    """

    xyz: np.ndarray
    parent: np.ndarray
    ids: np.ndarray
    types: np.ndarray
    radius: np.ndarray
    source: str


def read_swc_skeleton(path: str | Path, repair: bool = False, root: str = DEFAULT_ROOT) -> Skeleton:
    """Parse and validate an SWC file (one root, known parents, no cycles, finite numbers).

    With ``repair``, cycles and parts cut off from the root are mended (see
    :func:`~torch4dtree.trees.skeleton.repair_skeleton`) with a warning instead of an error: one
    published Pheno4D file (tomato_1, March 25) needs it.

    ``root`` (one of :data:`~torch4dtree.settings.ROOTS`) says where the skeleton is rooted: ``"file"`` the
    file's own root; ``"base"`` a plant's stem base; ``"auto"`` (default) the stem base unless the file is rooted
    at a soma (type 1) or a branching node, with a warning when it moves (:mod:`torch4dtree.io.rooting`): a scan
    rooted at its lowest node is rooted at a leaf tip when a leaf hangs below the stem base. Only parent links
    change; node order, ids, types and radii are the file's.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> path = Path(tempfile.mkdtemp()) / "plant.swc"
        >>> _ = path.write_text("1 0 0 0 0 1 -1\\n2 0 0 0 5 1 1\\n3 0 0 0 10 1 2\\n4 3 4 0 8 1 2\\n")  # stem, leaf
        >>> sk = read_swc_skeleton(path)
        >>> sk.parent.tolist(), sk.types.tolist()
        ([-1, 0, 1, 1], [0, 0, 0, 3])
        >>> _ = path.write_text("1 0 4 0 -1 1 -1\\n2 0 1 0 6 1 1\\n3 0 0 0 5 1 2\\n4 0 0 0 0 1 3\\n5 0 0 0 10 1 3\\n")
        >>> read_swc_skeleton(path, root="file").parent.tolist()  # rooted at a leaf tip hanging below the stem
        [-1, 0, 1, 2, 2]
        >>> import warnings
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     read_swc_skeleton(path).parent.tolist()  # rooted at the stem base, node 4
        [1, 2, 3, -1, 2]
        >>> "instead of the file's root, node 1" in str(caught[0].message)
        True
    """
    path = Path(path)
    rows: list[tuple[int, int, float, float, float, float, int]] = []
    line_of: dict[int, int] = {}
    with open(path, encoding="utf-8", errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            cols = text.split()
            if len(cols) != 7:
                raise SWCError(f"{path}:{lineno}: expected 7 columns (id type x y z radius parent), got {len(cols)}")
            try:
                nid, typ, par = int(cols[0]), int(float(cols[1])), int(cols[6])
                x, y, z, r = (float(c) for c in cols[2:6])
            except ValueError:
                raise SWCError(f"{path}:{lineno}: non-numeric value in {text!r}") from None
            if not all(math.isfinite(v) for v in (x, y, z)):
                raise SWCError(f"{path}:{lineno}: node {nid} has NaN or infinite coordinates")
            if nid in line_of:
                raise SWCError(f"{path}:{lineno}: duplicate node id {nid} (first on line {line_of[nid]})")
            line_of[nid] = lineno
            rows.append((nid, typ, x, y, z, r, par))
    if not rows:
        raise SWCError(f"{path}: empty file (no nodes)")
    ids = np.array([r[0] for r in rows])
    index = {nid: i for i, nid in enumerate(ids.tolist())}
    parent = np.empty(len(rows), dtype=np.int64)
    for i, r in enumerate(rows):
        if r[6] == -1:
            parent[i] = -1
        elif r[6] in index:
            parent[i] = index[r[6]]
        else:
            raise SWCError(f"{path}:{line_of[r[0]]}: node {r[0]} has parent {r[6]}, which does not exist")
    xyz = np.array([r[2:5] for r in rows], dtype=np.float64)
    roots = np.nonzero(parent == -1)[0]
    if len(roots) > 1:
        lines = ", ".join(str(line_of[int(ids[i])]) for i in roots[:5])
        raise SWCError(f"{path}: {len(roots)} roots (parent -1) on lines {lines}; an SWC tree has exactly one")
    try:
        validate_skeleton(xyz, parent, str(path), ids)
    except TreeError as e:
        if not repair or "not connected" not in str(e):
            hint = " (pass repair=True / --repair to mend it)" if "not connected" in str(e) else ""
            raise SWCError(f"{e}{hint}") from None
        parent, messages = repair_skeleton(xyz, parent, ids)
        for m in messages:
            warnings.warn(f"{path}: repaired: {m}", stacklevel=2)
    types = np.array([r[1] for r in rows])
    node, why = choose_root(xyz, parent, types, root, str(path), ids)
    if parent[node] != -1:
        parent = reroot(parent, node)
    if why and root == "auto":
        warnings.warn(why, stacklevel=2)
    return Skeleton(xyz, parent, ids, types, np.array([r[5] for r in rows]), str(path))


def read_swc(
    path: str | Path,
    T: int = DEFAULT_T,
    max_layers: int | None = None,
    min_branch_length: float = 0.0,
    labels_from_type: bool = False,
    repair: bool = False,
    main_path: Sequence[int] | None = None,
    hierarchy: str = DEFAULT_HIERARCHY,
    root: str = DEFAULT_ROOT,
) -> Trees:
    """Read an SWC file as a single-tree :class:`Trees` (branch hierarchy by the ``hierarchy`` rule, docs/method.md §2;
    see :mod:`torch4dtree.trees.skeleton`).

    With ``labels_from_type`` the type column holds branch identities (as the synthetic plants
    write them) and becomes :attr:`Trees.label`. ``main_path`` names the main branch explicitly as
    the file's node ids from the root (default: chosen by the rule); the tree is then rooted at its first node.
    ``root``: where the skeleton is rooted when ``main_path`` is not given (:func:`read_swc_skeleton`).

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> path = Path(tempfile.mkdtemp()) / "plant.swc"
        >>> _ = path.write_text("1 0 0 0 0 1 -1\\n2 0 0 0 5 1 1\\n3 0 0 0 10 1 2\\n4 3 4 0 8 1 2\\n")  # stem, leaf
        >>> tree = read_swc(path, T=8, labels_from_type=True)
        >>> tree.parent.tolist(), tree.label.tolist()
        ([-1, 0], [0, 3])
    """
    sk = read_swc_skeleton(path, repair, "file" if main_path is not None else root)
    path_index = None
    parent = sk.parent
    if main_path is not None:
        index = {int(nid): i for i, nid in enumerate(sk.ids.tolist())}
        missing = [nid for nid in main_path if int(nid) not in index]
        if missing:
            raise SWCError(f"{path}: the main path names node {missing[0]}, which is not in the file")
        path_index = [index[int(nid)] for nid in main_path]
        if path_index and parent[path_index[0]] != -1:
            parent = reroot(parent, path_index[0])
    return skeleton_to_trees(
        sk.xyz, parent, T=T, max_layers=max_layers, min_branch_length=min_branch_length, main_path=path_index,
        node_labels=sk.types if labels_from_type else None, where=str(path), ids=sk.ids, hierarchy=hierarchy,
    )


def write_swc(path: str | Path, tree: Trees, overwrite: bool = False, comment: str = "") -> Path:
    """Write one tree as SWC (labels in the type column). Refuses to replace a file unless ``overwrite``.

    Returns the path written; reading it back gives the same branches (same hierarchy rule).

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> tree = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> path = write_swc(Path(tempfile.mkdtemp()) / "tree.swc", tree)
        >>> read_swc(path, T=8).parent.tolist()
        [-1, 0]
    """
    xyz, parent, label = trees_to_skeleton(tree)
    lines = [f"# {c}" for c in comment.splitlines()] if comment else []
    lines.append("# id type x y z radius parent (written by torch4dtree)")
    for i, (p, q, lab) in enumerate(zip(xyz, parent, label)):
        lines.append(f"{i + 1} {max(int(lab), 0)} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 1.0 {q + 1 if q >= 0 else -1}")
    return write_text_safely(Path(path), "\n".join(lines) + "\n", overwrite)
