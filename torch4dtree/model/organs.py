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
  follows with probability ``persistence``, else one drawn with Gaussian kernel weights near ``z`` (in standard
  deviations: ``bandwidth``, widened on few training plants so a sample draws on several,
  :meth:`OrganModel.donor_bandwidth`) among the plants that have that previous organ. The organ exists if that plant
  has it (so topology is conditional on the parent and the previous sibling), and takes its log length (plus
  ``jitter``, kept within the lengths of the training organs standing in for it), its unit-length shapes over age,
  its monotone growth curve and its attachment; the plant stands as its first donor stands (its orientation about
  the vertical), and a copied organ keeps its azimuth relative to its parent.
  Size is apart from shape, so nothing is averaged into a stub; organs grow as the training organs grow, and vanish
  only where those did.

It is a kernel (nonparametric) conditional model: the fitted buffers hold the training organs. Samples mix organs of
different plants, so they are new plants, not copies (benchmarks/bench_generative.py measures both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from ..curves.srvf import interpolate_curve
from ..settings import OrganSettings
from ..trees.structures import Trees, TreeSequence
from .donors import effective_donors, latent_weights, pick_donors, widened_bandwidth
from .organ_table import UP, OrganLinks, organ_links, organ_table

__all__ = ["OrganModel", "OrganModelError", "PlantDraw", "assemble_batch", "assemble_frames", "carry_parents",
           "effective_donors", "latent_weights", "pick_donors", "rotate_about_up"]

# the plant latent's features: log total length at the last age, at the middle age, log(1 + organs at the last age)
LATENT = 3
# keep a sampled organ in a frame when it is at least this share of its plant's final main-branch length (a shorter
# one would be a zero-length branch once written)
MIN_LENGTH = 1e-3
# plants grown together by OrganModel.decode (bounds the memory of a chunk's organ curves)
DECODE_CHUNK = 64
# most botanical keys a sample can take (OrganModel.sample_keys): deep hierarchies with many children per organ would
# otherwise open keys exponentially in their depth (five Pheno4D tomatoes: not done in 5 min); keys open parents
# first, so the last ranks of the deepest organs are the ones left out
MAX_SAMPLE_KEYS = 50_000


class OrganModelError(ValueError):
    """An :class:`OrganModel` used before fitting, fitted on too few plants, or given a state that is not its own."""


def rotate_about_up(x: Tensor, angle: Tensor | float) -> Tensor:
    """Rotate points ``(..., d)`` about the vertical axis by ``angle`` radians (a number, or a tensor that broadcasts
    against ``x[..., 0]``).

    Example:
        >>> rotate_about_up(torch.tensor([[1.0, 0.0, 2.0]]), math.pi / 2).round().tolist()
        [[0.0, 1.0, 2.0]]
    """
    if isinstance(angle, Tensor) and angle.numel() > 1:
        c, s = torch.cos(angle), torch.sin(angle)
    else:
        c, s = math.cos(float(angle)), math.sin(float(angle))
    h = [i for i in range(x.shape[-1]) if i != UP][:2]
    out = x.clone()
    out[..., h[0]] = c * x[..., h[0]] - s * x[..., h[1]]
    out[..., h[1]] = s * x[..., h[0]] + c * x[..., h[1]]
    return out


class PlantDraw(NamedTuple):
    """The organs of ``B`` sampled plants over the ``K`` keys of :meth:`OrganModel.sample_keys`
    (:meth:`OrganModel.grow`)."""

    chosen: Tensor
    """``(B, K)`` long: the training organ each key copies (a row of the fitted buffers; -1: absent)."""
    length: Tensor
    """``(B, K)`` the organ's largest length, in data units (0: absent)."""
    turn: Tensor
    """``(B, K)`` its rotation about the vertical, radians."""
    s_of: Tensor
    """``(B, K, G)`` its attachment on its parent at each age."""


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
        self._links: OrganLinks | None = None
        self._reach: tuple[list[tuple[int, ...]], Tensor] | None = None
        self._plan: tuple[list[list[int]], np.ndarray, np.ndarray, np.ndarray] | None = None
        self._bandwidth: float | None = None

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
        self._links = self._reach = self._plan = self._bandwidth = None
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
        ``self``; ``report_`` holds the counts, the kernel width in use (:meth:`donor_bandwidth`) and the time."""
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
        self._links = self._reach = self._plan = self._bandwidth = None
        starts = torch.tensor([float(s.times[0]) for s in sequences], dtype=torch.float64)
        spans = torch.tensor([float(s.times[-1] - s.times[0]) for s in sequences], dtype=torch.float64)
        self.time_start, self.duration = starts.mean(), spans.mean().clamp_min(1e-12)
        self.report_ = {"plants": P, "keys": K, "organs": len(table.key), "ages": len(table.ages),
                        "bandwidth": self.donor_bandwidth(), "seconds": time.perf_counter() - t0}
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
        """``z (B, 1)`` seeds (:meth:`sample_coefficients`) -> ``B`` 4D trees (``label`` = index of the organ's
        botanical key in :meth:`sample_keys`).

        Plants are grown together, :data:`DECODE_CHUNK` at a time (one tensor operation per key for the whole chunk,
        not per plant); each draws its random numbers from its own seed, so a plant does not depend on the others.
        The work is many mid-sized tensor operations, so it runs on one intra-op thread (a second costs more CPU in
        synchronisation than it saves).
        """
        self.check_fitted()
        seeds = [int(x) for x in z.reshape(-1)]
        times = self.times().clone()
        out: list[TreeSequence] = []
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for lo in range(0, len(seeds), DECODE_CHUNK):
                chunk = seeds[lo:lo + DECODE_CHUNK]
                chosen, length, turn, s_of = self.grow(chunk)
                names = [f"sample_{i:03d}" for i in range(lo, lo + len(chunk))]
                out += self._frames(chosen, length, turn, s_of, times, names)
        finally:
            torch.set_num_threads(threads)
        return out

    def sample(self, n: int, generator: torch.Generator | None = None) -> list[TreeSequence]:
        """``n`` new 4D trees at :meth:`times`."""
        return self.decode(self.sample_coefficients(n, generator))

    def donor_bandwidth(self) -> float:
        """The latent kernel's width in standard deviations: the least one, at or above ``settings.bandwidth``, that
        keeps on average :data:`~torch4dtree.model.donors.MIN_DONORS` effective donors at the training plants' own
        latents (:func:`~torch4dtree.model.donors.widened_bandwidth`): on a few plants the kernel widens, so a
        sample's organs are drawn from several plants instead of copying the one its latent was drawn around.

        Example:
            >>> m = OrganModel(OrganSettings(bandwidth=0.5))
            >>> m.summary = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
            >>> m.keys = [()]
            >>> round(m.donor_bandwidth(), 2), round(float(effective_donors(m.summary, m.donor_bandwidth())), 2)
            (1.65, 3.0)
        """
        self.check_fitted()
        if self._bandwidth is None:
            self._bandwidth = widened_bandwidth(self.summary, float(self.settings.bandwidth))
        return self._bandwidth

    def kernel_weights(self, latent: Tensor) -> Tensor:
        """``(..., LATENT) -> (..., P)`` the training plants' weights near plant latents (sum 1), with the kernel
        width :meth:`donor_bandwidth`."""
        return latent_weights(self.summary, latent, self.donor_bandwidth())

    def _draws(self, seeds: list[int]) -> tuple[Tensor, Tensor]:
        """Each plant's random numbers from its own seed: uniforms ``(B, 3 + 2K)`` (latent's plant, first donor,
        one unused, then per key of :meth:`sample_keys` the switch and the donor's pick) and standard normals
        ``(B, LATENT + K)`` (latent noise, then per key the length jitter)."""
        K = len(self.sample_keys()[0])
        u, n = [], []
        for seed in seeds:
            g = torch.Generator().manual_seed(seed)
            u.append(torch.rand(3 + 2 * K, generator=g, dtype=torch.float64))
            n.append(torch.randn(LATENT + K, generator=g, dtype=torch.float64))
        return torch.stack(u), torch.stack(n)

    def links(self) -> OrganLinks:
        """The fitted organs' :class:`~torch4dtree.model.organ_table.OrganLinks` (built once from the buffers)."""
        self.check_fitted()
        if self._links is None:
            self._links = organ_links(self.record, self.key_parent, self.s, self.growth, self.log_length)
        return self._links

    def length_range(self) -> tuple[Tensor, Tensor]:
        """``(R,)`` twice: per training organ the least and the largest log length among the organs that stand in
        for it in the training plants (:attr:`OrganLinks.equivalent`, itself included): a sampled organ's length
        jitter stays within them, so no organ grows longer than any training plant's organ at its place.

        Example:
            >>> from torch4dtree.data.synthetic import synthetic_plant
            >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=3, T=16).sequence for i in range(3)]
            >>> model = OrganModel().fit(train)
            >>> lo, hi = model.length_range()
            >>> bool((lo <= model.log_length).all() and (model.log_length <= hi).all())
            True
        """
        eq = torch.from_numpy(self.links().equivalent)
        here = eq >= 0
        ll = self.log_length[eq.clamp(min=0)]
        own = self.log_length[:, None]
        lo = torch.where(here, ll, torch.inf).amin(1).minimum(own[:, 0])
        hi = torch.where(here, ll, -torch.inf).amax(1).maximum(own[:, 0])
        return lo, hi

    def sample_keys(self) -> tuple[list[tuple[int, ...]], Tensor]:
        """The botanical keys a sample's organs can take and each one's parent key ``(K',)``: the training keys
        (:attr:`keys`, in order) then, parents first, every further ``k``-th child of a key up to the most children
        an organ at that depth has in the training plants (a sample reads a parent's children along a training
        organ that may sit at another rank), at most :data:`MAX_SAMPLE_KEYS` in all. A sample's ``label`` indexes
        this list."""
        self.check_fitted()
        if self._reach is None:
            links = self.links()
            depth = np.array([len(k) for k in self.keys])
            organ_depth = np.zeros(len(links.plant), dtype=np.int64)
            organ_depth[self.record[self.record >= 0].numpy()] = depth[
                torch.nonzero(self.record >= 0, as_tuple=True)[1].numpy()]
            most = np.zeros(int(depth.max()) + 1, dtype=np.int64)
            np.maximum.at(most, organ_depth, links.n_kids)
            keys = list(self.keys)
            index = {k: i for i, k in enumerate(keys)}
            parent = self.key_parent.tolist()
            j = 0
            while j < len(keys):  # parents first: a key's children are appended after it
                key = keys[j]
                for r in range(int(most[len(key)])):
                    if len(keys) >= MAX_SAMPLE_KEYS:
                        break
                    child = key + (r,)
                    if child not in index:
                        index[child] = len(keys)
                        keys.append(child)
                        parent.append(j)
                j += 1
            self._reach = (keys, torch.tensor(parent, dtype=torch.long))
        return self._reach

    def grow(self, seeds: list[int]) -> PlantDraw:
        """The organs of plants from their seeds (:meth:`sample_coefficients`; module doc): latent, then organs
        parent by parent (topology, donors, sizes, rotations), before they are written as frames (:meth:`decode`).
        Returns a :class:`PlantDraw` over the keys of :meth:`sample_keys`: which training organ each sample organ
        copies tells, for instance, how much of a sample comes from one training plant.

        Example:
            >>> from torch4dtree.data.synthetic import synthetic_plant
            >>> train = [synthetic_plant(kind="bean", seed=i, n_frames=3, T=16).sequence for i in range(3)]
            >>> model = OrganModel().fit(train)
            >>> draw = model.grow([0, 1])
            >>> plants = model.links().plant[draw.chosen[0][draw.chosen[0] >= 0].numpy()]  # donor plant per organ
            >>> draw.chosen.shape == draw.length.shape == (2, len(model.sample_keys()[0])), len(plants) > 0
            (True, True)
        """
        u, noise = self._draws(seeds)
        P = len(self.summary)
        plant = (u[:, 0] * P).long().clamp(max=P - 1)
        eps = noise[:, :LATENT].clamp(-self.settings.c, self.settings.c)
        w = self.kernel_weights(self.summary[plant] + self.donor_bandwidth() * self.summary.std(0) * eps)  # (B, P)
        chosen = np.full((len(seeds), len(self.sample_keys()[0])), -1, dtype=np.int64)
        turn = np.zeros(chosen.shape)
        links, walk = self.links(), self._walk_plan()
        for b in range(len(seeds)):
            self._walk(u[b].numpy(), w[b].numpy(), links, walk, chosen[b], turn[b])
        chosen_t = torch.from_numpy(chosen)
        present = chosen_t >= 0
        rr = chosen_t.clamp(min=0)
        log_len = self.log_length[rr] + self.settings.jitter * noise[:, LATENT:]
        lo, hi = self.length_range()  # the jitter stays within what the organs standing in for this one span
        log_len = torch.minimum(torch.maximum(log_len, lo[rr]), hi[rr])
        s_of = torch.where(present[..., None], self.s[rr], 0.0)
        return PlantDraw(chosen_t, torch.where(present, log_len.exp(), 0.0), torch.from_numpy(turn), s_of)

    def _walk_plan(self) -> tuple[list[list[int]], np.ndarray, np.ndarray, np.ndarray]:
        """Per key (:meth:`sample_keys`) its children keys in rank order; the records, azimuths and parent
        azimuths as arrays (built once: every chunk of :meth:`decode` walks the same plan)."""
        if self._plan is None:
            keys, key_parent = self.sample_keys()
            children: list[list[int]] = [[] for _ in keys]
            for k, p in enumerate(key_parent.tolist()):
                if p >= 0:
                    children[p].append(k)  # siblings in rank order
            self._plan = children, self.record.numpy(), self.azimuth.numpy(), self.parent_azimuth.numpy()
        return self._plan

    def _walk(self, u: np.ndarray, w: np.ndarray, links: OrganLinks,
              plan: tuple[list[list[int]], np.ndarray, np.ndarray, np.ndarray], chosen: np.ndarray,
              turn: np.ndarray) -> None:
        """One plant's organs (module doc), written into its rows ``chosen (K,)`` and ``turn (K,)``: from its
        uniforms ``u`` (:meth:`_draws`) and kernel weights ``w (P,)``. Each organ's children are read along one
        training organ's children; a switch moves to the organ standing in for it in another plant
        (:class:`~torch4dtree.model.organ_table.OrganLinks`) and goes on after the child that stands in for the last
        one taken, so switching neither repeats nor skips an organ; it waits for a landmark to match by and for the
        end of a node (the organs of one node, an opposite pair, come from one plant: :attr:`OrganLinks.same_node`)."""
        children, record, az, parent_az = plan
        K = len(children)
        persistence = self.settings.persistence
        first = int(pick_donors(torch.from_numpy(w)[None], torch.tensor([u[1]]))[0])
        # the plant keeps its first donor's orientation about the vertical (the training plants' orientations are
        # part of what the ground metric compares, which registers plants without rotation); ``u[2]`` is unused
        chosen[0], turn[0] = record[first, 0], 0.0
        todo = [0]
        for k in todo:  # parents first: only the keys taken
            source = int(chosen[k])
            if not children[k]:
                continue
            here = az[source] + turn[k]
            standing = links.equivalent[source]  # (P,)
            # before the first child any stand-in (a childless one gives none, as often as the stand-ins do);
            # later only stand-ins with children, so a switch does not end the children early
            start = np.cumsum(np.where(standing >= 0, w, 0.0))
            later = np.cumsum(np.where((standing >= 0) & (links.n_kids[standing] > 0), w, 0.0))
            cur, i, last = source, 0, -1
            for c in children[k]:
                cdf = start if last < 0 else later
                # a switch waits for a landmark and for the end of a node (its organs come from one plant)
                at_node = last >= 0 and i < links.n_kids[cur] and bool(links.same_node[links.kids[cur, i]])
                if u[3 + c] >= persistence and cdf[-1] > 0 and (last < 0 or (links.landmark[last] and not at_node)):
                    q = min(int(np.searchsorted(cdf, u[3 + K + c] * cdf[-1], side="right")), len(w) - 1)
                    if int(standing[q]) != cur:
                        cur = int(standing[q])
                        i = links.node_start(cur, links.nearest_kid(last, cur) + 1) if last >= 0 else 0
                if i >= links.n_kids[cur] or i < 0:
                    break
                last = int(links.kids[cur, i])
                i += 1
                chosen[c], turn[c] = last, here - parent_az[last]
                todo.append(c)

    def _frames(self, chosen: Tensor, length: Tensor, turn: Tensor, s_of: Tensor, times: Tensor, names: list[str]
                ) -> list[TreeSequence]:
        """The frames of plants given their organs (:meth:`grow`): each at ``length x growth(age)``, every parent
        present wherever one of its children is (:func:`carry_parents`)."""
        b, k = torch.nonzero(chosen >= 0, as_tuple=True)  # plant-major, keys in order: parents first
        r = chosen[b, k]
        keys, key_parent = self.sample_keys()
        used = torch.unique(k)  # the keys these plants reach and their ancestors: a few of sample_keys' many
        while True:
            up = key_parent[used]
            wider = torch.unique(torch.cat([used, up[up >= 0]]))
            if len(wider) == len(used):
                break
            used = wider
        local = torch.full((len(keys),), -1, dtype=torch.long)
        local[used] = torch.arange(len(used))
        up = key_parent[used]
        sizes = torch.zeros(chosen.shape[0], len(used), len(self.ages), dtype=torch.float64)
        sizes[b, local[k]] = length[b, k, None] * self.growth[r]
        sizes = carry_parents(sizes, torch.where(up >= 0, local[up.clamp(min=0)], -1),
                              [len(keys[i]) for i in used.tolist()])
        shapes = rotate_about_up(self.shape[r], turn[b, k][:, None, None])
        return assemble_batch(b, k, key_parent, sizes[b, local[k]], shapes, s_of[b, k], times, names)


def carry_parents(sizes: Tensor, key_parent: Tensor, depth: Sequence[int]) -> Tensor:
    """Organ sizes ``(B, K, G)`` (0: absent) with every parent present wherever one of its children is: at its last
    size after it was last seen, at its first size before it appeared. Organs copied from different training plants
    keep their own timing, so a child whose parent's plant had lost that parent (a tracking gap, a shed organ), or
    grew it later, would otherwise be left out of the frame (a sample would lag the plants it copies).
    ``key_parent (K,)`` as in :func:`assemble_frames`, ``depth`` each key's depth (0: the main branch). Returns a new
    tensor.

    Example:
        >>> sizes = torch.tensor([[[1.0, 2.0, 3.0], [0.0, 2.0, 0.0], [1.0, 1.0, 1.0]]])
        >>> carry_parents(sizes, torch.tensor([-1, 0, 1]), [0, 1, 2])[0, 1].tolist()
        [2.0, 2.0, 2.0]
    """
    depth_t = torch.as_tensor(list(depth), dtype=torch.long)
    out = sizes.clone()
    for d in range(max(depth, default=0), 0, -1):  # deepest first: a carried child carries its parent
        children = torch.nonzero(depth_t == d).reshape(-1)
        parents, slot = torch.unique(key_parent[children], return_inverse=True)  # only these columns can change
        here = out[:, parents]
        need = torch.zeros_like(here).index_add_(1, slot, (out[:, children] > 0).to(out.dtype)) > 0
        fill = need & (here <= 0)
        if bool(fill.any()):
            held = torch.cummax(here, 2).values  # the last size after it was last seen (0 before it appears)
            first = torch.where(here > 0, here, torch.inf).min(2, keepdim=True).values  # its first (smallest) size
            first = torch.where(torch.isfinite(first), first, 0.0)  # never there at all: stays out
            out[:, parents] = torch.where(fill, torch.where(held > 0, held, first), here)
    return out


def assemble_batch(plant: Tensor, key: Tensor, key_parent: Tensor, size: Tensor, shape: Tensor, s: Tensor,
                   times: Tensor, names: Sequence[str]) -> list[TreeSequence]:
    """4D trees from the organs of ``B = len(names)`` plants at the ``G`` frames ``times``: organ ``i`` (``N`` in
    all, each plant's main branch with ``key_parent[key[i]] = -1``) of plant ``plant[i]`` and key ``key[i]`` (its
    parent: the same plant's organ at ``key_parent[key[i]]``) has length ``size[i] (G,)`` (0: absent), unit-length
    shapes ``shape[i] (G, T, d)`` and attachment ``s[i] (G,)``. An organ shorter than :data:`MIN_LENGTH` of its
    plant's final main branch, or whose parent is left out, is left out of that frame; the main branch is always there
    (at least that long). Branches of a frame are in depth-first order, children by ``s`` then key; ``label`` is the
    key. All plants' organs are placed together, depth by depth.
    """
    B, G, N = len(names), len(times), len(key)
    row_of = torch.full((B, len(key_parent)), -1, dtype=torch.long)
    row_of[plant, key] = torch.arange(N)
    kp = key_parent[key]
    main = kp < 0
    parent_row = torch.where(main, -1, row_of[plant, kp.clamp(min=0)])
    depth = torch.zeros(N, dtype=torch.long)
    up = parent_row.clone()
    while bool((up >= 0).any()):
        depth += (up >= 0).long()
        up = torch.where(up >= 0, parent_row[up.clamp(min=0)], -1)
    floor = torch.zeros(B, dtype=size.dtype)
    floor[plant[main]] = MIN_LENGTH * size[main].max(1).values
    size = size.clone()
    size[main] = torch.maximum(size[main], floor[plant[main], None])
    keep = (size >= floor[plant][:, None]) & (main | (parent_row >= 0))[:, None]  # (N, G)
    points = size[..., None, None] * shape  # (N, G, T, d), each organ from its own base
    D = int(depth.max())
    for d in range(1, D + 1):
        rows = torch.nonzero(depth == d).reshape(-1)
        pr = parent_row[rows]
        keep[rows] &= keep[pr]
        points[rows] += interpolate_curve(points[pr], s[rows][..., None])
    # depth-first order: sort by plant, frame, then (s, key) of the ancestor at each depth (-1 below an organ)
    anc = torch.full((N, D + 1), -1, dtype=torch.long)
    cur, level = torch.arange(N), depth.clone()
    for _ in range(D + 1):
        ok = level >= 0
        anc[ok, level[ok]] = cur[ok]
        cur = torch.where(ok & (cur >= 0), parent_row[cur.clamp(min=0)], -1)
        level -= 1
    er, ej = torch.nonzero(keep, as_tuple=True)
    columns = []
    for d in range(D, 0, -1):
        a = anc[er, d]
        columns += [torch.where(a >= 0, key[a.clamp(min=0)], -1).numpy(),
                    torch.where(a >= 0, s[a.clamp(min=0), ej], -1.0).numpy()]
    order = torch.from_numpy(np.lexsort(columns + [ej.numpy(), plant[er].numpy()]))
    er, ej = er[order], ej[order]
    group = plant[er] * G + ej
    counts = torch.bincount(group, minlength=B * G)
    local = torch.arange(len(er)) - (counts.cumsum(0) - counts)[group]
    pos = torch.full((N, G), -1, dtype=torch.long)
    pos[er, ej] = local
    is_main = main[er]
    parent_local = torch.where(is_main, -1, pos[parent_row[er].clamp(min=0), ej])
    s_out = torch.where(is_main, 0.0, s[er, ej])
    pts, labels = points[er, ej], key[er]
    per_plant = counts.reshape(B, G)
    bounds = [0] + per_plant.sum(1).cumsum(0).tolist()
    return [TreeSequence(Trees(pts[a:b], parent_local[a:b], s_out[a:b], per_plant[i], labels[a:b]),
                         times.clone(), names[i])
            for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]


def assemble_frames(sizes: dict[int, Tensor], shapes: dict[int, Tensor], s: dict[int, Tensor], key_parent: Tensor,
                    times: Tensor, name: str) -> TreeSequence:
    """A 4D tree from its organs: organ ``k`` (key ``0`` the main branch, parents in ``key_parent``) has length
    ``sizes[k] (G,)`` (0: absent), unit-length shapes ``shapes[k] (G, T, d)`` and attachment ``s[k] (G,)`` at each of
    the ``G`` frames (``times``). An organ shorter than :data:`MIN_LENGTH` of the final main branch, or whose parent
    is absent, is left out of that frame; the main branch is always there (at least that long). One plant of
    :func:`assemble_batch`.

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
    keys = sorted(sizes)
    key = torch.tensor(keys, dtype=torch.long)
    return assemble_batch(torch.zeros(len(keys), dtype=torch.long), key, key_parent,
                          torch.stack([sizes[k] for k in keys]).to(torch.float64),
                          torch.stack([shapes[k] for k in keys]), torch.stack([s[k] for k in keys]).to(torch.float64),
                          times, [name])[0]
