"""Shared test helpers: paths to the real data and a random tree generator."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

# the real data lives beside the repository (../shared), or wherever TORCH4DTREE_PHENO4D points
PHENO4D = Path(os.environ.get("TORCH4DTREE_PHENO4D",
                              Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pheno4d"))


def smooth_curve(rng: np.random.Generator, n: int = 40, length: float = 10.0, start=None, direction=None) -> np.ndarray:
    """A smooth random 3D polyline of about ``length``, ``(n, 3)``."""
    direction = rng.normal(size=3) if direction is None else np.asarray(direction, float)
    direction /= np.linalg.norm(direction)
    bend = rng.normal(scale=0.6, size=(3, 3))
    t = np.linspace(0, 1, n)[:, None]
    pts = t * direction + (t**2) * bend[0] * 0.3 + np.sin(np.pi * t) * bend[1] * 0.2
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    pts = pts / seg * length
    return pts + (np.zeros(3) if start is None else np.asarray(start, float))


def random_tree_branches(rng: np.random.Generator, n_side: int = 4, depth: int = 2):
    """Random polylines and parents of one tree: a main branch, side branches, sub-branches.

    Children attach in the first 55% of their parent and are under 40% of its length, so the
    longest-path rule recovers this very hierarchy from the tree's skeleton.
    """
    main = smooth_curve(rng, 60, 30.0, start=np.zeros(3), direction=[0, 0, 1])
    branches, parents, lengths = [main], [-1], [30.0]
    frontier = [0]
    for _ in range(depth - 1):
        new = []
        for b in frontier:
            for _ in range(n_side):
                parent = branches[b]
                frac = np.concatenate([[0], np.linalg.norm(np.diff(parent, axis=0), axis=1).cumsum()]) / lengths[b]
                k = int(rng.choice(np.nonzero((frac > 0.1) & (frac < 0.55))[0]))
                length = lengths[b] * rng.uniform(0.25, 0.4)
                branches.append(smooth_curve(rng, 25, length, start=parent[k]))
                parents.append(b)
                lengths.append(length)
                new.append(len(branches) - 1)
        frontier = new[:2]
    return branches, parents


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


def pheno4d(*parts: str) -> Path:
    """A path in the Pheno4D data; skipped where the data is absent, but never in CI, where it must be."""
    path = PHENO4D.joinpath(*parts)
    if not path.exists():
        if os.environ.get("CI"):
            pytest.fail(f"real data not found at {path} (CI must have ../shared beside the repository)")
        pytest.skip(f"real data not found at {path}")
    return path


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels():
    """Compile (or load) the numba kernels once before any test: on a fresh clone the first registration
    otherwise prints the one-time compile notice inside whichever test happens to run first (and a test of
    one-line CLI errors then sees two lines)."""
    from torch4dtree.curves.dp_numba import warm_up

    warm_up()


@pytest.fixture(scope="session")
def synthetic_folder(tmp_path_factory):
    """``make(plants, seed, frames, kind="tomato")``: the dataset folder ``torch4dtree synth`` writes for those
    arguments, written once per session (tests read it, never write into it)."""
    from torch4dtree.data import run_synth

    folders: dict[tuple, Path] = {}

    def make(plants: int, seed: int, frames: int, kind: str = "tomato") -> Path:
        key = (kind, plants, seed, frames)
        if key not in folders:
            out = tmp_path_factory.mktemp("synth") / kind
            run_synth(kind=kind, plants=plants, seed=seed, out=str(out), frames=frames)
            folders[key] = out
        return folders[key]

    return make
