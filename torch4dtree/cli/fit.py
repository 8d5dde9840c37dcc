"""``torch4dtree fit DATASET --config configs/X --out RUN [--model organs|paper]``: fit a generative model of 4D
trees on a dataset folder.

``--model`` (or the config's ``model``) chooses the paper's :class:`~torch4dtree.model.FourDTreeModel` or the
organ-by-organ :class:`~torch4dtree.model.OrganModel`. Writes a new run directory: ``model.pt`` (checkpoint),
``fit.log``, and the report of :mod:`torch4dtree.evaluate.model_report` (``report.json`` / ``report.md`` and the
figures: ``mean.png``, ``modes.png``, ``samples.png`` for the paper's model, ``samples.png`` for the organ model).
Refuses an existing run directory unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path

from ..settings import MODELS
from .options import add_config_arguments, add_executor_arguments, config_from_args, executor_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="a dataset folder: one subfolder of frame files (.swc / .mat) per 4D tree")
    p.add_argument("--out", required=True, help="the run directory to create")
    add_config_arguments(p, registration=True)
    p.add_argument("--model", choices=MODELS, default=None,
                   help="which generative model: organs (organ by organ) or paper (4D mean and modes); "
                        "default: the config's model, else paper")
    p.add_argument("--n-t", type=int, default=None,
                   help="common time samples of the trajectories (default: the config's n_t, 32)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sample figure (default 0)")
    p.add_argument("--no-figures", action="store_true", help="skip the rendered figures")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_executor_arguments(p)


def _logger(path: Path, quiet: bool) -> logging.Logger:
    log = logging.getLogger(f"torch4dtree.fit.{path}")
    log.setLevel(logging.INFO)
    log.handlers.clear()
    fh = logging.FileHandler(path)
    fh.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
    log.addHandler(fh)
    if not quiet:
        log.addHandler(logging.StreamHandler())
    log.propagate = False
    return log


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm.auto import tqdm

    from ..evaluate.model_report import write_model_report
    from ..io import read_sequence, sequence_folders
    from ..model import FourDTreeModel, OrganModel, save_model
    from ..parallel import run_tasks

    out = Path(args.out)
    if out.exists():
        if not args.overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace the run directory")
        if not (out / "model.pt").exists() and any(out.iterdir()):
            raise FileExistsError(f"{out} is not empty and holds no model.pt: not replacing a folder that is not a run")
        shutil.rmtree(out)
    cfg = config_from_args(args)
    if args.n_t is not None:
        cfg = dataclasses.replace(cfg, n_t=args.n_t)
    folders = sequence_folders(args.dataset)
    out.mkdir(parents=True)
    log = _logger(out / "fit.log", args.quiet)
    log.info("torch4dtree fit %s -> %s; config %s", args.dataset, out, json.dumps(cfg.to_dict()))
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    opts = dataclasses.replace(cfg.load_options(), dtype=torch.float64)
    with executor_from_args(args) as executor, \
            tqdm(total=len(folders), desc="reading", unit="plant", disable=args.quiet) as bar:
        seqs = [r.sequence for r in run_tasks(read_sequence, [(f, opts) for f in folders], executor,
                                              done=lambda i, r: bar.update())]
        seconds["read"] = time.perf_counter() - t0
        log.info("read %d 4D trees (%d frames) in %.2f s", len(seqs), sum(len(s) for s in seqs), seconds["read"])
        t0 = time.perf_counter()
        if cfg.model == "organs":
            model = OrganModel(cfg.organ_settings()).fit(seqs)
            seconds["fit"] = time.perf_counter() - t0
            log.info("fitted the organ model in %.2f s: %d organs at %d botanical keys, %d ages", seconds["fit"],
                     model.report_["organs"], model.report_["keys"], model.report_["ages"])
        else:
            model = FourDTreeModel(cfg.model_settings()).fit(seqs, progress=not args.quiet, executor=executor)
            seconds["fit"] = time.perf_counter() - t0
            log.info("fitted the paper's model in %.2f s: %d slots, %d tree components, %d modes", seconds["fit"],
                     model.report_["population"]["slots"], model.population.k, model.n_modes)
    path = save_model(model, out / "model.pt", cfg.to_dict())
    log.info("wrote %s", path)
    report = write_model_report(model, out, args.dataset, seqs, seconds, figures=not args.no_figures,
                                size=cfg.render_size, seed=args.seed)
    for f in report.get("figures", []):
        log.info("wrote %s", f)
    log.info("wrote %s and %s", out / "report.json", out / "report.md")
    print(f"run directory: {out}")
    return 0
