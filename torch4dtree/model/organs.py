"""A generative model of growing plants built organ by organ (docs/method.md §5, generative models).

The paper's model (:class:`~torch4dtree.model.FourDTreeModel`) averages whole 4D trees in one linear space: a new
plant's organs beyond the common layout are dropped, presence thresholded from averaged SRVFs makes ghost stubs, and
averaging differently bent branches shrinks them. This model keeps the 4D registration within each plant (one
identity per organ over time) and models what the plants are made of instead:

* **slots by botanical position** (:mod:`torch4dtree.model.organ_table`): the ``k``-th organ along its parent,
  open-ended, so every training plant is written whole;
* **a plant latent** ``z`` (log total length at the last and the middle age, log organ count), drawn from the
  training plants' kernel density: it ties a plant's organs together (vigorous plants have more, longer, earlier
  organs);
* **organs copied with switches** (as haplotype copying models do): key by key, parents first and siblings in
  order, each organ follows a training plant: the one its previous sibling (or, for a first child, its parent)
  follows with probability ``persistence``, else one drawn with Gaussian kernel weights near ``z`` (``bandwidth`` in
  standard deviations) among the plants that have that previous organ. The organ exists if that plant has it (so
  topology is conditional on the parent and the previous sibling), and takes its log length (plus ``jitter``), its
  unit-length shapes over age, its monotone growth curve and its attachment. Size is apart from shape, so nothing is
  averaged into a stub; organs grow as the training organs grow, and vanish only where those did.

It is a kernel (nonparametric) conditional model: the fitted buffers hold the training organs. Samples mix organs of
different plants, so they are new plants, not copies (benchmarks/bench_generative.py measures both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from ..curves.srvf import interpolate_curve
from ..settings import OrganSettings
from ..trees.structures import Trees, TreeSequence
from .organ_table import UP, organ_table

__all__ = ["OrganModel", "OrganModelError", "assemble_frames", "carry_parents", "rotate_about_up"]

# the plant latent's features: log total length at the last age, at the middle age, log(1 + organs at the last age)
LATENT = 3
# siblings attached closer than this (share of the parent) sit on one node (a whorl, a leaflet pair)
SAME_NODE = 1e-4
# keep a sampled organ in a frame when it is at least this share of its plant's final main-branch length (a shorter
# one would be a zero-length branch once written)
MIN_LENGTH = 1e-3


class OrganModelError(ValueError):
    """An :class:`OrganModel` used before fitting, fitted on too few plants, or given a state that is not its own."""


def rotate_about_up(x: Tensor, angle: Tensor | float) -> Tensor:
    """Rotate points ``(..., d)`` about the vertical axis by ``angle`` radians.

    Example:
        >>> rotate_about_up(torch.tensor([[1.0, 0.0, 2.0]]), math.pi / 2).round().tolist()
        [[0.0, 1.0, 2.0]]
    """
    c, s = math.cos(float(angle)), math.sin(float(angle))
    h = [i for i in range(x.shape[-1]) if i != UP][:2]
    out = x.clone()
    out[..., h[0]] = c * x[..., h[0]] - s * x[..., h[1]]
    out[..., h[1]] = s * x[..., h[0]] + c * x[..., h[1]]
    return out


class OrganModel(nn.Module):
    """Generative model of 4D trees organ by organ (module doc). Build, then :meth:`fit`, or
    :func:`torch4dtree.model.load` a checkpoint written by :func:`torch4dtree.model.save_model`.

    Args:
        settings: the model's :class:`~torch4dtree.settings.OrganSettings` (``None``: the defaults): frames of a
            generated plant, the latent kernel's bandwidth, the donors' persistence, the length jitter, the
            latent's truncation ``c`` and the within-sequence registration's search.

    Example:
        >>> from torch4dtree.data.synthetic import synthetic_plant
        >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=3, T=16).sequence for i in range(3)]
        >>> model = OrganModel(OrganSettings(bandwidth=1.0)).fit(train)
        >>> plants = model.sample(2, generator=torch.Generator().manual_seed(0))
        >>> len(plants), len(plants[0])
        (2, 3)
    """

    def __init__(self, settings: OrganSettings | None = None) -> None:
        super().__init__()
        if settings is not None and not isinstance(settings, OrganSettings):
            raise TypeError(f"settings must be an OrganSettings, got {type(settings).__name__}")
        self.settings = settings if settings is not None else OrganSettings()
        self.keys: list[tuple[int, ...]] = []
        f64, long = torch.float64, torch.long
        for name, dtype in (("key_parent", long), ("key_condition", long), ("record", long), ("log_length", f64),
                            ("shape", f64), ("growth", f64), ("s", f64), ("azimuth", f64), ("parent_azimuth", f64),
                            ("summary", f64), ("ages", f64)):
            self.register_buffer(name, torch.zeros(0, dtype=dtype))
        self.register_buffer("time_start", torch.tensor(0.0, dtype=f64))
        self.register_buffer("duration", torch.tensor(1.0, dtype=f64))
        self.report_: dict[str, Any] = {}

    # ------------------------------------------------------------------------ state
    def get_extra_state(self) -> dict[str, Any]:
        return {"version": 1, "keys": [list(k) for k in self.keys], "report": self.report_}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("version") != 1:
            raise OrganModelError("not an OrganModel state")
        self.keys = [tuple(int(r) for r in k) for k in state["keys"]]
        self.report_ = dict(state.get("report", {}))

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        # the buffers' shapes depend on the training plants: take them from the state first
        for name in list(self._buffers):
            if name in state_dict:
                self._buffers[name] = torch.empty_like(state_dict[name])
        return super().load_state_dict(state_dict, strict, assign)

    def save(self, path: str | Path, config: dict[str, Any] | None = None, overwrite: bool = False) -> str:
        """Write a checkpoint (:func:`torch4dtree.model.save_model`; :func:`torch4dtree.model.load` reads it)."""
        from .checkpoint import save_model

        return str(save_model(self, path, config, overwrite=overwrite))

    @property
    def is_fitted(self) -> bool:
        return len(self.keys) > 0

    def times(self) -> Tensor:
        """``(n_ages,)`` the generated plants' times in data units (the training plants' mean start and span)."""
        return self.time_start + self.ages * self.duration

    # ------------------------------------------------------------------------ fit
    def fit(self, sequences: Sequence[TreeSequence]) -> OrganModel:
        """Fit on ``N >= 2`` 4D trees: register each within itself, tabulate its organs, fit the latent. Returns
        ``self``."""
        import time

        sequences = list(sequences)
        if len(sequences) < 2:
            raise OrganModelError(f"fit needs at least 2 plants, got {len(sequences)}")
        t0 = time.perf_counter()
        n_ages = self.settings.n_ages or int(torch.tensor([len(s) for s in sequences]).median())
        table = organ_table(sequences, max(n_ages, 2), self.settings.registration)
        P, K = len(sequences), len(table.keys)
        record = torch.full((P, K), -1, dtype=torch.long)
        record[table.plant, table.key] = torch.arange(len(table.key))
        condition = torch.full((K,), -1, dtype=torch.long)
        index = {k: i for i, k in enumerate(table.keys)}
        for i, k in enumerate(table.keys):
            if k:
                condition[i] = index[k[:-1] + (k[-1] - 1,)] if k[-1] > 0 else index[k[:-1]]
        summary = table.summary
        self.keys = table.keys
        self.key_parent, self.key_condition, self.record = table.key_parent, condition, record
        self.log_length = table.log_length
        self.shape, self.growth, self.s = table.shape, table.growth, table.s
        self.azimuth, self.parent_azimuth = table.azimuth, table.parent_azimuth
        self.summary, self.ages = summary, table.ages
        starts = torch.tensor([float(s.times[0]) for s in sequences], dtype=torch.float64)
        spans = torch.tensor([float(s.times[-1] - s.times[0]) for s in sequences], dtype=torch.float64)
        self.time_start, self.duration = starts.mean(), spans.mean().clamp_min(1e-12)
        self.report_ = {"plants": P, "keys": K, "organs": len(table.key), "ages": len(table.ages),
                        "seconds": time.perf_counter() - t0}
        return self

    def check_fitted(self) -> None:
        """Raise :class:`OrganModelError` unless the model is fitted (or loaded)."""
        if not self.is_fitted:
            raise OrganModelError("OrganModel is not fitted: call fit() or torch4dtree.model.load() a checkpoint")

    # ------------------------------------------------------------------------ sampling
    def sample_coefficients(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """``(n, 1)`` one seed per plant (a float64 integer below 2**31): :meth:`decode` grows plant ``i`` from it,
        so a plant is reproducible on its own."""
        self.check_fitted()
        return torch.randint(0, 2**31 - 1, (n, 1), generator=generator, dtype=torch.long).to(torch.float64)

    def decode(self, z: Tensor) -> list[TreeSequence]:
        """``z (B, 1)`` seeds (:meth:`sample_coefficients`) -> ``B`` 4D trees (``label`` = botanical key index)."""
        self.check_fitted()
        zz = z.reshape(-1)
        return [self._grow(torch.Generator().manual_seed(int(seed)), f"sample_{i:03d}") for i, seed in enumerate(zz)]

    def sample(self, n: int, generator: torch.Generator | None = None) -> list[TreeSequence]:
        """``n`` new 4D trees at :meth:`times`."""
        return self.decode(self.sample_coefficients(n, generator))

    def kernel_weights(self, latent: Tensor) -> Tensor:
        """``(LATENT,) -> (P,)`` the training plants' weights near a plant latent (sum 1)."""
        scale = self.summary.std(0).clamp_min(1e-9)
        d2 = ((latent - self.summary) / scale).square().sum(-1)
        w = torch.exp(-0.5 * d2 / self.settings.bandwidth ** 2)
        return w / w.sum() if w.sum() > 0 else torch.full_like(w, 1 / len(w))

    def _latent(self, g: torch.Generator) -> Tensor:
        """A plant latent from the training plants' kernel density: one of them, moved by ``bandwidth`` standard
        deviations of Gaussian noise (truncated at ``c``), so every training plant is as likely a neighbour."""
        plant = int(torch.randint(0, len(self.summary), (), generator=g))
        eps = torch.randn(LATENT, generator=g, dtype=torch.float64).clamp(-self.settings.c, self.settings.c)
        return self.summary[plant] + self.settings.bandwidth * self.summary.std(0) * eps

    def _grow(self, g: torch.Generator, name: str) -> TreeSequence:
        """One plant: latent, then organs key by key (topology, donors, sizes, rotations), then its frames."""
        w = self.kernel_weights(self._latent(g))
        has = self.record >= 0  # (P, K)
        K = len(self.keys)
        chosen = torch.full((K,), -1, dtype=torch.long)  # the training organ each present key copies
        log_len = torch.zeros(K, dtype=torch.float64)
        turn = torch.zeros(K, dtype=torch.float64)  # rotation about the vertical of each organ
        donor_of = torch.full((K,), -1, dtype=torch.long)
        s_of: dict[int, Tensor] = {}  # each organ's attachment per age
        for k in range(K):
            cond = int(self.key_condition[k])
            if k == 0:
                donor = int(torch.multinomial(w, 1, generator=g))
            else:
                if chosen[cond] < 0:
                    continue
                donor = int(donor_of[cond])
                if float(torch.rand((), generator=g, dtype=torch.float64)) >= self.settings.persistence:
                    # switch: a plant near the latent among those that have the organ this one follows
                    donor = int(torch.multinomial(torch.where(has[:, cond], w, torch.zeros_like(w)), 1, generator=g))
                if not has[donor, k]:
                    continue
            r = int(self.record[donor, k])
            chosen[k], donor_of[k] = r, donor
            s_of[k] = self.s[r]
            if k > 0 and self.keys[k][-1] > 0:  # organs sharing a node in their plant share it here too
                before = int(self.record[donor, cond])
                if before >= 0:
                    same = (self.s[r] - self.s[before]).abs() < SAME_NODE
                    s_of[k] = torch.where(same, s_of[cond], self.s[r])
            noise = float(torch.randn((), generator=g, dtype=torch.float64))
            log_len[k] = self.log_length[r] + self.settings.jitter * noise
            if k == 0:
                turn[k] = 2 * math.pi * float(torch.rand((), generator=g, dtype=torch.float64))
            else:
                parent = int(self.key_parent[k])
                parent_az = self.azimuth[chosen[parent]] + turn[parent]
                turn[k] = parent_az - self.parent_azimuth[r]
        return self._frames(chosen, log_len.exp(), turn, s_of, name)

    def _frames(self, chosen: Tensor, length: Tensor, turn: Tensor, s_of: dict[int, Tensor], name: str
                ) -> TreeSequence:
        """The frames of a plant given its organs: each at ``length x growth(age)``, parents before children."""
        present = [k for k in range(len(self.keys)) if chosen[k] >= 0]
        sizes = carry_parents({k: length[k] * self.growth[chosen[k]] for k in present}, self.key_parent)
        shapes = {k: rotate_about_up(self.shape[chosen[k]], turn[k]) for k in present}
        return assemble_frames(sizes, shapes, {k: s_of[k] for k in present}, self.key_parent,
                               self.times().clone(), name)


