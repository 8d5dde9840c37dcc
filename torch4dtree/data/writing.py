"""Writing synthetic plants as a dataset folder (the layout of :mod:`torch4dtree.io.dataset`).

Layout written by :func:`write_dataset`::

    out/
      dataset.json              kind, seed, settings, label scheme and, per plant, the ground
                                truth: its seed, frame times, normalised times, biological times
                                and growth warp h on its grid
      tomato_00/
        times.json              {"day_000.swc": 0.0, "day_002.swc": 2.0, ...}
        day_000.swc             one SWC per frame: the frame's raw skeleton (nodes, parent links),
        ...                     each node's organ label in the type column
      tomato_01/ ...

The files hold skeletons, not trees: a reader derives the branch hierarchy as it would for any
SWC file. Read them back with ``read_dataset(out, LoadOptions(labels_from_type=True))``: with
the reader's default hierarchy rule this gives the trees and labels of
:attr:`SyntheticPlant.sequence` (for plants generated without ``hierarchy_kwargs``).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..io import write_text_safely
from ..io.dataset import TIMES_MANIFEST
from .labels import SPUR_LABEL
from .synthetic import SyntheticPlant, synthetic_dataset

DATASET_MANIFEST = "dataset.json"
FORMAT = "torch4dtree-synthetic"
FORMAT_VERSION = 2  # 2: frames are raw skeletons with organ labels (1: re-derived trees)

LABEL_SCHEME = (
    "organ label per node, base-100 digit pairs from the stem: 0 main stem; k (1..49) k-th leaf from the bottom "
    "(tomato: 1, 2 cotyledons; bean: 1, 2 primary leaves); 50+k side shoot from the axil of leaf k; S*100+i i-th "
    "leaf of shoot S; L*100+j leaflet j of leaf L (j = 2p-1 / 2p: left / right leaflet of pair p from the leaf "
    f"base); (L*100+j)*100+m lobe m of that leaflet; {SPUR_LABEL} skeletonisation spur (not an organ). A branch "
    "point carries its parent organ's label; the parent organ of a label is label // 100"
)


def write_skeleton_swc(
    path: str | Path, xyz: np.ndarray, parent: np.ndarray, labels: np.ndarray, overwrite: bool = False,
    comment: str = "",
) -> Path:
    """Write a skeleton graph as SWC: node ``i`` gets id ``i + 1``, ``labels`` (non-negative) go to the type column.

    Coordinates are written with 6 decimals (exact for the synthetic plants' 1e-4 mm grid).
    Refuses to replace a file unless ``overwrite``.

    Example:
        >>> import tempfile
        >>> xyz = np.array([[0.0, 0, 0], [0, 0, 5], [0, 0, 10], [4, 0, 8]])
        >>> path = write_skeleton_swc(Path(tempfile.mkdtemp()) / "plant.swc", xyz, [-1, 0, 1, 1], [0, 0, 0, 3])
        >>> path.read_text().splitlines()[-1]
        '4 3 4.000000 0.000000 8.000000 1.0 2'
    """
    xyz, parent, labels = np.asarray(xyz, dtype=np.float64), np.asarray(parent), np.asarray(labels)
    if (labels < 0).any():
        raise ValueError("SWC type labels must be non-negative")
    lines = [f"# {c}" for c in comment.splitlines()] if comment else []
    lines.append("# id type x y z radius parent (written by torch4dtree)")
    for i, (p, q, lab) in enumerate(zip(xyz.tolist(), parent.tolist(), labels.tolist())):
        lines.append(f"{i + 1} {int(lab)} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 1.0 {q + 1 if q >= 0 else -1}")
    return write_text_safely(Path(path), "\n".join(lines) + "\n", overwrite)


def frame_file_name(time: float, index: int) -> str:
    """``day_007.swc`` for a whole-number time, else ``frame_03.swc`` (the manifest holds the time).

    Example:
        >>> frame_file_name(7.0, 2), frame_file_name(7.5, 3)
        ('day_007.swc', 'frame_03.swc')
    """
    return f"day_{int(time):03d}.swc" if float(time).is_integer() and time >= 0 else f"frame_{index:02d}.swc"


def _plant_folder_names(plants: Sequence[SyntheticPlant]) -> list[str]:
    names = [p.name or f"{p.kind}_{i:02d}" for i, p in enumerate(plants)]
    if len(set(names)) != len(names):  # plants generated one by one may share default names
        names = [f"{p.kind}_{i:02d}" for i, p in enumerate(plants)]
    return names


def _remove_old_plants(out: Path, keep: set[str]) -> None:
    """With ``overwrite``: delete plant folders an earlier synthetic dataset.json listed and we do not rewrite.

    Only folders named in our own manifest are touched, and in them only their frames and times
    manifest, so user files are never removed.
    """
    manifest = out / DATASET_MANIFEST
    try:
        old = json.loads(manifest.read_text())
        if old.get("format") != FORMAT:
            return
        old_names = [p["folder"] for p in old.get("plants", [])]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return
    for name in old_names:
        folder = out / str(name)
        if name in keep or not folder.is_dir() or folder.resolve().parent != out.resolve():
            continue
        for f in folder.iterdir():
            if f.is_file() and (f.suffix.lower() == ".swc" or f.name == TIMES_MANIFEST):
                f.unlink()
        if not any(folder.iterdir()):
            shutil.rmtree(folder)


def write_dataset(plants: Sequence[SyntheticPlant], out_dir: str | Path, overwrite: bool = False) -> Path:
    """Write plants as a dataset folder with their ground truth (layout in the module doc).

    Refuses (``FileExistsError``) when ``out_dir`` exists and is not empty, unless ``overwrite``;
    then files of the same names are replaced and plant folders of an earlier synthetic dataset
    that are not rewritten lose their frames. Returns ``out_dir``.

    Example:
        >>> import tempfile
        >>> from torch4dtree.data import synthetic_dataset
        >>> out = write_dataset(synthetic_dataset("tomato", plants=2, n_frames=2, T=8), Path(tempfile.mkdtemp()) / "ds")
        >>> sorted(p.name for p in out.iterdir())
        ['dataset.json', 'tomato_00', 'tomato_01']
    """
    if not plants:
        raise ValueError("no plants to write")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out} exists and is not empty; pass overwrite=True (--overwrite) to write into it")
    names = _plant_folder_names(plants)
    if overwrite and out.is_dir():
        _remove_old_plants(out, set(names))
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for name, plant in zip(names, plants):
        folder = out / name
        times = plant.times.tolist()
        files = [frame_file_name(t, j) for j, t in enumerate(times)]
        if len(set(files)) != len(files):
            files = [f"frame_{j:02d}.swc" for j in range(len(times))]
        if len(plant.skeletons) != len(times):
            raise ValueError(f"plant {name} has {len(plant.skeletons)} skeletons for {len(times)} frames")
        for j, ((xyz, parent, organ), fname) in enumerate(zip(plant.skeletons, files)):
            comment = (f"synthetic {plant.kind} plant {name} (seed {plant.seed}), frame {j}, time {times[j]:g}\n"
                       "raw skeleton; type = organ label (see dataset.json)")
            write_skeleton_swc(folder / fname, xyz, parent, organ, overwrite=overwrite, comment=comment)
        manifest = {f: float(t) for f, t in zip(files, times)}
        write_text_safely(folder / TIMES_MANIFEST, json.dumps(manifest, indent=1) + "\n", overwrite)
        records.append({
            "folder": name,
            "kind": plant.kind,
            "seed": plant.seed,
            "files": files,
            "times": [float(t) for t in times],
            "normalized_times": plant.sequence.normalized_times().double().tolist(),
            "bio_times": plant.bio_times.double().tolist(),
            "growth_warp": {"grid": plant.growth_grid.double().tolist(), "values": plant.growth_warp.double().tolist()},
            "labels_per_frame": plant.labels_per_frame(),
            "organs_per_frame": plant.organs_per_frame(),
            "settings": plant.settings,
        })
    kinds = sorted({p.kind for p in plants})
    dataset_seed = {p.settings.get("dataset_seed") for p in plants}
    meta = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "kind": kinds[0] if len(kinds) == 1 else "mixed",
        "seed": dataset_seed.pop() if len(dataset_seed) == 1 else None,
        "units": "mm, z up, root at the origin",
        "label_scheme": LABEL_SCHEME,
        "frames": "raw skeletons (SWC, organ label per node in the type column); labels_per_frame: the branch labels "
                  "of the trees derived by the generator's hierarchy (settings.hierarchy_kwargs, default the "
                  "reader's), organs_per_frame: the organs present",
        "growth_warp": "biological time = h(normalised calendar time); h piecewise linear on its grid",
        "settings": {k: v for k, v in plants[0].settings.items() if k != "index"},
        "plants": records,
    }
    write_text_safely(out / DATASET_MANIFEST, json.dumps(meta, indent=1) + "\n", overwrite)
    return out


def read_ground_truth(dataset_dir: str | Path) -> dict:
    """The ``dataset.json`` of a synthetic dataset folder (see :func:`write_dataset`), checked.

    Per plant (``["plants"]``, in folder order): ``folder``, ``seed``, ``times``,
    ``normalized_times``, ``bio_times``, ``growth_warp`` (``grid``, ``values``), ``labels_per_frame``
    and (format version 2) ``organs_per_frame``.

    Example:
        >>> import tempfile
        >>> out = run_synth("maize", plants=1, seed=0, out=str(Path(tempfile.mkdtemp()) / "ds"), frames=2)
        >>> truth = read_ground_truth(out)
        >>> truth["kind"], [p["folder"] for p in truth["plants"]], len(truth["plants"][0]["times"])
        ('maize', ['maize_00'], 2)
    """
    path = Path(dataset_dir) / DATASET_MANIFEST
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no synthetic ground truth here (written by write_dataset / synth)")
    try:
        meta = json.loads(path.read_text())
    except ValueError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path}: not a torch4dtree synthetic dataset manifest")
    if meta.get("version", 0) > FORMAT_VERSION:
        raise ValueError(f"{path}: format version {meta.get('version')} is newer than this package's {FORMAT_VERSION}")
    return meta


def run_synth(kind: str, plants: int, seed: int, out: str, frames: int = 10, overwrite: bool = False,
              variation: bool = False) -> Path:
    """What ``torch4dtree synth --kind K --plants N --seed S --out DIR [--vary]`` does: generate and write a dataset
    (``variation``: plants vary in vigour, :func:`~torch4dtree.data.synthetic.synthetic_plant`).

    Example:
        >>> import tempfile
        >>> out = run_synth("bean", plants=1, seed=0, out=str(Path(tempfile.mkdtemp()) / "ds"), frames=2)
        >>> sorted(p.name for p in (out / "bean_00").iterdir())
        ['day_000.swc', 'day_001.swc', 'times.json']
    """
    return write_dataset(synthetic_dataset(kind, plants, seed, n_frames=frames, variation=variation), out,
                         overwrite=overwrite)
