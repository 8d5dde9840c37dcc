"""Ragged batches of trees (`Trees`) and 4D trees (`TreeSequence`).

One canonical form, everything else derived (docs/method.md §2):

* every branch of every tree is **packed** in one tensor ``points (N, T, d)`` of polylines
  resampled uniformly in arc length (``T`` points each),
* ``parent (N,)`` is the index of the branch's parent **within its own tree** (``-1`` for the
  main branch), so concatenating or slicing trees never shifts it,
* ``s (N,)`` is the bifurcation parameter: the arc-length fraction on the parent where the
  branch starts (``0`` for the main branch),
* ``num_branches (n_trees,)`` says how many consecutive packed branches belong to each tree.

Within a tree the main branch comes first and every parent comes before its children
(depth-first order, children sorted by ``s``), so a subtree is a contiguous range.
``label (N,)`` optionally carries a ground-truth identity per branch (``-1`` = unknown).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..curves.srvf import curve_length, interpolate_curve, resample_polylines
from ..settings import DEFAULT_T

# a side branch whose first point is within this many parent grid steps of its parent is moved onto it whole
BRIDGE_GAP = 0.5


class TreeError(ValueError):
    """A tree or skeleton that breaks the data model (names where, and what is wrong)."""


@dataclass(frozen=True, eq=False)
class Trees:
    """A ragged batch of 3D trees (any depth), packed branch by branch.

    Attributes:
        points: ``(N, T, d)`` branch polylines, uniform in arc length.
        parent: ``(N,)`` long, parent index within the same tree, ``-1`` for a main branch.
        s: ``(N,)`` bifurcation parameter on the parent in ``[0, 1]`` (``0`` for a main branch).
        num_branches: ``(n_trees,)`` long, branches per tree (each at least 1).
        label: ``(N,)`` long ground-truth branch identity, ``-1`` where unknown.

    Example:
        >>> import torch
        >>> t = torch.linspace(0, 1, 8, dtype=torch.float64)[:, None]
        >>> stem = torch.cat([0 * t, 0 * t, t], dim=1)
        >>> leaf = torch.cat([t, 0 * t, 0.5 + 0 * t], dim=1)  # starts on the stem at half its length
        >>> tree = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8, dtype=torch.float64)
        >>> tree.num_trees, tree.points.shape, tree.parent.tolist(), [round(x, 6) for x in tree.s.tolist()]
        (1, torch.Size([2, 8, 3]), [-1, 0], [0.0, 0.5])
        >>> Trees.cat([tree, tree]).num_branches.tolist()
        [2, 2]
    """

    points: Tensor
    parent: Tensor
    s: Tensor
    num_branches: Tensor
    label: Tensor

    def __post_init__(self) -> None:
        N = self.points.shape[0]
        if self.points.dim() != 3 or self.points.shape[1] < 2:
            raise TreeError(f"points must be (N, T>=2, d), got {tuple(self.points.shape)}")
        for name in ("parent", "s", "label"):
            if getattr(self, name).shape != (N,):
                raise TreeError(f"{name} must have shape ({N},), got {tuple(getattr(self, name).shape)}")
        if int(self.num_branches.sum()) != N or (self.num_branches < 1).any():
            raise TreeError(f"num_branches {self.num_branches.tolist()} must be >= 1 and sum to {N}")
        # a finite sum means every point is finite (inf and NaN propagate); cheaper than an elementwise check
        if not torch.isfinite(self.points.sum()) and not torch.isfinite(self.points).all():
            bad = int(torch.nonzero(~torch.isfinite(self.points).all(-1).all(-1))[0])
            raise TreeError(f"branch {bad} has non-finite coordinates")
        local = self.local_index
        is_main = local == 0
        if not torch.equal(self.parent == -1, is_main):
            raise TreeError("each tree must have exactly one main branch (parent -1), stored first")
        if (self.parent >= local).any():
            raise TreeError("parents must come before their children within a tree")
        if ((self.s < 0) | (self.s > 1)).any():
            raise TreeError("bifurcation parameters s must lie in [0, 1]")

    # ----------------------------------------------------------------------------- derived
    @property
    def T(self) -> int:
        """Points per branch."""
        return self.points.shape[1]

    @property
    def dim(self) -> int:
        """Ambient dimension."""
        return self.points.shape[2]

    @property
    def device(self) -> torch.device:
        return self.points.device

    @property
    def dtype(self) -> torch.dtype:
        return self.points.dtype

    @property
    def num_trees(self) -> int:
        return len(self.num_branches)

    def __len__(self) -> int:
        return self.num_trees

    @property
    def ptr(self) -> Tensor:
        """``(n_trees + 1,)`` offsets of each tree's first branch in the packed tensors."""
        return torch.cat([self.num_branches.new_zeros(1), self.num_branches.cumsum(0)])

    @property
    def tree_index(self) -> Tensor:
        """``(N,)`` which tree each packed branch belongs to."""
        return torch.repeat_interleave(
            torch.arange(self.num_trees, device=self.num_branches.device), self.num_branches
        )

    @property
    def local_index(self) -> Tensor:
        """``(N,)`` index of each branch within its tree."""
        N = self.points.shape[0]
        return torch.arange(N, device=self.num_branches.device) - self.ptr[:-1][self.tree_index]

    @property
    def global_parent(self) -> Tensor:
        """``(N,)`` packed index of each branch's parent (``-1`` for main branches)."""
        start = self.ptr[:-1][self.tree_index]
        return torch.where(self.parent >= 0, self.parent + start, self.parent)

    @property
    def depth(self) -> Tensor:
        """``(N,)`` layer of each branch: 0 main, 1 its side branches, and so on."""
        gp = self.global_parent.tolist()
        depth = [0] * len(gp)
        for i, p in enumerate(gp):  # parents precede children, so one pass suffices
            depth[i] = 0 if p < 0 else depth[p] + 1
        return torch.tensor(depth, dtype=torch.long, device=self.num_branches.device)

    @property
    def main_index(self) -> Tensor:
        """``(n_trees,)`` packed index of each tree's main branch."""
        return self.ptr[:-1]

    def root(self) -> Tensor:
        """``(n_trees, d)`` the first point of each main branch."""
        return self.points[self.main_index, 0]

    def branch_lengths(self) -> Tensor:
        """``(N,)`` polyline length of every branch."""
        return curve_length(self.points)

    def total_length(self) -> Tensor:
        """``(n_trees,)`` summed branch length per tree."""
        out = self.points.new_zeros(self.num_trees)
        return out.index_add_(0, self.tree_index, self.branch_lengths())

    def height(self, up: int = 2) -> Tensor:
        """``(n_trees,)`` extent along the ``up`` axis above the root (z by default)."""
        top = self.points[..., up].amax(1)
        out = torch.full((self.num_trees,), -torch.inf, dtype=self.dtype, device=self.device)
        out = out.scatter_reduce(0, self.tree_index, top, reduce="amax")
        return out - self.root()[:, up]

    def branches_per_layer(self) -> list[list[int]]:
        """Per tree, the number of branches in each layer (``[[1, 5, 12], ...]``)."""
        depth, tree = self.depth.tolist(), self.tree_index.tolist()
        out: list[list[int]] = [[] for _ in range(self.num_trees)]
        for d, t in zip(depth, tree):
            layer = out[t]
            layer.extend([0] * (d + 1 - len(layer)))
            layer[d] += 1
        return out

    def attachment_points(self) -> Tensor:
        """``(N, d)`` the point of the parent curve at each branch's ``s`` (root for main branches)."""
        gp = self.global_parent
        parent_curves = self.points[gp.clamp(min=0)]
        on_parent = interpolate_curve(parent_curves, self.s.unsqueeze(-1))[:, 0]
        return torch.where((gp >= 0).unsqueeze(-1), on_parent, self.points[:, 0])

    # ------------------------------------------------------------------------ transforms
    def to(self, *args, **kwargs) -> Trees:
        """Move / cast like ``Tensor.to``; only ``points`` and ``s`` change dtype."""
        points = self.points.to(*args, **kwargs)
        return Trees(
            points,
            self.parent.to(points.device),
            self.s.to(device=points.device, dtype=points.dtype),
            self.num_branches.to(points.device),
            self.label.to(points.device),
        )

    def with_points(self, points: Tensor) -> Trees:
        """The same topology with new branch polylines ``(N, T', d')``."""
        return Trees(points, self.parent, self.s, self.num_branches, self.label)

    def translate(self, offset: Tensor) -> Trees:
        """Add ``offset (n_trees, d)`` to every point of each tree."""
        return self.with_points(self.points + offset[self.tree_index].unsqueeze(1))

    def __getitem__(self, index: int | slice | Sequence[int] | Tensor) -> Trees:
        """Select trees: an int, a slice, a list or a tensor of tree indices (negative ones count from the end)."""
        n = self.num_trees
        if isinstance(index, slice):
            idx = list(range(n))[index]
        else:
            idx = torch.as_tensor(index, dtype=torch.long).reshape(-1).tolist()
        if any(not -n <= t < n for t in idx):
            raise IndexError(f"tree index {index} out of range for {n} trees")
        idx = [t % n for t in idx]
        ptr = self.ptr.tolist()
        # whole trees of a valid batch make a valid batch: no need to check them again
        if idx and idx == list(range(idx[0], idx[0] + len(idx))):  # a run of trees: views
            a, b = ptr[idx[0]], ptr[idx[-1] + 1]
            return Trees._unchecked(self.points[a:b], self.parent[a:b], self.s[a:b],
                                    self.num_branches[idx[0]:idx[-1] + 1], self.label[a:b])
        rows = [i for t in idx for i in range(ptr[t], ptr[t + 1])]
        sel = torch.tensor(rows, dtype=torch.long, device=self.device)
        return Trees._unchecked(self.points[sel], self.parent[sel], self.s[sel], self.num_branches[idx],
                                self.label[sel])

    @classmethod
    def _unchecked(cls, points: Tensor, parent: Tensor, s: Tensor, num_branches: Tensor, label: Tensor) -> Trees:
        """A batch built from whole trees of a valid one, skipping ``__post_init__``'s checks (a dozen small tensor
        ops, more than the slicing itself costs)."""
        trees = object.__new__(cls)
        for name, value in zip(("points", "parent", "s", "num_branches", "label"),
                               (points, parent, s, num_branches, label)):
            object.__setattr__(trees, name, value)
        return trees

    def split(self) -> list[Trees]:
        """One single-tree batch per tree."""
        return [self[i] for i in range(self.num_trees)]

    @staticmethod
    def cat(batches: Sequence[Trees]) -> Trees:
        """Concatenate batches (same ``T``, ``d``, dtype and device)."""
        if not batches:
            raise TreeError("cannot concatenate an empty list of Trees")
        return Trees(
            torch.cat([b.points for b in batches]),
            torch.cat([b.parent for b in batches]),
            torch.cat([b.s for b in batches]),
            torch.cat([b.num_branches for b in batches]),
            torch.cat([b.label for b in batches]),
        )

    def resample(self, T: int) -> Trees:
        """The same trees with ``T`` points per branch."""
        counts = torch.full((len(self.points),), self.T, device=self.device)
        return self.with_points(resample_polylines(self.points, counts, T))

    # ----------------------------------------------------------------------- construction
    @staticmethod
    def from_branches(
        branches: Sequence[Sequence[np.ndarray | Tensor]],
        parents: Sequence[Sequence[int]],
        T: int = DEFAULT_T,
        labels: Sequence[Sequence[int]] | None = None,
        dtype: torch.dtype = torch.float32,
        names: Sequence[str] | None = None,
    ) -> Trees:
        """Build a batch from raw polylines.

        Args:
            branches: per tree, a list of polylines ``(n_i, d)`` (any node spacing, ``n_i >= 2``).
                A side branch's first point is its attachment point on its parent.
            parents: per tree, the parent index of each branch in that list (``-1`` for exactly
                one main branch; any order, cycles are rejected).
            T: points per branch after arc-length resampling.
            labels: optional per-tree, per-branch identities.
            names: optional tree names used in error messages (e.g. file names).

        The bifurcation parameter of a side branch is the arc-length fraction of the projection
        of its first point on the (resampled) parent; the branch is then made to start exactly
        there, so every child hangs off a real point of its parent.
        """
        if len(branches) != len(parents):
            raise TreeError(f"{len(branches)} branch lists but {len(parents)} parent lists")
        all_pts: list[Tensor] = []
        all_parent: list[int] = []
        all_s: list[float] = []
        all_label: list[int] = []
        counts: list[int] = []
        for t, (brs, pars) in enumerate(zip(branches, parents)):
            where = names[t] if names is not None else f"tree {t}"
            labs = list(labels[t]) if labels is not None else [-1] * len(brs)
            pts, par, s, lab = _build_one_tree(list(brs), list(pars), labs, T, dtype, where)
            all_pts.append(pts)
            all_parent += par
            all_s += s
            all_label += lab
            counts.append(len(par))
        return Trees(
            torch.cat(all_pts) if all_pts else torch.zeros(0, T, 3, dtype=dtype),
            torch.tensor(all_parent, dtype=torch.long),
            torch.tensor(all_s, dtype=dtype),
            torch.tensor(counts, dtype=torch.long),
            torch.tensor(all_label, dtype=torch.long),
        )

    def to_branches(self) -> list[tuple[list[np.ndarray], list[int]]]:
        """Per tree, its polylines and parent indices (the input form of :meth:`from_branches`)."""
        ptr = self.ptr.tolist()
        pts = self.points.detach().cpu().numpy()
        par = self.parent.tolist()
        return [(list(pts[a:b]), par[a:b]) for a, b in zip(ptr[:-1], ptr[1:])]


