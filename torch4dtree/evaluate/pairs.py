"""Registrations several experiments share, computed once per evaluation and kept on the :class:`EvalData`.

Table 1 (4D rows) and Table 3 (a) both need the spatiotemporal registration of every pair of plants of a kind, and
every experiment on 4D trees needs each plant's within-sequence registration: these functions memoise them in
``data.cache`` so a report never registers the same thing twice.
"""

from __future__ import annotations

import itertools
import time
from typing import Any

from tqdm.auto import tqdm

from ..temporal import AlignedSequence, register4d, register_sequence
from ..temporal.spatiotemporal import SpatiotemporalRegistration
from .data import EvalData, EvalSettings

__all__ = ["aligned_sequence", "pair_seconds", "plant_pairs", "registered_pairs"]


def _cache(data: EvalData, key: str) -> dict[Any, Any]:
    return data.cache.setdefault(key, {})


def aligned_sequence(data: EvalData, name: str) -> AlignedSequence:
    """The within-sequence registration of plant ``name`` (the library's defaults: identities over time)."""
    cache = _cache(data, "aligned")
    if name not in cache:
        plant = next(p for p in data.plants if p.name == name)
        t0 = time.perf_counter()
        cache[name] = register_sequence(plant.sequence)
        _cache(data, "aligned_seconds")[name] = time.perf_counter() - t0
    return cache[name]


def pair_seconds(data: EvalData, ref: str, mov: str, reg: SpatiotemporalRegistration) -> float:
    """Wall time of one spatiotemporal registration from scratch: both within-sequence registrations (computed
    once per plant and shared) plus the pair's own stages."""
    within = _cache(data, "aligned_seconds")
    return within.get(ref, 0.0) + within.get(mov, 0.0) + sum(v for k, v in reg.seconds.items()
                                                             if k != "within_sequence")


def plant_pairs(data: EvalData, kind: str, settings: EvalSettings) -> list[tuple[str, str]]:
    """Every pair ``(reference, moving)`` of plants of ``kind`` in name order (``quick``: at most 2)."""
    names = [p.name for p in data.by_kind(kind)]
    pairs = list(itertools.combinations(names, 2))
    return pairs[:2] if settings.quick else pairs


def registered_pairs(data: EvalData, kind: str, settings: EvalSettings, progress: bool = False
                     ) -> list[tuple[str, str, SpatiotemporalRegistration]]:
    """:func:`~torch4dtree.temporal.register4d` of every pair of :func:`plant_pairs` (moving onto reference)."""
    cache = _cache(data, "register4d")
    pairs = plant_pairs(data, kind, settings)
    out = []
    for ref, mov in tqdm(pairs, desc=f"4D pairs ({kind})", unit="pair", disable=not progress):
        key = (ref, mov, settings.n_t, tuple(settings.lambdas), settings.rotation, settings.cross_positions,
               settings.cross_lp, settings.cross_order_tol)
        if key not in cache:
            cache[key] = register4d(aligned_sequence(data, ref), aligned_sequence(data, mov), settings.lambdas,
                                    settings.rotation, settings.n_t, cross=settings.cross_settings())
        out.append((ref, mov, cache[key]))
    return out
