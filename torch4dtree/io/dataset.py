"""Sequence folders (one 4D tree) and dataset folders (several), docs/method.md §6.

A **sequence folder** holds one file per frame (``.swc`` or reference ``.mat``). Frame times
come, in this order of precedence, from

1. a manifest ``times.json`` in the folder: ``{"<file name>": <time>, ...}`` (any unit); files
   not listed are ignored, so the manifest also selects frames;
2. the file names, all in the same style:
   * a month and day as two 2-digit tokens (``03_05.mat``) or one 4-digit token (``T03_0305_a_seg.swc``)
     -> days since January 1 (dates carry no year; a leap year is assumed),
   * otherwise the last integer token (``frame_7.swc``, ``012.swc``) -> that number.

Tokens are the parts of the name between ``_``, ``-``, ``.`` and spaces. Empty frames (the
placeholder ``.mat`` files of removed days) are skipped and reported.

A **dataset folder** holds one sequence folder per 4D tree (sorted by name); an optional
``dataset.json`` may record metadata (the synthetic generator writes its settings there).
"""

from __future__ import annotations

import datetime
import json
import re
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..parallel import run_tasks
from ..settings import DEFAULT_HIERARCHY, DEFAULT_ROOT, DEFAULT_T, HIERARCHIES, ROOTS, check_choice
from ..trees.structures import TreeError, Trees, TreeSequence
from .mat import read_mat_tree
from .swc import read_swc, read_swc_skeleton

FRAME_SUFFIXES = (".swc", ".mat")
TIMES_MANIFEST = "times.json"


class DatasetError(TreeError):
    """A sequence or dataset folder that does not follow the documented layout."""


@dataclass
class LoadOptions:
    """How skeleton files become trees (the same for every frame of a dataset).

    Attributes:
        T: points per branch after arc-length resampling.
        max_layers: keep branches up to this depth (``None``: all).
        min_branch_length: drop side branches shorter than this (file units).
        repair: mend cycles and parts cut off from the root (with a warning) instead of failing.
        labels_from_type: the SWC type column holds branch identities (:attr:`Trees.label`).
        dtype: of the points.
        hierarchy: how a skeleton's branch points are resolved, one of
            :data:`~torch4dtree.settings.HIERARCHIES` (docs/method.md §2).
        joint_hierarchy: in a sequence of SWC frames, main branches chosen to agree over time
            (:func:`~torch4dtree.trees.growth.consistent_frames`).
        root: where an SWC skeleton is rooted, one of :data:`~torch4dtree.settings.ROOTS`: ``"auto"`` (default)
            a plant's stem base, with a warning, where the file roots it at a leaf tip hanging below it (a soma or a
            branching root is kept); ``"base"`` the stem base always; ``"file"`` the file's own root
            (:mod:`torch4dtree.io.rooting`). ``.mat`` trees keep theirs.

    Example:
        >>> LoadOptions(T=16).hierarchy
        'straightest'
        >>> LoadOptions(hierarchy="tallest")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        torch4dtree.trees.structures.TreeError: hierarchy must be one of (...), got 'tallest'
    """

    T: int = DEFAULT_T
    max_layers: int | None = None
    min_branch_length: float = 0.0
    repair: bool = False
    labels_from_type: bool = False
    dtype: torch.dtype = torch.float32
    hierarchy: str = DEFAULT_HIERARCHY
    joint_hierarchy: bool = True
    root: str = DEFAULT_ROOT

    def __post_init__(self) -> None:
        check_choice("hierarchy", self.hierarchy, HIERARCHIES)
        check_choice("root", self.root, ROOTS)


@dataclass
class LoadedSequence:
    """A sequence read from a folder, with the names of its frame files and skipped frames."""

    sequence: TreeSequence
    files: list[str]
    skipped: list[str] = field(default_factory=list)


def read_tree(path: str | Path, options: LoadOptions | None = None) -> Trees | None:
    """Read one tree file (``.swc`` or reference ``.mat``); ``None`` for an empty ``.mat`` frame.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "day_1.swc"
        >>> _ = path.write_text("1 0 0 0 0 1 -1\\n2 0 0 0 5 1 1\\n3 0 0 0 10 1 2\\n4 0 4 0 8 1 2\\n")
        >>> read_tree(path, LoadOptions(T=8, dtype=torch.float64)).points.shape
        torch.Size([2, 8, 3])
    """
    o = options or LoadOptions()
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such file")
    if path.suffix.lower() == ".swc":
        tree = read_swc(path, T=o.T, max_layers=o.max_layers, min_branch_length=o.min_branch_length,
                        labels_from_type=o.labels_from_type, repair=o.repair, hierarchy=o.hierarchy, root=o.root)
    elif path.suffix.lower() == ".mat":
        tree = read_mat_tree(path, T=o.T)
    else:
        raise DatasetError(f"{path}: unknown tree file type (expected .swc or .mat)")
    return None if tree is None else tree.to(o.dtype)