def _build_one_tree(
    branches: list[np.ndarray | Tensor],
    parents: list[int],
    labels: list[int],
    T: int,
    dtype: torch.dtype,
    where: str,
) -> tuple[Tensor, list[int], list[float], list[int]]:
    """Order one tree depth-first, resample its branches, attach children at their projection."""
    n = len(branches)
    if n == 0:
        raise TreeError(f"{where}: a tree needs at least a main branch")
    if len(parents) != n or len(labels) != n:
        raise TreeError(f"{where}: {n} branches but {len(parents)} parents and {len(labels)} labels")
    roots = [i for i, p in enumerate(parents) if p == -1]
    if len(roots) != 1:
        raise TreeError(f"{where}: needs exactly one main branch (parent -1), found {len(roots)}")
    raw = []
    for i, b in enumerate(branches):
        arr = torch.as_tensor(np.asarray(b, dtype=np.float64) if not isinstance(b, Tensor) else b)
        arr = arr.to(torch.float64)
        if arr.dim() != 2 or arr.shape[0] < 2:
            raise TreeError(f"{where}: branch {i} must be a polyline (n>=2, d), got {tuple(arr.shape)}")
        check = arr.detach().cpu().numpy()  # the checks in numpy: a few small torch ops per branch cost more
        if not np.isfinite(check).all():
            raise TreeError(f"{where}: branch {i} has NaN or infinite coordinates")
        if not (np.diff(check, axis=0) != 0).any():
            raise TreeError(f"{where}: branch {i} is degenerate (zero length)")
        raw.append(arr)
        if not (parents[i] == -1 or 0 <= parents[i] < n) or parents[i] == i:
            raise TreeError(f"{where}: branch {i} has invalid parent {parents[i]}")
    children: list[list[int]] = [[] for _ in range(n)]
    for i, p in enumerate(parents):
        if p >= 0:
            children[p].append(i)
    # depth-first from the main branch; children ordered by where they attach on their parent.
    # The attachment parameter is the arc-length fraction of the first point's projection on the RAW parent.
    # A child whose first point lies on its raw parent (skeletons, .mat trees) is translated onto the resampled
    # parent, whose chords cut the raw curve's corners by a little: its shape is kept exactly. So the tree depends
    # on the geometry alone, not on how densely the nodes sample it (replacing the first node by its projection,
    # as before, turned the first segment by an amount that depended on the node spacing). A child that starts
    # off its parent is joined to it by a straight bridge from its attachment point instead.
    order: list[int] = []
    s_of: dict[int, float] = {}
    layers: list[list[int]] = []  # branches by depth, to resample each layer in one batch
    stack: list[tuple[int, float, int]] = [(roots[0], 0.0, 0)]
    while stack:
        i, s_i, depth = stack.pop()
        order.append(i)
        s_of[i] = s_i
        if depth == len(layers):
            layers.append([])
        layers[depth].append(i)
        kids = children[i]
        if kids:
            ks = _arc_fractions_of_projections(raw[i], torch.stack([raw[k][0] for k in kids]))
            # popped in order of s; equal s keep their input order
            stack.extend((k, s_k, depth + 1) for k, s_k in sorted(zip(kids, ks), key=lambda kid_s: (-kid_s[1],
                                                                                                    -kid_s[0])))
    if len(order) != n:
        missing = sorted(set(range(n)) - set(order))
        raise TreeError(f"{where}: branches {missing} are not connected to the main branch (cycle?)")
    resampled: dict[int, Tensor] = {}
    for layer in layers:
        pts_of = []
        if parents[layer[0]] >= 0:  # start exactly on the (resampled) parent curves at s
            par = torch.stack([resampled[parents[i]] for i in layer])
            s_layer = torch.tensor([[s_of[i]] for i in layer], dtype=torch.float64)
            starts = interpolate_curve(par, s_layer)[:, 0]
            for i, start, pr in zip(layer, starts, par):
                pts = raw[i]
                gap = float((start - pts[0]).norm())
                if gap <= BRIDGE_GAP * float((pr[1] - pr[0]).norm()):
                    pts_of.append(pts + (start - pts[0]))
                else:
                    pts_of.append(torch.cat([start[None], pts]))
        else:
            pts_of = [raw[i] for i in layer]
        counts = torch.tensor([len(p) for p in pts_of])
        padded = torch.nn.utils.rnn.pad_sequence(pts_of, batch_first=True)
        for i, r in zip(layer, resample_polylines(padded, counts, T)):
            resampled[i] = r
    new_index = {i: k for k, i in enumerate(order)}
    points = torch.stack([resampled[i] for i in order]).to(dtype)
    par = [-1 if parents[i] < 0 else new_index[parents[i]] for i in order]
    return points, par, [s_of[i] for i in order], [labels[i] for i in order]


