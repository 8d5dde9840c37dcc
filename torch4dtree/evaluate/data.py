"""What ``torch4dtree evaluate`` runs on: the plants of a data folder, grouped by kind, with whatever truth it has.

Two layouts are recognised:

* **Pheno4D-style** (as ``../shared/data/pheno4d``): ``DIR/mat/<plant>_seq/`` (the paper's hand-corrected trees;
  ``<plant>_seq_alt`` / ``_altered`` are the same plants with days removed, kept as :attr:`Plant4D.altered`) and / or
  ``DIR/swc/<plant>/`` (raw skeletons). The kind is read from the plant's name (``maize...`` or tomato).
* **Synthetic dataset folder** (``torch4dtree synth``): sequence folders of SWC skeletons whose type column is the
  organ label, and ``dataset.json`` with each plant's growth clock (:attr:`Plant4D.truth`).
* **Any other dataset folder** (what ``torch4dtree fit`` reads: one sequence folder per plant), source ``folder``:
  every plant is of one kind, ``plant``; no ground truth, no paper figures beside ours.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..io import LoadOptions, read_sequence, sequence_folders
from ..io.dataset import DatasetError
from ..settings import CROSS_LP, CROSS_ORDER_TOL, CROSS_POSITIONS, CrossSettings, ModelSettings
from ..trees.structures import TreeSequence

__all__ = ["MAX_FOLDS", "MORPHO_DRAWS", "QUICK_MORPHO_DRAWS", "EvalData", "EvalSettings", "Plant4D", "load_eval_data",
           "primary_source", "sources_of"]

SOURCES = ("mat", "swc", "synthetic", "folder")
# the source the paper-style 4D experiments and the figures use when a folder has several: the paper's trees first
PRIMARY_ORDER = ("mat", "synthetic", "swc", "folder")
GENERIC_KIND = "plant"
# the generative section's split: at most this many folds per kind by default
MAX_FOLDS = 3
# its independent morphometric draws per generator and fold (quick: QUICK_MORPHO_DRAWS at most)
MORPHO_DRAWS, QUICK_MORPHO_DRAWS = 5, 2


@dataclass
class EvalSettings:
    """Settings of every experiment (one object so the report can state them).

    ``T``: points per branch for registration and the 4D experiments; ``T_cycle``: points per branch of the cycle
    consistency table (the paper's trees are dense); ``n_t``: common time samples of trajectories; ``lambdas``:
    ``(lm, ls, lp)`` with ``lp`` relative to the plant's size; ``rotation``: of cross-plant registrations;
    ``quick``: small versions of every experiment (tests, a first look); ``seed``: every random choice;
    ``cross_positions`` / ``cross_lp`` / ``cross_order_tol``: the cross-sequence registrations' settings
    (:func:`register4d`'s ``positions`` / ``cross_lp`` / ``cross_order_tol``, also the truth section's cross-plant
    registrations); ``heldout`` / ``folds`` / ``morpho_draws``: the generative section's split and draws
    (:mod:`~torch4dtree.evaluate.generative_split`): a folder of held-out plants (the data folder is then the
    training set), else the largest number of folds (at least 2), and the morphometric draws per generator and fold
    (at least 1).

    Example:
        >>> EvalSettings(T=16).folds, EvalSettings(folds=2, quick=True).generative_draws()
        (3, 2)
    """

    T: int = 64
    T_cycle: int = 256
    n_t: int = 32
    lambdas: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation: str = "none"
    quick: bool = False
    seed: int = 0
    figures: bool = True
    cross_positions: str = CROSS_POSITIONS
    cross_lp: float | None = CROSS_LP
    cross_order_tol: float | None = CROSS_ORDER_TOL
    heldout: str | None = None
    folds: int = MAX_FOLDS
    morpho_draws: int = MORPHO_DRAWS

    def __post_init__(self) -> None:
        if self.folds < 2:
            raise ValueError(f"folds must be at least 2, got {self.folds}")
        if self.morpho_draws < 1:
            raise ValueError(f"morpho_draws must be at least 1, got {self.morpho_draws}")

    def generative_draws(self) -> int:
        """Morphometric draws per generator and fold of a run (:data:`QUICK_MORPHO_DRAWS` at most when
        :attr:`quick`)."""
        return min(self.morpho_draws, QUICK_MORPHO_DRAWS) if self.quick else self.morpho_draws

    def cross_settings(self) -> CrossSettings:
        """The cross-sequence registration settings (:func:`~torch4dtree.temporal.register4d`'s ``cross``).

        Example:
            >>> EvalSettings(cross_lp=None).cross_settings().lp is None
            True
        """
        return CrossSettings(positions=self.cross_positions, lp=self.cross_lp, order_tol=self.cross_order_tol)

    def model_settings(self, n_t: int) -> ModelSettings:
        """The generative model's settings of the experiments (one medoid candidate with :attr:`quick`)."""
        return ModelSettings(lambdas=self.lambdas, rotation=self.rotation, n_t=n_t, cross=self.cross_settings(),
                             medoid_candidates=1 if self.quick else 3)

    def generator(self, offset: int = 0) -> torch.Generator:
        """A fresh generator seeded from :attr:`seed` (``offset`` keeps experiments' streams apart)."""
        return torch.Generator().manual_seed(self.seed * 1000 + offset)


@dataclass
class Plant4D:
    """One 4D plant: ``sequence`` (float64), its frame ``files``, the ``altered`` copy with days removed (Pheno4D
    ``.mat`` only) and ``truth`` (synthetic only: the ``dataset.json`` record with ``growth_warp`` ``{grid,
    values}``, ``normalized_times``...; branch labels are the organs, in ``sequence.frames.label``)."""

    kind: str
    name: str
    sequence: TreeSequence
    files: list[Path]
    altered: TreeSequence | None = None
    truth: dict | None = None


@dataclass
class EvalData:
    """The plants of one source of a data folder: ``source`` is ``mat``, ``swc`` or ``synthetic``."""

    root: Path
    source: str
    plants: list[Plant4D] = field(default_factory=list)
    cache: dict = field(default_factory=dict, repr=False)  # registrations shared by experiments (.pairs)

    @property
    def kinds(self) -> list[str]:
        """The kinds present, in a fixed order (tomato before maize, as the paper's tables)."""
        order = {"tomato": 0, "maize": 1, "bean": 2, "almond": 3}
        return sorted({p.kind for p in self.plants}, key=lambda k: (order.get(k, 9), k))

    def by_kind(self, kind: str) -> list[Plant4D]:
        return [p for p in self.plants if p.kind == kind]

    @property
    def has_truth(self) -> bool:
        return self.source == "synthetic"


def _pheno4d_kind(name: str) -> str:
    return "maize" if name.lower().startswith("maize") else "tomato"


def sources_of(root: str | Path) -> list[str]:
    """The sources a data folder offers: ``["mat", "swc"]`` (either or both) or ``["synthetic"]``."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a folder")
    found = [s for s in ("mat", "swc") if (root / s).is_dir()]
    if found:
        return found
    if (root / "dataset.json").is_file():
        return ["synthetic"]
    try:
        sequence_folders(root)
    except DatasetError:
        raise DatasetError(f"{root}: neither a Pheno4D-style folder (mat/ or swc/ inside), a synthetic dataset folder "
                           "(dataset.json inside) nor a dataset folder (sequence folders of .swc / .mat frames)"
                           ) from None
    return ["folder"]


def primary_source(datas: dict[str, EvalData]) -> str | None:
    """The source the 4D experiments and figures use (:data:`PRIMARY_ORDER`), None without plants."""
    return next((s for s in PRIMARY_ORDER if s in datas and datas[s].plants), None)


def _frame_files(folder: Path, used: list[str]) -> list[Path]:
    return [folder / name for name in used]


def load_eval_data(root: str | Path, source: str, T: int = 64, max_plants: int | None = None) -> EvalData:
    """Read every plant of ``source`` (one of :func:`sources_of`) at ``T`` points per branch, in float64."""
    root = Path(root)
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    data = EvalData(root, source)
    if source == "synthetic":
        from ..data.writing import read_ground_truth

        meta = read_ground_truth(root)
        records = {r["folder"]: r for r in meta["plants"]}
        opts = LoadOptions(T=T, dtype=torch.float64, labels_from_type=True)
        for folder in sequence_folders(root)[:max_plants]:
            loaded = read_sequence(folder, opts)
            rec = records.get(folder.name)
            if rec is None:
                raise DatasetError(f"{folder}: not listed in {root / 'dataset.json'}")
            data.plants.append(Plant4D(rec.get("kind", meta["kind"]), folder.name, loaded.sequence,
                                       _frame_files(folder, loaded.files), truth=rec))
        return data
    if source == "folder":
        for folder in sequence_folders(root)[:max_plants]:
            loaded = read_sequence(folder, LoadOptions(T=T, dtype=torch.float64))
            data.plants.append(Plant4D(GENERIC_KIND, folder.name, loaded.sequence, _frame_files(folder, loaded.files)))
        return data
    opts = LoadOptions(T=T, dtype=torch.float64, repair=True)
    base = root / source
    folders = sorted(p for p in base.iterdir() if p.is_dir() and not p.name.startswith("."))
    altered = {p.name for p in folders if p.name.endswith(("_alt", "_altered"))}
    folders = [p for p in folders if p.name not in altered][:max_plants]
    for folder in folders:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # repaired Pheno4D skeletons are reported by the reader; known here
            loaded = read_sequence(folder, opts)
            alt = next((base / a for a in sorted(altered) if a.rsplit("_", 1)[0] == folder.name), None)
            alt_seq = read_sequence(alt, opts).sequence if alt is not None else None
        data.plants.append(Plant4D(_pheno4d_kind(folder.name), folder.name, loaded.sequence,
                                   _frame_files(folder, loaded.files), alt_seq))
    if not data.plants:
        raise DatasetError(f"{base}: no plant folders")
    return data
