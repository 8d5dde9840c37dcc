"""Argument types and checks shared by the subcommands, and the ``--config`` flags (argparse glue only).

Everything here is cheap to import (no torch): the parser, and so ``--help``, is built from it.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path

from ..config import Config, load_config
from ..settings import HIERARCHIES, ROOTS, ROTATIONS


class UsageError(ValueError):
    """Bad input found after parsing (a path that is a folder, a missing output folder...): exit code 2."""


def int_at_least(low: int) -> Callable[[str], int]:
    """An argparse type: a whole number ``>= low`` (its name shows in argparse's messages)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {low}, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {value}")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def check_output_file(path: Path, overwrite: bool, suffixes: tuple[str, ...], flag: str) -> Path:
    """Fail before any work if ``path`` cannot be written: wrong suffix, missing folder, a folder, or an
    existing file without ``--overwrite``. Folders are never created for an output file."""
    if path.suffix.lower() not in suffixes:
        raise UsageError(f"{flag} must end in {', '.join(suffixes)}, got {path.name!r}")
    if path.is_dir():
        raise UsageError(f"{flag} {path} is a folder; give a file name")
    if not path.parent.is_dir():
        raise UsageError(f"{flag} {path}: the folder {path.parent} does not exist (create it first)")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass --overwrite to replace it")
    return path


def add_config_arguments(parser: argparse.ArgumentParser, registration: bool = False) -> None:
    """``--config FILE`` and the flags that override it: the loading settings, and with ``registration``
    also ``--rotation``, ``--lambdas`` and ``--neighbourhood``. Every flag defaults to None (= not given), so
    that a config file's value is kept unless the flag is given; the help shows the built-in default."""
    group = parser.add_argument_group("settings (override --config, which overrides the built-in defaults)")
    group.add_argument("--config", default=None, metavar="FILE",
                       help="a JSON settings file (see configs/); flags given override it (default: none)")
    group.add_argument("--T", type=positive_int, default=None,
                       help=f"points per branch after resampling (default: {Config.T})")
    group.add_argument("--max-layers", type=positive_int, default=None, metavar="N",
                       help="keep at most this many branch layers (default: all)")
    group.add_argument("--min-branch-length", type=float, default=None, metavar="LENGTH",
                       help=f"drop SWC side branches shorter than this, in the file's units "
                            f"(default: {Config.min_branch_length:g})")
    group.add_argument("--repair", action="store_true", default=None,
                       help="mend SWC cycles / parts cut off from the root, with a warning (default: off, an "
                            "error names the node)")
    group.add_argument("--hierarchy", choices=HIERARCHIES, default=None,
                       help=f"which child continues a branch at an SWC branch point (default: {Config.hierarchy}, "
                            "stable as plants grow; longest = the paper's longest-path rule)")
    group.add_argument("--per-frame-hierarchy", dest="joint_hierarchy", action="store_const", const=False,
                       default=None, help="in SWC sequences, apply the rule to each frame alone (default: each "
                       "frame's main branch is chosen to agree with the next frame's)")
    group.add_argument("--root", choices=ROOTS, default=None,
                       help=f"where an SWC skeleton is rooted (default: {Config.root}: the stem base where the file "
                            "roots a plant at a leaf tip hanging below it, with a warning; file: the file's root)")
    if registration:
        group.add_argument("--rotation", choices=ROTATIONS, default=None,
                           help=f"global rotation to optimise (default: {Config.rotation}, the scans share a frame)")
        group.add_argument("--lambdas", type=float, nargs=3, default=None, metavar=("LM", "LS", "LP"),
                           help="metric weights of main branch, subtrees, bifurcation parameters (default: "
                                + " ".join(f"{x:g}" for x in Config.lambdas) + ")")
        group.add_argument("--neighbourhood", type=positive_int, default=None, metavar="N",
                           help=f"largest DP slope (default: {Config.neighbourhood}; 6 for strongly non-uniform "
                                f"warps)")


def config_from_args(args: argparse.Namespace) -> Config:
    """The :class:`Config` of ``--config`` (or the defaults) with the flags given on the command line on top."""
    config = load_config(args.config) if getattr(args, "config", None) else Config()
    names = [f.name for f in dataclasses.fields(Config)]
    given = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    try:
        return dataclasses.replace(config, **given)
    except ValueError as e:
        raise UsageError(f"command line: {e}") from None


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` (local processes) and ``--scheduler ADDRESS`` (a Dask cluster): where the heavy work runs
    (:func:`torch4dtree.parallel.make_executor`; docs/distributed.md). Neither: in this process, as without them."""
    group = parser.add_argument_group("where the work runs (docs/distributed.md)")
    group.add_argument("--workers", type=positive_int, default=None, metavar="N",
                       help="run the heavy steps on N local worker processes (default: in this process)")
    group.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="run them on the Dask cluster of this scheduler (e.g. tcp://host:8786; needs "
                            "pip install torch4dtree[distributed]), or on Ray (ray, ray://host:10001) "
                            "(default: none)")


def executor_from_args(args: argparse.Namespace) -> AbstractContextManager:
    """A context manager giving the executor of ``--workers`` / ``--scheduler``, or ``None`` when neither is given
    (so every entry point keeps its in-process default)."""
    workers, scheduler = getattr(args, "workers", None), getattr(args, "scheduler", None)
    if workers is not None and scheduler is not None:
        raise UsageError("give --workers or --scheduler, not both (a cluster's workers are its own)")
    if workers is None and scheduler is None:
        return nullcontext(None)
    from ..parallel import make_executor  # here: building the parser must not import torch

    return make_executor(workers, scheduler)