def carry_parents(sizes: dict[int, Tensor], key_parent: Tensor) -> dict[int, Tensor]:
    """Organ sizes ``sizes[k] (G,)`` (0: absent) with every parent present wherever one of its children is: before
    it appears at its first size, after it was last seen at its last. Organs copied from different training plants
    keep their own timing, and a child whose parent's plant had not grown (or had lost) that parent yet would be
    left out of the frame; returns a new dict (keys in ``sizes`` are parents before children, ``key_parent`` as in
    :func:`assemble_frames`).

    Example:
        >>> out = carry_parents({0: torch.tensor([1.0, 2.0, 3.0]), 1: torch.tensor([0.0, 2.0, 0.0]),
        ...                      2: torch.tensor([1.0, 1.0, 1.0])}, torch.tensor([-1, 0, 1]))
        >>> out[1].tolist()
        [2.0, 2.0, 2.0]
    """
    out = dict(sizes)
    for k in sorted(out, reverse=True):  # children before parents: a carried child carries its parent
        if k == 0:
            continue
        parent = int(key_parent[k])
        size, need = out[parent], out[k] > 0
        seen = torch.nonzero(size > 0).reshape(-1)
        if len(seen) == 0 or not bool((need & (size <= 0)).any()):
            continue
        held = torch.cummax(size, 0).values  # its last size after it was last seen
        held = torch.where(held > 0, held, size[seen[0]])  # its first size before it appears
        out[parent] = torch.where(need & (size <= 0), held, size)
    return out


