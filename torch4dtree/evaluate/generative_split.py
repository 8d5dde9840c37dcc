"""Which plants the generative section fits on and which it holds out (docs/method.md §7).

Two ways, per kind of plant:

* **Folds** (the default): a seeded permutation of the kind's plants is cut into ``min(N // 2, folds)`` near-equal
  folds; each is held out once and both models are fit on the others. ``folds=2`` on 40 plants is the protocol of
  the plausibility targets: fit on 20, 20 held out (and the other way round).
* **An explicit held-out folder** (``heldout``): the data folder's plants are the training set, the held-out
  folder's plants (read as the data folder is, its own source) the held-out set: one fold per kind. Kinds are paired
  by name; when each side has exactly one kind they are paired whatever their names (a dataset folder without
  ``dataset.json`` reads as the kind ``plant``).

The split and the draws are :class:`~torch4dtree.evaluate.data.EvalSettings`' ``heldout``, ``folds`` and
``morpho_draws``. The plausibility protocol's draws (``morpho_draws``): every generator's morphometrics are
measured on that many independent draws of as many samples as held-out plants (the equal-size comparison the
training plants' own row makes), summarised by the median and the worst draw: with 20-30 samples one draw moves the
worst median ratio and the morphometric 1-NNA by 0.1-0.2.
"""

from __future__ import annotations

from pathlib import Path

import torch

from .data import MAX_FOLDS, EvalData, EvalSettings, Plant4D, load_eval_data, primary_source, sources_of

__all__ = ["folds_of", "heldout_by_kind", "load_heldout", "splits"]

MIN_PLANTS = 2  # per side of a split: COV and 1-NNA are meaningless with one held-out plant


def folds_of(n: int, generator: torch.Generator, max_folds: int = MAX_FOLDS) -> list[list[int]]:
    """Held-out index sets: a permutation of ``range(n)`` cut into ``min(n // 2, max_folds)`` near-equal folds
    (each of at least 2 plants, each training set of at least 2); empty when ``n < 4``.

    Example:
        >>> [len(f) for f in folds_of(40, torch.Generator().manual_seed(0), max_folds=2)]
        [20, 20]
    """
    k = min(n // 2, max_folds)
    if n < 2 * MIN_PLANTS or k < 2:
        return []
    perm = torch.randperm(n, generator=generator)
    return [sorted(int(i) for i in f) for f in torch.tensor_split(perm, k)]


def load_heldout(folder: str | Path, T: int) -> EvalData:
    """The held-out plants of a folder: its primary source (as the data folder's), read at ``T`` points per branch."""
    folder = Path(folder)
    datas = {s: load_eval_data(folder, s, T) for s in sources_of(folder)}
    source = primary_source(datas)
    if source is None:
        raise ValueError(f"{folder}: no plants to hold out")
    return datas[source]


def heldout_by_kind(train: EvalData, heldout: EvalData) -> dict[str, list[Plant4D]]:
    """Held-out plants for each training kind (module doc: by name, or the only kind of each side); a plant with a
    frame file among the training plants' is an error.

    Example:
        >>> from pathlib import Path
        >>> a, b = EvalData(Path("a"), "folder"), EvalData(Path("b"), "synthetic")
        >>> heldout_by_kind(a, b)
        {}
    """
    fit = {f.resolve() for p in train.plants for f in p.files}
    both = [p.name for p in heldout.plants if any(f.resolve() in fit for f in p.files)]
    if both:
        raise ValueError(f"held-out plants that are also training plants (a frame file in both): {both[:5]}")
    if len(train.kinds) == 1 and len(heldout.kinds) == 1:
        return {train.kinds[0]: heldout.plants}
    return {k: heldout.by_kind(k) for k in train.kinds if heldout.by_kind(k)}


def splits(plants: list[Plant4D], settings: EvalSettings, generator: torch.Generator,
           heldout: list[Plant4D] | None = None) -> list[tuple[list[Plant4D], list[Plant4D]]]:
    """``(training, held-out)`` plants of each fold of one kind (module doc); ``heldout`` given: one fold, the
    plants against it; empty when a side would have fewer than 2 plants. ``quick``: the fold with the largest
    training set only.

    Example:
        >>> [(len(t), len(h)) for t, h in splits(list(range(40)), EvalSettings(folds=2), torch.Generator())]
        [(20, 20), (20, 20)]
    """
    if heldout is not None:
        return [(plants, heldout)] if len(plants) >= MIN_PLANTS and len(heldout) >= MIN_PLANTS else []
    folds = folds_of(len(plants), generator, settings.folds)
    if settings.quick and folds:
        folds = [min(folds, key=len)]
    return [([p for i, p in enumerate(plants) if i not in set(f)], [plants[i] for i in f]) for f in folds]
