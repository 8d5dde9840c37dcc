"""``torch4dtree evaluate DATA_DIR [--json] [--out DIR]``: the paper's experiments and the generative model's quality.

``DATA_DIR`` is a Pheno4D-style folder (``mat/`` and / or ``swc/`` sequence folders, as ``../shared/data/pheno4d``),
a synthetic dataset folder (``torch4dtree synth``) or any dataset folder ``fit`` reads (one kind, no ground truth).
Writes ``report.md`` (tables with the paper's figures beside ours, figures) and ``report.json`` into ``--out`` (a new
or empty folder; ``--overwrite`` replaces an earlier report there); ``--json`` prints the report as one JSON object.
See :mod:`torch4dtree.evaluate`.

The generative section holds plants out per kind: ``--folds K`` folds, each held out once (``--folds 2`` on 40 plants:
fit on 20, 20 held out, both ways), or ``--heldout DIR``: fit on ``DATA_DIR``'s plants, measure on ``DIR``'s (one
fold; e.g. ``evaluate pop/train --heldout pop/heldout --sections generative``). ``--draws N``: morphometric draws per
generator, summarised by their median and worst.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ..settings import CROSS_LP, CROSS_ORDER_TOL, CROSS_POSITIONS, POSITIONS
from .options import UsageError, add_executor_arguments, executor_from_args, int_at_least

if TYPE_CHECKING:
    from ..evaluate import EvalSettings

SECTION_NAMES = ("spatial", "temporal", "generative", "truth", "robustness")


def _number_or_none(text: str) -> float | None:
    if text.lower() == "none":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'none', got {text!r}") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'none', got {text!r}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", help="a Pheno4D-style folder (mat/ and/or swc/ inside), a synthetic dataset folder or any "
                                "dataset folder (one sequence folder per plant)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write report.md, report.json and the figures here (a new or empty folder) (default: none)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object on stdout")
    p.add_argument("--quick", action="store_true", help="small versions of every experiment (a first look, tests)")
    p.add_argument("--sections", default=",".join(SECTION_NAMES), metavar="LIST",
                   help="comma-separated experiments to run (default: %(default)s)")
    p.add_argument("--T", type=int_at_least(4), default=64, metavar="N",
                   help="points per branch of the registrations (default: %(default)s)")
    p.add_argument("--T-cycle", type=int_at_least(4), default=256, metavar="N",
                   help="points per branch of the cycle-consistency table (default: %(default)s)")
    p.add_argument("--n-t", type=int_at_least(2), default=32, metavar="N",
                   help="common time samples of the trajectories (default: %(default)s)")
    p.add_argument("--cross-positions", choices=POSITIONS, default=CROSS_POSITIONS,
                   help="children's positions in the cross-sequence registrations (default: %(default)s)")
    p.add_argument("--cross-lp", type=_number_or_none, default=CROSS_LP, metavar="LP",
                   help="relative lp of the cross-sequence registrations; 'none': the evaluation's lambdas "
                        "(default: %(default)s)")
    p.add_argument("--cross-order-tol", type=_number_or_none, default=CROSS_ORDER_TOL, metavar="TOL",
                   help="cross-sequence registrations match a node's children in their order along the parent, "
                        "siblings within TOL of each other (a fraction of the parent) in any order; 'none': any "
                        "order (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default: %(default)s)")
    p.add_argument("--heldout", default=None, metavar="DIR",
                   help="generative section: hold out the plants of DIR (a folder as DATA) and fit on DATA's plants, "
                        "instead of folds (default: folds)")
    p.add_argument("--folds", type=int_at_least(2), default=None, metavar="K",
                   help="generative section: at most K folds per kind, each held out once (2: half the plants fit, "
                        "half held out) (default: %(default)s, the section's 3)")
    p.add_argument("--draws", type=int_at_least(1), default=None, metavar="N",
                   help="generative section: morphometric draws per generator and fold, each of as many samples as "
                        "held-out plants; median and worst reported (default: %(default)s, the section's 5)")
    p.add_argument("--no-figures", action="store_true", help="skip the rendered figures")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier report in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_executor_arguments(p)


def _prepare_out(out: Path, overwrite: bool) -> None:
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return
    if not overwrite:
        raise FileExistsError(f"{out} exists and is not empty; pass --overwrite to replace an earlier report")
    if not (out / "report.json").is_file():
        raise FileExistsError(f"{out} holds no report.json: not replacing a folder that is not an evaluation report")
    shutil.rmtree(out)


def settings_from_args(args: argparse.Namespace, figures: bool = True) -> EvalSettings:
    """The evaluation's settings from parsed arguments (``figures``: an output folder is given)."""
    from ..evaluate import EvalSettings

    if args.heldout is not None and args.folds is not None:
        raise UsageError("--heldout and --folds: give one split (a held-out folder is one fold)")
    split = {k: v for k, v in (("folds", args.folds), ("morpho_draws", args.draws)) if v is not None}
    if args.heldout is not None:
        heldout = Path(args.heldout)
        if not heldout.is_dir():
            raise FileNotFoundError(f"--heldout {heldout}: no such folder")
        if heldout.resolve() == Path(args.data).resolve():
            raise UsageError("--heldout: the held-out folder is the data folder")
    return EvalSettings(T=args.T, T_cycle=args.T_cycle, n_t=args.n_t, quick=args.quick, seed=args.seed,
                        figures=not args.no_figures and figures, cross_positions=args.cross_positions,
                        cross_lp=args.cross_lp, cross_order_tol=args.cross_order_tol, heldout=args.heldout, **split)


def run(args: argparse.Namespace) -> int:
    from ..evaluate import dumps, evaluate

    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = [s for s in sections if s not in SECTION_NAMES]
    if unknown or not sections:
        raise UsageError(f"--sections: unknown {unknown or 'empty list'}; choose from {', '.join(SECTION_NAMES)}")
    data = Path(args.data)
    if not data.is_dir():
        raise FileNotFoundError(f"{data}: no such folder")
    out = Path(args.out) if args.out else None
    if out is not None:
        _prepare_out(out, args.overwrite)
    settings = settings_from_args(args, out is not None)
    with executor_from_args(args) as executor:
        report = evaluate(data, out, settings, sections, progress=not args.quiet, executor=executor)
    if args.json:
        print(dumps(report))
    elif out is not None:
        print(f"report: {out / 'report.md'} (and report.json)")
    else:
        from ..evaluate.report import markdown

        print(markdown(report, sections))
    return 0