def _arc_fractions_of_projections(curve: Tensor, xs: Tensor) -> list[float]:
    """Arc-length fraction of the closest point of a raw polyline ``(n, d)`` to each point of ``xs (m, d)``."""
    seg = curve[1:] - curve[:-1]
    denom = (seg * seg).sum(-1)
    u = (((xs[:, None] - curve[:-1]) * seg).sum(-1) / torch.where(denom > 0, denom, 1)).clamp(0, 1)  # (m, n-1)
    nearest = (curve[:-1] + u[..., None] * seg - xs[:, None]).norm(dim=-1).argmin(-1).tolist()
    lengths = denom.sqrt()
    total = float(lengths.sum())
    if not total > 0:
        return [0.0] * len(xs)
    return [min(max(float(lengths[:k].sum() + u[j, k] * lengths[k]) / total, 0.0), 1.0)
            for j, k in enumerate(nearest)]


@dataclass(frozen=True, eq=False)
class TreeSequence:
    """A 4D tree: frames (one tree each, in time order) and their acquisition times.

    Attributes:
        frames: a :class:`Trees` batch with one tree per frame.
        times: ``(n_frames,)`` strictly increasing acquisition times (days, hours, ...).
        name: a label (e.g. the plant or folder name).
    """

    frames: Trees
    times: Tensor
    name: str = ""

    def __post_init__(self) -> None:
        if self.times.shape != (self.frames.num_trees,):
            raise TreeError(
                f"{self.name or 'sequence'}: {self.frames.num_trees} frames but times of shape "
                f"{tuple(self.times.shape)}"
            )
        if self.frames.num_trees == 0:
            raise TreeError(f"{self.name or 'sequence'}: a sequence needs at least one frame")
        if len(self.times) > 1 and not (torch.diff(self.times) > 0).all():
            raise TreeError(f"{self.name or 'sequence'}: times must increase strictly, got {self.times.tolist()}")

    def __len__(self) -> int:
        return self.frames.num_trees

    def normalized_times(self) -> Tensor:
        """Times mapped affinely onto ``[0, 1]`` (a single frame sits at 0)."""
        span = self.times[-1] - self.times[0]
        return (self.times - self.times[0]) / span if len(self.times) > 1 else torch.zeros_like(self.times)

    def to(self, *args, **kwargs) -> TreeSequence:
        frames = self.frames.to(*args, **kwargs)
        return TreeSequence(frames, self.times.to(device=frames.device, dtype=frames.dtype), self.name)

    def __getitem__(self, index: int | slice | Sequence[int]) -> TreeSequence:
        """Select frames (keeps them in time order)."""
        idx = [index] if isinstance(index, int) else index
        sub = self.frames[idx]
        times = self.times[torch.as_tensor(idx)] if not isinstance(idx, slice) else self.times[idx]
        return TreeSequence(sub, times.reshape(-1), self.name)
