"""The ground-truth layout of labelled plants: trajectories built from the organ labels, without any spatial
registration, so that a temporal registration on them measures the temporal step alone (an oracle for
``torch4dtree evaluate``'s truth section and the growth-clock benchmark)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from ..curves.rotation import optimal_rotation
from ..curves.srvf import srvf
from ..space.pca import principal_axes
from ..temporal.trajectory import resample_trajectory

__all__ = ["label_features", "pca_trajectories"]


def label_features(seqs: Sequence, T: int) -> list[Tensor]:
    """Per sequence ``(n_frames, F)``: the SRVF of every organ (ground-truth label; zeros where absent) and its
    ``s``, in one layout shared by all sequences (an oracle layout that isolates the temporal registration).
    Every sequence is first turned about the vertical to face the first one (plants grow in any azimuth):
    the rotation is fitted on the organs common to their last frames."""
    labels = sorted({int(v) for s in seqs for v in s.frames.label.tolist()})
    col = {v: i for i, v in enumerate(labels)}
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    qs = [srvf(s.frames.points.double()) for s in seqs]
    last = [s.frames.tree_index == len(s) - 1 for s in seqs]
    out = []
    for s, q, lst in zip(seqs, qs, last):
        f = s.frames
        ref_lab = {int(v): i for i, v in zip(last[0].nonzero()[:, 0].tolist(), seqs[0].frames.label[last[0]].tolist())}
        pairs = [(ref_lab[int(v)], i) for i, v in zip(lst.nonzero()[:, 0].tolist(), f.label[lst].tolist())
                 if int(v) in ref_lab]
        q1 = qs[0][[i for i, _ in pairs]].reshape(1, -1, 3)
        q2 = q[[j for _, j in pairs]].reshape(1, -1, 3)
        O = optimal_rotation(q1, q2, "vertical", up)[0]
        tab = torch.zeros(len(s), len(labels), T - 1, f.dim, dtype=torch.float64)
        pos = torch.zeros(len(s), len(labels), dtype=torch.float64)
        idx = torch.tensor([col[int(v)] for v in f.label.tolist()])
        tab[f.tree_index, idx] = q @ O.T
        pos[f.tree_index, idx] = f.s.double()
        out.append(torch.cat([tab.flatten(1) / math.sqrt(T - 1), pos], 1))
    return out


def pca_trajectories(feats: list[Tensor], times: list[Tensor], k: int, n_t: int) -> list[Tensor]:
    """Project every frame on the top ``k`` principal directions of all frames, resample on ``n_t`` times."""
    allf = torch.cat(feats)
    mean = allf.mean(0)
    Vh = principal_axes(allf - mean)[1]
    return [resample_trajectory((f - mean) @ Vh[:k].T, t.double(), n_t) for f, t in zip(feats, times)]
