"""Synthetic growing plants (tomato, maize, bean and almond 4D skeletons) with organ-level ground truth.

The package's embedded data: methods can be tested and benchmarked where the right answer is
known (which branch is which organ, how two plants' clocks relate), without real scans.

**What a plant is.** Every frame of a plant is a *skeleton graph*, as a skeletonised laser scan
gives it (Pheno4D, docs/method.md §6): nodes ``xyz (n, 3)`` (mm, z up, the root at the origin),
parent links ``parent (n,)`` (``-1`` for the root) and, as ground truth, the organ of every node
``organ (n,)`` (a branch point belongs to the parent organ). :attr:`SyntheticPlant.skeletons`
holds them; :attr:`SyntheticPlant.sequence` is derived from them by the package's reader path,
:func:`torch4dtree.trees.skeleton.skeleton_to_trees` (the hierarchy rule a user's SWC file goes
through; a branch's label is the most common organ among its own nodes). Organs are not
branches: when the rule runs the main branch up the stem into a leaf, that branch carries the
label of whichever organ has more of its nodes, the stem above the leaf becomes a side branch
labelled ``0``, and the next frame may pick another leaf. Nothing here protects the rule.

How a plant is made, one module per step:

* :mod:`.clock`: the plant's biological clock ``h`` and its scanning days;
* :mod:`.kinds`: the organs of a plant of each kind (:mod:`.plant_model`: how they grow with ``h``);
* :mod:`.organ_curves`: the organs as 3D curves at a frame's biological time, with random bends;
* :mod:`.scanning`: the curves as a skeleton graph with skeletonisation noise;
* :mod:`.labels`: the organ labels (base-100 digit paths, the same organ in every frame and plant).

Randomness: ``numpy.random.default_rng`` (PCG64) seeded from the plant seed (plant structure)
and from ``(seed, frame)`` (per-frame scanning noise), so a seed gives the same plant on any
machine, and a written frame reads back as the same skeleton (and the same trees).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from ..settings import DEFAULT_T
from ..trees.growth import consistent_frames
from ..trees.skeleton import skeleton_to_trees
from ..trees.structures import Trees, TreeSequence
from .clock import default_times, evaluate_warp, sample_growth_warp
from .kinds import KIND_MODELS, KINDS, STRUCTURES
from .labels import SHOOT_OFFSET, SPUR_LABEL, STEM_LABEL, label_layer, label_organ, label_parts, parent_label
from .organ_curves import organ_curves
from .scanning import sample_skeleton

__all__ = [
    "KINDS", "SHOOT_OFFSET", "SPUR_LABEL", "STEM_LABEL", "Skeleton", "SyntheticPlant", "default_times",
    "evaluate_warp", "label_layer", "label_organ", "label_parts", "parent_label", "plant_seed", "relative_warp",
    "sample_growth_warp", "synthetic_dataset", "synthetic_plant",
]

Skeleton = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True, eq=False)
class SyntheticPlant:
    """A synthetic 4D plant and its ground truth.

    Attributes:
        sequence: the 4D tree derived from :attr:`skeletons` by
            :func:`~torch4dtree.trees.skeleton.skeleton_to_trees` (with the plant's ``hierarchy_kwargs``);
            ``sequence.frames.label`` is each branch's majority organ (module doc).
        kind: ``"tomato"``, ``"maize"``, ``"bean"`` or ``"almond"``.
        seed: the seed that regenerates this plant alone (``synthetic_plant(kind, seed, ...)``).
        growth_grid: ``(G,)`` normalised calendar times ``linspace(0, 1, G)``.
        growth_warp: ``(G,)`` the biological clock ``h`` on ``growth_grid`` (monotone, ``h(0)=0``,
            ``h(1)=1``, linear in between).
        bio_times: ``(n_frames,)`` ``h`` at the frames' normalised times.
        settings: the generation settings (JSON-serialisable).
        skeletons: per frame ``(xyz (n, 3) float64 mm, parent (n,) int64 with -1 at the root (node 0),
            organ (n,) int64 labels)``; a branch point carries its parent organ's label.
        name: e.g. ``"tomato_03"`` in a dataset.
    """

    sequence: TreeSequence
    kind: str
    seed: int
    growth_grid: Tensor
    growth_warp: Tensor
    bio_times: Tensor
    settings: dict
    skeletons: list[Skeleton] = field(default_factory=list)
    name: str = ""

    def warp(self, t: Tensor | np.ndarray | float) -> Tensor:
        """The biological clock ``h`` at normalised calendar times ``t`` (float64, same shape)."""
        return evaluate_warp(self.growth_grid, self.growth_warp, t)

    @property
    def times(self) -> Tensor:
        """``(n_frames,)`` frame times (calendar, e.g. days)."""
        return self.sequence.times

    def warp_inverse(self, y: Tensor | np.ndarray | float) -> Tensor:
        """``h^{-1}``: the normalised calendar time at which the plant reaches biological time ``y``."""
        return evaluate_warp(self.growth_warp, self.growth_grid, y)

    def labels_per_frame(self) -> list[list[int]]:
        """Per frame, the sorted labels of the derived trees' branches (a label may repeat or be missing)."""
        f = self.sequence.frames
        ptr = f.ptr.tolist()
        lab = f.label.tolist()
        return [sorted(lab[a:b]) for a, b in zip(ptr[:-1], ptr[1:])]

    def organs_per_frame(self) -> list[list[int]]:
        """Per frame, the sorted organ labels present in the skeleton (spurs left out)."""
        return [sorted(set(organ.tolist()) - {SPUR_LABEL}) for _, _, organ in self.skeletons]

    def organ_lengths(self) -> list[dict[int, float]]:
        """Per frame, each organ's length along the skeleton (mm; the edges ending in its nodes, spurs left out)."""
        out = []
        for xyz, parent, organ in self.skeletons:
            edge = np.linalg.norm(xyz[1:] - xyz[parent[1:]], axis=1)
            sums: Counter[int] = Counter()
            for lab, e in zip(organ[1:].tolist(), edge.tolist()):
                sums[lab] += e
            sums.pop(SPUR_LABEL, None)
            out.append({lab: sums.get(lab, 0.0) for lab in sorted(set(organ.tolist()) - {SPUR_LABEL})})
        return out


def relative_warp(a: SyntheticPlant, b: SyntheticPlant, t: Tensor | np.ndarray | float) -> Tensor:
    """The true time warp between two plants: ``xi(t) = h_b^{-1}(h_a(t))`` (float64, shape of ``t``).

    Plant ``b`` at normalised time ``xi(t)`` is as developed as plant ``a`` at ``t``, so a temporal
    registration that matches ``b``'s trajectory at ``xi(t)`` to ``a``'s at ``t`` should recover it.

    Example:
        >>> plant = synthetic_plant("tomato", seed=0, n_frames=2, T=8)
        >>> relative_warp(plant, plant, torch.tensor([0.0, 0.5, 1.0])).tolist()  # a plant is in step with itself
        [0.0, 0.5, 1.0]
    """
    return b.warp_inverse(a.warp(t))


def _json_safe(value: object) -> object:
    return value if isinstance(value, (str, int, float, bool, type(None))) else repr(value)


def synthetic_plant(
    kind: str = "tomato",
    seed: int = 0,
    n_frames: int = 10,
    times: Sequence[float] | Tensor | np.ndarray | None = None,
    T: int = DEFAULT_T,
    noise: float = 0.5,
    warp_strength: float = 1.0,
    min_length: float = 2.0,
    grid_size: int = 101,
    dtype: torch.dtype = torch.float32,
    name: str = "",
    node_spacing: float | None = None,
    jitter: float = 0.15,
    spurs: float = 1.0,
    hierarchy_kwargs: dict | None = None,
    joint_hierarchy: bool = True,
    variation: bool = False,
) -> SyntheticPlant:
    """Generate one synthetic growing plant: per-frame skeletons with organ labels, and the trees derived from them.

    Args:
        kind: ``"tomato"`` (stem, cotyledons, compound leaves with leaflets and lobes, basal side
            shoots), ``"maize"`` (stem and whorl, two-ranked arching leaves), ``"bean"`` (primary
            leaves, trifoliate leaves, side shoots with leaves of their own) or ``"almond"`` (a young
            tree's wood: trunk, scaffolds, secondary shoots, spurs); see the module doc.
        seed: any non-negative int; the same seed gives the same plant.
        n_frames: number of frames when ``times`` is not given.
        times: ``(n_frames,)`` strictly increasing acquisition times (any unit); default:
            irregular days from the seed (:func:`default_times`). The first and last map to
            normalised times 0 and 1.
        T: points per branch of the derived trees.
        noise: size (mm) of the smooth per-frame random bend of each branch (tip displacement); 0 for none.
        warp_strength: how far the growth clock departs from the identity (0: ``h(t) = t``).
        min_length: an organ appears in a frame once it is at least this long (mm).
        grid_size: points of the growth-warp grid.
        dtype: dtype of the derived trees' points.
        name: the sequence name.
        node_spacing: mean distance (mm) between skeleton nodes; default the kind's (1.15-1.4).
        jitter: standard deviation (mm) of the per-node position noise; 0 for none.
        spurs: multiplier of the kind's rate of skeletonisation spurs; 0 for none.
        hierarchy_kwargs: keyword arguments of :func:`~torch4dtree.trees.skeleton.skeleton_to_trees` (the
            hierarchy rule and its settings) used to derive :attr:`SyntheticPlant.sequence`.
        joint_hierarchy: choose each frame's main branch to agree with the next frame's
            (:func:`~torch4dtree.trees.growth.consistent_frames`), as :func:`~torch4dtree.io.read_sequence` does
            with the written SWC files by default; ``False``: the rule on each frame alone.
        variation: herbaceous plants get a per-plant vigour that varies their leaf count, side shoots and the
            leaves of those (as plants of one crop in a field differ; module :mod:`~torch4dtree.data.kinds`);
            ``False`` keeps the plants of a seed those of the generator without it.

    Organs grow as real ones do, with no cap that would let the longest-path rule find the stem: the
    derived hierarchy is whatever the rule makes, as on real scans.

    Returns:
        a :class:`SyntheticPlant`. Units are mm, z up, the root at the origin.

    Example:
        >>> plant = synthetic_plant("tomato", seed=0, n_frames=2, T=8)
        >>> len(plant.sequence), plant.sequence.frames.T, plant.name
        (2, 8, 'tomato_seed0')
        >>> plant.organs_per_frame()[0][:3]  # the stem and the cotyledons
        [0, 1, 2]
    """
    if kind not in KINDS:
        raise ValueError(f"unknown plant kind {kind!r}; expected one of {', '.join(KINDS)}")
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    model_kind = KIND_MODELS[kind]
    spacing = model_kind.node_spacing if node_spacing is None else float(node_spacing)
    if not 0.1 <= spacing <= 20.0:
        raise ValueError(f"node_spacing must lie in [0.1, 20] mm, got {spacing}")
    if jitter < 0 or spurs < 0 or noise < 0:
        raise ValueError(f"noise, jitter and spurs must be non-negative, got {noise}, {jitter}, {spurs}")
    kid = KINDS.index(kind)  # different kinds with one seed get unrelated draws
    rng = np.random.default_rng([seed, kid, 0])
    model = STRUCTURES[kind](rng, variation)
    if times is None:
        if n_frames < 2:
            raise ValueError(f"a synthetic plant needs at least 2 frames, got n_frames={n_frames}")
        t = default_times(np.random.default_rng([seed, kid, 1]), n_frames)
    else:
        t = np.asarray(torch.as_tensor(times).double().cpu()).reshape(-1)
        if len(t) < 2 or not np.all(np.diff(t) > 0) or not np.isfinite(t).all():
            raise ValueError(f"times must be at least 2 finite, strictly increasing values, got {t.tolist()}")
    grid, h = sample_growth_warp(np.random.default_rng([seed, kid, 2]), grid_size, warp_strength)
    tn = (t - t[0]) / (t[-1] - t[0])
    bio = np.interp(tn, grid, h)
    name = name or f"{kind}_seed{seed}"
    skeletons: list[Skeleton] = []
    for j, b in enumerate(bio):
        frame_rng = np.random.default_rng([seed, kid, 3, j])
        curves, length, pos = organ_curves(model, float(b), frame_rng, noise, min_length)
        sk = sample_skeleton(model, curves, length, pos, frame_rng, spacing, jitter, spurs)
        skeletons.append(sk)
    names = [f"{name} frame {j}" for j in range(len(bio))]
    if joint_hierarchy:
        trees = consistent_frames(skeletons, T=T, names=names, dtype=dtype, **(hierarchy_kwargs or {}))
    else:
        trees = [skeleton_to_trees(sk[0], sk[1], T=T, node_labels=sk[2], dtype=dtype, where=where,
                                   **(hierarchy_kwargs or {})) for sk, where in zip(skeletons, names)]
    sequence = TreeSequence(Trees.cat(trees), torch.tensor(t, dtype=dtype), name)
    settings = {"n_frames": len(t), "T": T, "noise": noise, "warp_strength": warp_strength,
                "min_length": min_length, "grid_size": grid_size, "node_spacing": spacing, "jitter": jitter,
                "spurs": spurs}
    if not joint_hierarchy:
        settings["joint_hierarchy"] = False
    if hierarchy_kwargs:
        settings["hierarchy_kwargs"] = {k: _json_safe(v) for k, v in hierarchy_kwargs.items()}
    return SyntheticPlant(
        sequence, kind, int(seed), torch.from_numpy(grid), torch.from_numpy(h), torch.from_numpy(bio), settings,
        skeletons, name,
    )


def plant_seed(seed: int, index: int) -> int:
    """The seed of plant ``index`` of a dataset drawn with ``seed`` (a 32-bit int).

    Example:
        >>> plant_seed(0, 1)
        3964924996
    """
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def synthetic_dataset(
    kind: str = "tomato",
    plants: int = 7,
    seed: int = 0,
    n_frames: int = 10,
    times: Sequence[float] | Tensor | np.ndarray | None = None,
    shared_times: bool = True,
    hierarchy_kwargs: dict | None = None,
    **kwargs: object,
) -> list[SyntheticPlant]:
    """Several plants of one kind (their labels name the same organs).

    Plant ``i`` is ``synthetic_plant(kind, plant_seed(seed, i), ...)`` named ``f"{kind}_{i:02d}"``.
    With ``shared_times`` (default) and no ``times``, all plants are scanned on the same irregular
    days drawn from ``seed`` (as in Pheno4D); otherwise each plant draws its own.
    ``hierarchy_kwargs`` and other keyword arguments go to :func:`synthetic_plant`.

    Example:
        >>> plants = synthetic_dataset("tomato", plants=2, seed=0, n_frames=2, T=8)
        >>> [p.name for p in plants], bool((plants[0].times == plants[1].times).all())
        (['tomato_00', 'tomato_01'], True)
    """
    if plants < 1:
        raise ValueError(f"plants must be at least 1, got {plants}")
    if times is None and shared_times:
        times = default_times(np.random.default_rng([seed, 99]), n_frames)
    out = []
    for i in range(plants):
        p = synthetic_plant(kind, plant_seed(seed, i), n_frames=n_frames, times=times, name=f"{kind}_{i:02d}",
                            hierarchy_kwargs=hierarchy_kwargs, **kwargs)  # type: ignore[arg-type]
        out.append(replace(p, settings={**p.settings, "dataset_seed": seed, "index": i}))
    return out