def assemble_frames(sizes: dict[int, Tensor], shapes: dict[int, Tensor], s: dict[int, Tensor], key_parent: Tensor,
                    times: Tensor, name: str) -> TreeSequence:
    """A 4D tree from its organs: organ ``k`` (key ``0`` the main branch, parents in ``key_parent``) has length
    ``sizes[k] (G,)`` (0: absent), unit-length shapes ``shapes[k] (G, T, d)`` and attachment ``s[k] (G,)`` at each of
    the ``G`` frames (``times``). An organ shorter than :data:`MIN_LENGTH` of the final main branch, or whose parent
    is absent, is left out of that frame; the main branch is always there (at least that long).

    Example:
        >>> up = torch.linspace(0, 1, 4)[:, None] * torch.tensor([0.0, 0.0, 1.0])  # a unit vertical segment
        >>> side = torch.linspace(0, 1, 4)[:, None] * torch.tensor([1.0, 0.0, 0.0])
        >>> plant = assemble_frames({0: torch.tensor([1.0, 2.0]), 1: torch.tensor([0.0, 0.5])},
        ...                         {0: up.expand(2, 4, 3), 1: side.expand(2, 4, 3)},
        ...                         {0: torch.zeros(2), 1: torch.full((2,), 0.5)}, torch.tensor([-1, 0]),
        ...                         torch.tensor([0.0, 1.0]), "two frames")
        >>> plant.frames.num_branches.tolist(), plant.frames.points[-1, 0].round(decimals=4).tolist()
        ([1, 2], [0.0, 0.0, 1.0])
    """
    present = sorted(sizes)
    children: dict[int, list[int]] = {k: [] for k in present}
    for k in present[1:]:
        children[int(key_parent[k])].append(k)
    floor = MIN_LENGTH * float(sizes[0].max())
    frames = []
    for j in range(len(times)):
        size = {k: float(sizes[k][j]) for k in present}
        size[0] = max(size[0], floor)
        points: list[Tensor] = []
        parent: list[int] = []
        s_j: list[float] = []
        label: list[int] = []
        stack = [(0, -1)]
        while stack:
            k, p = stack.pop()
            if size[k] < floor:
                continue
            start = (interpolate_curve(points[p][None], s[k][j].reshape(1, 1))[0, 0] if p >= 0
                     else torch.zeros(shapes[k].shape[-1], dtype=torch.float64))
            me = len(points)
            points.append(start + size[k] * shapes[k][j])
            parent.append(p)
            s_j.append(float(s[k][j]) if p >= 0 else 0.0)
            label.append(k)
            kids = sorted(children[k], key=lambda c: float(s[c][j]))  # depth-first, children by s
            stack.extend((c, me) for c in reversed(kids))
        frames.append(Trees(torch.stack(points), torch.tensor(parent), torch.tensor(s_j, dtype=torch.float64),
                            torch.tensor([len(points)]), torch.tensor(label)))
    return TreeSequence(Trees.cat(frames), times, name)
