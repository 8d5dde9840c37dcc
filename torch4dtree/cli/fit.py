"""``torch4dtree fit DATASET --config configs/X --out RUN``: fit the generative model of 4D trees on a dataset folder.

Writes a new run directory: ``model.pt`` (checkpoint), ``report.json`` / ``report.md`` (dataset summary, distances
before / after each registration stage, variance per mode, reconstruction error, timings), ``fit.log`` and the
figures ``mean.png`` (the mean 4D tree over time), ``modes.png`` (the first modes at -2..+2 sd, mean-time frame) and
``samples.png`` (a few samples over time). Refuses an existing run directory unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path
from typing import Any

from .options import add_config_arguments, config_from_args

FIGURE_COLUMNS = 6


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="a dataset folder: one subfolder of frame files (.swc / .mat) per 4D tree")
    p.add_argument("--out", required=True, help="the run directory to create")
    add_config_arguments(p, registration=True)
    p.add_argument("--n-t", type=int, default=None,
                   help="common time samples of the trajectories (default: the config's n_t, 32)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sample figure (default 0)")
    p.add_argument("--no-figures", action="store_true", help="skip the rendered figures")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


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


def _stats(x: list[float]) -> dict[str, float]:
    import torch

    t = torch.tensor(x, dtype=torch.float64)
    if len(t) == 0:
        return {"mean": float("nan"), "median": float("nan"), "max": float("nan")}
    return {"mean": float(t.mean()), "median": float(t.median()), "max": float(t.max())}


def report_markdown(r: dict[str, Any]) -> str:
    """The run report as Markdown."""
    d, reg = r["dataset"], r["registration"]
    lines = [f"# torch4dtree fit: {r['dataset']['path']}", "",
             f"{d['sequences']} 4D trees, {d['frames']} frames (days {d['time_min']:.4g}..{d['time_max']:.4g}).",
             f"Layout: {r['tree_space']['slots']} slots; tree PCA {r['tree_space']['components']} components "
             f"({100 * r['tree_space']['variance_explained']:.1f} % of the frames' variance); "
             f"reference 4D tree {r['tree_space']['reference']}.", "",
             "## Distances (mean / median / max)", "", "| stage | before | after |", "|---|---|---|"]
    for name, key in (("cross-sequence spatial (representatives)", "cross_sequence"),
                      ("temporal (trajectories onto the 4D mean)", "temporal")):
        b, a = reg[key]["before"], reg[key]["after"]
        lines.append(f"| {name} | {b['mean']:.4g} / {b['median']:.4g} / {b['max']:.4g} | "
                     f"{a['mean']:.4g} / {a['median']:.4g} / {a['max']:.4g} |")
    lines += ["", f"Within-sequence registration: mean consecutive-frame distance {reg['within_sequence_mean']:.4g}.",
              f"4D Karcher mean energy per round: {', '.join(f'{e:.4g}' for e in r['mean_energies'])}.", "",
              "## Modes", "", "| mode | variance | share |", "|---|---|---|"]
    for i, (v, s) in enumerate(zip(r["modes"]["variance"], r["modes"]["variance_ratio"])):
        lines.append(f"| {i + 1} | {v:.4g} | {100 * s:.1f} % |")
    rec = r["reconstruction"]
    lines += ["", f"Reconstruction of the training plants by the modes (4D distance): mean {rec['mean']:.4g}, "
              f"max {rec['max']:.4g}.", "", "## Timings (s)", ""]
    lines += [f"* {k}: {v:.3f}" for k, v in r["seconds"].items()]
    if r.get("figures"):
        lines += ["", "## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in r["figures"]]
    return "\n".join(lines) + "\n"


def build_report(model: Any, dataset: str, seqs: list[Any], seconds: dict[str, float]) -> dict[str, Any]:
    import torch

    rep = model.report_
    pop = rep["population"]
    times = torch.cat([s.times for s in seqs])
    return {
        "dataset": {"path": str(dataset), "sequences": len(seqs), "names": [s.name for s in seqs],
                    "frames": int(sum(len(s) for s in seqs)), "frames_per_sequence": [len(s) for s in seqs],
                    "time_min": float(times.min()), "time_max": float(times.max())},
        "tree_space": {k: pop[k] for k in ("reference", "slots", "reference_slots", "components",
                                           "variance_explained")},
        "registration": {
            "within_sequence_mean": pop["within_sequence_distance_mean"],
            "cross_sequence": {"before": _stats(pop["cross_distance_before"]),
                               "after": _stats(pop["cross_distance_after"])},
            "temporal": {"before": _stats(rep["temporal_distance_before"]),
                         "after": _stats(rep["temporal_distance_after"])}},
        "mean_energies": rep["mean_energies"],
        "modes": {"count": rep["modes"], "variance": rep["mode_variance"],
                  "variance_ratio": rep["mode_variance_ratio"]},
        "reconstruction": _stats(rep["reconstruction_4d"]),
        "seconds": {**rep["seconds"], **seconds},
    }


def write_figures(model: Any, out: Path, size: int, seed: int, n_samples: int = 3, note: str | None = None
                  ) -> list[str]:
    """``mean.png``, ``modes.png``, ``samples.png`` in ``out``; ``note`` (e.g. what the model was fitted on) is a
    second title line of each."""
    import torch

    from ..render import render_grid, save_image

    written = []
    mean = model.decode_trajectories(model.mean.trajectory[None].to(model.pca.mean), ["mean"])[0]
    sub = time_columns(mean)
    img = render_grid([sub], row_labels=["4D mean"], col_labels=[f"t = {t:.3g}" for t in sub.times.tolist()],
                      title=_titled("mean 4D tree", note), size=size, color="label")
    written.append(str(save_image(out / "mean.png", img)))
    rows, labels = [], []
    taus = (-2.0, -1.0, 0.0, 1.0, 2.0)
    for i, mode in enumerate(model.modes(taus, modes=min(3, model.n_modes))):
        for t, seq in zip(taus, mode):
            rows.append(time_columns(seq))
            labels.append(f"mode {i + 1}, {t:+.0f} sd")
    img = render_grid(rows, row_labels=labels, title=_titled("modes of variation (rows) over time (columns)", note),
                      size=size, color="label")
    written.append(str(save_image(out / "modes.png", img)))
    samples = model.sample(n_samples, generator=torch.Generator().manual_seed(seed))
    img = render_grid([time_columns(s) for s in samples], row_labels=[s.name for s in samples],
                      title=_titled("samples over time", note), size=size, color="label")
    written.append(str(save_image(out / "samples.png", img)))
    return written


def _titled(title: str, note: str | None) -> str:
    return f"{title}\n{note}" if note else title


def time_columns(seq: Any, columns: int = FIGURE_COLUMNS) -> Any:
    """The frames of a 4D tree at ``columns`` evenly spaced indices, first and last included (a figure's columns;
    fewer if the sequence is shorter)."""
    n = len(seq)
    idx = sorted({round(j * (n - 1) / max(columns - 1, 1)) for j in range(columns)})
    return seq[idx]


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm.auto import tqdm

    from ..io import read_sequence, sequence_folders
    from ..io.files import write_text_safely
    from ..model import FourDTreeModel, save_model

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
    seqs = [read_sequence(f, opts).sequence for f in tqdm(folders, desc="reading", unit="plant", disable=args.quiet)]
    seconds["read"] = time.perf_counter() - t0
    log.info("read %d 4D trees (%d frames) in %.2f s", len(seqs), sum(len(s) for s in seqs), seconds["read"])
    t0 = time.perf_counter()
    model = FourDTreeModel(**cfg.model_args()).fit(seqs, progress=not args.quiet)
    seconds["fit"] = time.perf_counter() - t0
    log.info("fitted in %.2f s: %d slots, %d tree components, %d modes", seconds["fit"],
             model.report_["population"]["slots"], model.population.k, model.n_modes)
    path = save_model(model, out / "model.pt", cfg.to_dict())
    log.info("wrote %s", path)
    report = build_report(model, args.dataset, seqs, seconds)
    if not args.no_figures:
        t0 = time.perf_counter()
        report["figures"] = write_figures(model, out, cfg.render_size, args.seed)
        report["seconds"]["figures"] = time.perf_counter() - t0
        for f in report["figures"]:
            log.info("wrote %s", f)
    write_text_safely(out / "report.json", json.dumps(report, indent=2))
    write_text_safely(out / "report.md", report_markdown(report))
    log.info("wrote %s and %s", out / "report.json", out / "report.md")
    print(f"run directory: {out}")
    return 0