def _tokens(name: str) -> list[str]:
    return [t for t in re.split(r"[_\-. ]+", Path(name).stem) if t]


def _day_of_year(month: int, day: int) -> int | None:
    try:
        return datetime.date(2020, month, day).timetuple().tm_yday
    except ValueError:
        return None


def time_from_name(name: str) -> tuple[str, float] | None:
    """``(style, time)`` parsed from a frame file name, or ``None`` (see the module doc).

    Example:
        >>> time_from_name("03_05.mat"), time_from_name("frame_7.swc"), time_from_name("scan.swc")
        (('date', 65.0), ('integer', 7.0), None)
    """
    toks = _tokens(name)
    for a, b in zip(toks[:-1], toks[1:]):
        if len(a) == 2 == len(b) and a.isdigit() and b.isdigit():
            doy = _day_of_year(int(a), int(b))
            if doy is not None:
                return "date", float(doy)
    for t in toks:
        if len(t) == 4 and t.isdigit():
            doy = _day_of_year(int(t[:2]), int(t[2:]))
            if doy is not None:
                return "date", float(doy)
    ints = [t for t in toks if t.isdigit()]
    return ("integer", float(ints[-1])) if ints else None


def frame_times(folder: Path) -> list[tuple[Path, float]]:
    """The frame files of a sequence folder with their times, sorted by time."""
    manifest = folder / TIMES_MANIFEST
    if manifest.exists():
        try:
            table = json.loads(manifest.read_text())
            pairs = [(folder / str(k), float(v)) for k, v in table.items()]
        except (ValueError, AttributeError, TypeError) as e:
            raise DatasetError(f"{manifest}: expected a JSON object {{file name: time}} ({e})") from None
        for p, _ in pairs:
            if not p.is_file():
                raise DatasetError(f"{manifest}: lists {p.name}, which is not in {folder}")
    else:
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in FRAME_SUFFIXES and p.is_file())
        if not files:
            raise DatasetError(f"{folder}: no frame files ({', '.join(FRAME_SUFFIXES)}) and no {TIMES_MANIFEST}")
        parsed = {p: time_from_name(p.name) for p in files}
        bad = [p.name for p, v in parsed.items() if v is None]
        if bad:
            raise DatasetError(f"{folder}: no time in the file name {bad[0]!r}; name frames by date "
                               f"(MMDD, MM_DD) or number, or add {TIMES_MANIFEST}")
        styles = {v[0] for v in parsed.values() if v}
        if len(styles) > 1:
            raise DatasetError(f"{folder}: file names mix dates and plain numbers; add {TIMES_MANIFEST}")
        pairs = [(p, v[1]) for p, v in parsed.items() if v]
    pairs.sort(key=lambda pt: pt[1])
    for (p1, t1), (p2, t2) in zip(pairs[:-1], pairs[1:]):
        if t1 == t2:
            raise DatasetError(f"{folder}: {p1.name} and {p2.name} have the same time {t1:g}")
    return pairs


