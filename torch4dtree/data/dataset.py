"""A ``torch.utils.data.Dataset`` over a dataset folder (one 4D tree per item) and a padded collate.

4D trees differ in frames and branches, so a batch pads them to the largest and carries masks
(:class:`SequenceBatch`), and keeps the sequences themselves for the package's own methods
(e.g. :meth:`~torch4dtree.model.FourDTreeModel.encode`). ``examples/training_loop.py`` uses both in
a training loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import torch
from torch import Tensor
from torch.utils.data import Dataset

from ..trees.structures import TreeSequence

__all__ = ["SequenceBatch", "TreeSequenceDataset", "collate_sequences"]


class TreeSequenceDataset(Dataset):
    """The 4D trees of a dataset folder (``io.sequence_folders``), read lazily, one per item.

    Args:
        root: the dataset folder.
        T: points per branch after resampling; ``dtype``: of the points; other loading settings via ``options``
            (an :class:`~torch4dtree.io.LoadOptions`, overriding ``T`` and ``dtype`` when given).
        cache: keep the sequences read in memory.

    Example:
        >>> import tempfile
        >>> from torch.utils.data import DataLoader
        >>> from torch4dtree.data import synthetic_dataset, write_dataset
        >>> root = write_dataset(synthetic_dataset("tomato", plants=2, n_frames=2, T=8), tempfile.mkdtemp())
        >>> dataset = TreeSequenceDataset(root, T=8)
        >>> len(dataset), dataset[0].name
        (2, 'tomato_00')
        >>> batch = next(iter(DataLoader(dataset, batch_size=2, collate_fn=collate_sequences)))
        >>> batch.points.shape[:2], batch.points.shape[3:], batch.frame_mask.tolist()
        (torch.Size([2, 2]), torch.Size([8, 3]), [[True, True], [True, True]])
    """

    def __init__(self, root: str | Path, T: int = 32, dtype: torch.dtype = torch.float32, options: object = None,
                 cache: bool = True) -> None:
        from ..io import LoadOptions, sequence_folders

        self.root = Path(root)
        self.folders = sequence_folders(self.root)
        self.options = options if options is not None else LoadOptions(T=T, dtype=dtype)
        self.cache = cache
        self._cached: dict[int, TreeSequence] = {}

    def __len__(self) -> int:
        return len(self.folders)

    def __getitem__(self, index: int) -> TreeSequence:
        from ..io import read_sequence

        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} 4D trees")
        index %= len(self)
        if index in self._cached:
            return self._cached[index]
        seq = read_sequence(self.folders[index], self.options).sequence  # type: ignore[arg-type]
        if self.cache:
            self._cached[index] = seq
        return seq


class SequenceBatch(NamedTuple):
    """A padded batch of ``B`` 4D trees (``F`` = most frames, ``N`` = most branches in a frame, ``T`` points).

    * ``points (B, F, N, T, d)``, ``parent (B, F, N)`` long (index within the frame, ``-1`` main branch or
      padding), ``s (B, F, N)``, ``label (B, F, N)`` long (``-1`` padding), ``branch_mask (B, F, N)`` bool.
    * ``times (B, F)``, ``frame_mask (B, F)`` bool; ``sequences``: the input list.
    """

    points: Tensor
    parent: Tensor
    s: Tensor
    label: Tensor
    branch_mask: Tensor
    times: Tensor
    frame_mask: Tensor
    sequences: list[TreeSequence]


def collate_sequences(items: Sequence[TreeSequence]) -> SequenceBatch:
    """Pad 4D trees into one :class:`SequenceBatch` (frames and branches padded with zeros / ``-1``).

    Example:
        >>> import numpy as np
        >>> from torch4dtree import Trees
        >>> stem, leaf = np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([[0.0, 0, 5], [4, 0, 8]])
        >>> young = Trees.from_branches([[stem * 0.5]], [[-1]], T=8)
        >>> grown = Trees.from_branches([[stem, leaf]], [[-1, 0]], T=8)
        >>> one = TreeSequence(young, torch.tensor([0.0]))
        >>> two = TreeSequence(Trees.cat([young, grown]), torch.tensor([0.0, 2.0]))
        >>> batch = collate_sequences([one, two])
        >>> batch.points.shape, batch.branch_mask.tolist()
        (torch.Size([2, 2, 2, 8, 3]), [[[True, False], [False, False]], [[True, False], [True, True]]])
    """
    if not items:
        raise ValueError("collate_sequences needs at least one 4D tree")
    T, d = items[0].frames.T, items[0].frames.dim
    for seq in items:
        if not isinstance(seq, TreeSequence):
            raise TypeError(f"expected TreeSequences, got {type(seq).__name__}")
        if (seq.frames.T, seq.frames.dim) != (T, d):
            raise ValueError(f"4D trees with different T or dimension: {(seq.frames.T, seq.frames.dim)} vs {(T, d)}; "
                             f"resample them to one T")
    B = len(items)
    F = max(len(s) for s in items)
    N = max(int(torch.diff(s.frames.ptr).max()) for s in items)
    dt = items[0].frames.dtype
    points = torch.zeros(B, F, N, T, d, dtype=dt)
    parent = torch.full((B, F, N), -1, dtype=torch.long)
    s_ = torch.zeros(B, F, N, dtype=dt)
    label = torch.full((B, F, N), -1, dtype=torch.long)
    mask = torch.zeros(B, F, N, dtype=torch.bool)
    times = torch.zeros(B, F, dtype=items[0].times.dtype)
    fmask = torch.zeros(B, F, dtype=torch.bool)
    for b, seq in enumerate(items):
        fr = seq.frames
        f, j = fr.tree_index.cpu(), fr.local_index.cpu()
        points[b, f, j] = fr.points.detach().cpu().to(dt)
        parent[b, f, j] = fr.parent.cpu()
        s_[b, f, j] = fr.s.detach().cpu().to(dt)
        label[b, f, j] = fr.label.cpu()
        mask[b, f, j] = True
        times[b, : len(seq)] = seq.times.cpu()
        fmask[b, : len(seq)] = True
    return SequenceBatch(points, parent, s_, label, mask, times, fmask, list(items))
