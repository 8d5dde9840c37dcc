"""Trees between the scans of a 4D tree, for smooth videos: the geodesic between registered neighbours.

A video of a growing plant at one picture per scan jumps (scans are days apart, irregularly). Between
two scans ``k`` and ``k + 1`` we show the geodesic from scan ``k`` to scan ``k + 1`` (docs/method.md §3:
both registered into one slot layout, a straight line there), at the fraction of the time elapsed
between them. A branch that appears between the scans grows from nothing; at a scan time the scan itself is
shown (its registered copy, the same curves). This is a picture of the registration, not of biology.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # torch and the trees are imported where used: importing the renderer stays light
    import torch

    from ..trees.structures import Trees, TreeSequence

# branches shorter than this fraction of the scan's largest extent are not drawn (just-appeared branches)
MIN_LENGTH = 1e-4


def _slot_labels(frames: list[Trees], k: int, source: torch.Tensor) -> torch.Tensor:
    """``(S,)`` original label of every slot of the layout of scans ``k`` (moving) and ``k + 1`` (reference):
    the reference branch's label where the slot holds one, else the moving branch's."""
    import torch

    src_m, src_r = source[0].cpu(), source[1].cpu()
    lab_m, lab_r = frames[k].label.cpu(), frames[k + 1].label.cpu()
    out = torch.full(src_m.shape, -1, dtype=torch.long)
    has_m, has_r = src_m >= 0, src_r >= 0
    out[has_m] = lab_m[src_m[has_m]]
    out[has_r] = lab_r[src_r[has_r]]
    return out


def interpolate_sequence(seq: TreeSequence, times: np.ndarray | torch.Tensor | list[float],
                         **register_kwargs: Any) -> Trees:
    """One tree per requested time: the geodesic point between the registered scans that bracket it.

    Args:
        seq: the 4D tree (``n`` scans at increasing times).
        times: ``(k,)`` times in ``seq.times`` units; clamped to ``[t_0, t_n]``.
        register_kwargs: passed to :func:`~torch4dtree.trees.registration.register_trees` (default: no
            rotation, the scans share a frame).

    Returns:
        ``Trees`` with ``k`` trees (float64), in the order of ``times``. Branch labels are the scans' own
        (not slot indices), so ``color="label"`` keeps a branch's colour across scans.
    """
    import torch

    from ..trees.registration import register_trees
    from ..trees.structures import Trees

    t_scan = seq.times.detach().cpu().double().numpy()
    u = np.clip(np.asarray(times, dtype=np.float64).reshape(-1), t_scan[0], t_scan[-1])
    frames = seq.frames.to(torch.float64).split()
    if len(frames) == 1:
        return Trees.cat([frames[0]] * len(u))
    # segment k covers [t_k, t_k+1]; a time equal to a scan time starts its segment (the last ends one)
    seg = np.clip(np.searchsorted(t_scan, u, side="right") - 1, 0, len(frames) - 2)
    frac = (u - t_scan[seg]) / (t_scan[seg + 1] - t_scan[seg])
    kwargs = {"rotation": "none", **register_kwargs}
    out: list[Trees | None] = [None] * len(u)
    for k in np.unique(seg).tolist():
        idx = np.nonzero(seg == k)[0]
        reg = register_trees(frames[k], frames[k + 1], **kwargs)
        aligned = reg.aligned
        scale = float(torch.cat([frames[k].height(), frames[k + 1].height()]).max()) or 1.0
        path = aligned[0].lerp(aligned[1], torch.as_tensor(frac[idx])).to_trees(MIN_LENGTH * scale)
        labels = _slot_labels(frames, k, aligned.source)
        path = replace(path, label=labels.to(path.label.device)[path.label])
        for j, tree in zip(idx.tolist(), path.split()):
            out[j] = tree
    return Trees.cat(out)  # type: ignore[arg-type]