def read_sequence(
    folder: str | Path,
    options: LoadOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> LoadedSequence:
    """Read a sequence folder as a :class:`TreeSequence` (empty frames skipped).

    With ``options.joint_hierarchy`` (the default) and SWC frames only, each frame's main branch is chosen to agree
    with the next frame's (:func:`torch4dtree.trees.growth.consistent_frames`): a young plant's main branch then
    runs up its stem as on later days instead of into whichever apex leaf leaves the stem straightest on that day.

    Example:
        >>> import tempfile
        >>> from torch4dtree.data import synthetic_plant
        >>> root = Path(tempfile.mkdtemp())
        >>> files = write_sequence(root / "plant_1", synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence)
        >>> loaded = read_sequence(root / "plant_1", LoadOptions(T=8))
        >>> loaded.files, loaded.sequence.frames.T
        (['frame_000.swc', 'frame_001.swc'], 8)
    """
    o = options or LoadOptions()
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder")
    pairs = frame_times(folder)
    if o.joint_hierarchy and len(pairs) > 1 and all(p.suffix.lower() == ".swc" for p, _ in pairs):
        return _read_swc_sequence(folder, pairs, o, progress)
    frames: list[Trees] = []
    times: list[float] = []
    used: list[str] = []
    skipped: list[str] = []
    for path, t in pairs:
        if progress:
            progress(path.name)
        tree = read_tree(path, o)
        if tree is None:
            skipped.append(path.name)
            continue
        frames.append(tree)
        times.append(t)
        used.append(path.name)
    if not frames:
        raise DatasetError(f"{folder}: every frame is empty")
    dtype = frames[0].dtype
    seq = TreeSequence(Trees.cat(frames), torch.tensor(times, dtype=dtype), folder.name)
    return LoadedSequence(seq, used, skipped)


def _read_swc_sequence(folder: Path, pairs: list[tuple[Path, float]], o: LoadOptions,
                       progress: Callable[[str], None] | None) -> LoadedSequence:
    """A folder of SWC frames with main branches that agree over time (see :func:`read_sequence`)."""
    from ..trees.growth import consistent_frames

    skeletons, ids = [], []
    for path, _ in pairs:
        if progress:
            progress(path.name)
        sk = read_swc_skeleton(path, o.repair, o.root)
        skeletons.append((sk.xyz, sk.parent, sk.types if o.labels_from_type else None))
        ids.append(sk.ids)
    # built as read_tree builds a single file (float32, then cast), so the numbers match it where the hierarchy does
    trees = consistent_frames(skeletons, T=o.T, hierarchy=o.hierarchy, names=[str(p) for p, _ in pairs],
                              max_layers=o.max_layers, min_branch_length=o.min_branch_length, ids=ids)
    frames = Trees.cat([t.to(o.dtype) for t in trees])
    seq = TreeSequence(frames, torch.tensor([t for _, t in pairs], dtype=o.dtype), folder.name)
    return LoadedSequence(seq, [p.name for p, _ in pairs])


def is_sequence_folder(folder: Path) -> bool:
    """True if the folder holds frame files (or a times manifest) directly."""
    return (folder / TIMES_MANIFEST).exists() or any(
        p.suffix.lower() in FRAME_SUFFIXES for p in folder.iterdir() if p.is_file()
    )


def sequence_folders(folder: str | Path) -> list[Path]:
    """The sequence folders of a dataset folder, sorted by name.

    Example:
        >>> import tempfile
        >>> from torch4dtree.data import synthetic_plant
        >>> root = Path(tempfile.mkdtemp())
        >>> files = write_sequence(root / "plant_1", synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence)
        >>> [p.name for p in sequence_folders(root)]
        ['plant_1']
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder")
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    seqs = [p for p in subs if is_sequence_folder(p)]
    if not seqs:
        raise DatasetError(f"{folder}: no sequence folders (subfolders holding .swc or .mat frames)")
    return seqs


def read_dataset(
    folder: str | Path,
    options: LoadOptions | None = None,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
) -> list[LoadedSequence]:
    """Read every sequence folder of a dataset folder (see :func:`read_sequence`), in name order.

    ``executor``: one task a sequence folder there (:mod:`torch4dtree.parallel`; the workers must see the
    folder's path); ``progress`` is then called with each sequence folder's name as it is read, on the caller's side.

    Example:
        >>> import tempfile
        >>> from torch4dtree.data import synthetic_plant
        >>> root = Path(tempfile.mkdtemp())
        >>> files = write_sequence(root / "plant_1", synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence)
        >>> [s.sequence.name for s in read_dataset(root, LoadOptions(T=8))]
        ['plant_1']
    """
    folders = sequence_folders(folder)
    if executor is None:
        return [read_sequence(p, options, progress) for p in folders]
    def done(i: int, loaded: LoadedSequence) -> None:
        if progress:
            progress(folders[i].name)

    return run_tasks(read_sequence, [(p, options) for p in folders], executor, done=done)


def write_sequence(folder: str | Path, seq: TreeSequence, overwrite: bool = False, comment: str = "") -> list[Path]:
    """Write a 4D tree as a sequence folder: one SWC file per frame (``frame_NNN.swc``, branch type = label) and a
    ``times.json`` manifest. Checks every target first: nothing is written if a file exists and not ``overwrite``.
    Returns the written paths.

    Example:
        >>> import tempfile
        >>> from torch4dtree.data import synthetic_plant
        >>> root = Path(tempfile.mkdtemp())
        >>> files = write_sequence(root / "plant_1", synthetic_plant("tomato", seed=0, n_frames=2, T=8).sequence)
        >>> [p.name for p in files]
        ['frame_000.swc', 'frame_001.swc', 'times.json']
    """
    from .files import write_text_safely
    from .swc import write_swc

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder} exists and is not a folder")
    names = [f"frame_{j:03d}.swc" for j in range(len(seq))]
    targets = [folder / n for n in names] + [folder / TIMES_MANIFEST]
    existing = [str(p) for p in targets if p.exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{existing[0]} exists ({len(existing)} file(s) in {folder}); pass overwrite to replace")
    folder.mkdir(parents=True, exist_ok=True)
    written = [write_swc(folder / n, seq.frames[j], overwrite=overwrite, comment=comment)
               for j, n in enumerate(names)]
    times = {n: float(t) for n, t in zip(names, seq.times.tolist())}
    written.append(write_text_safely(folder / TIMES_MANIFEST, json.dumps(times, indent=1) + "\n", overwrite))
    return written
