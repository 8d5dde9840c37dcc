"""The report of a fitted generative model (what ``torch4dtree fit`` writes beside the checkpoint).

For the paper's :class:`~torch4dtree.model.FourDTreeModel`: dataset summary, distances before / after each
registration stage, variance per mode, reconstruction error, timings, and the figures ``mean.png`` (the mean 4D tree
over time), ``modes.png`` (the first modes at -2..+2 sd) and ``samples.png`` (a few samples over time). For the
:class:`~torch4dtree.model.OrganModel` (no mean, no modes): dataset summary, its organ table (plants, botanical
keys, organs, ages), settings, timings and ``samples.png``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .stats import summary

__all__ = ["FIGURE_COLUMNS", "age_columns", "model_kind", "model_report", "model_report_markdown", "time_columns",
           "write_model_figures", "write_model_report", "write_sample_figure"]

FIGURE_COLUMNS = 6  # times shown of a 4D tree in a figure row
MODE_TAUS = (-2.0, -1.0, 0.0, 1.0, 2.0)  # the modes' figure: standard deviations along each mode
FIGURE_MODES = 3  # modes shown (at most)
# the markdown's line naming the model (settings.MODELS)
MODEL_NAMES = {"organs": "organ by organ (OrganModel)", "paper": "the paper's 4D mean and modes (FourDTreeModel)"}


def _spread(x: Sequence[float]) -> dict[str, float]:
    """Mean, median and max (the report's three columns) of :func:`.stats.summary`."""
    s = summary(x)
    return {k: s[k] for k in ("mean", "median", "max")}


def model_kind(model: Any) -> str:
    """``"organs"`` for an :class:`~torch4dtree.model.OrganModel`, ``"paper"`` for a
    :class:`~torch4dtree.model.FourDTreeModel` (:data:`~torch4dtree.settings.MODELS`)."""
    from ..model.organs import OrganModel

    return "organs" if isinstance(model, OrganModel) else "paper"


def _dataset(dataset: str | Path, seqs: Sequence[Any]) -> dict[str, Any]:
    import torch

    times = torch.cat([s.times for s in seqs])
    return {"path": str(dataset), "sequences": len(seqs), "names": [s.name for s in seqs],
            "frames": int(sum(len(s) for s in seqs)), "frames_per_sequence": [len(s) for s in seqs],
            "time_min": float(times.min()), "time_max": float(times.max())}


def model_report(model: Any, dataset: str | Path, seqs: Sequence[Any], seconds: dict[str, float]) -> dict[str, Any]:
    """The JSON-ready report of ``model`` (either model; ``model`` names which) fitted on ``seqs`` (the 4D trees of
    folder ``dataset``); ``seconds``: the caller's timings (reading...), added to the fit's own."""
    rep = model.report_
    if model_kind(model) == "organs":
        return {"model": "organs", "dataset": _dataset(dataset, seqs),
                "organs": {k: rep[k] for k in ("plants", "keys", "organs", "ages")},
                "bandwidth_used": float(model.donor_bandwidth()),
                "settings": model.settings.to_dict(), "seconds": {"fit": rep["seconds"], **seconds}}
    pop = rep["population"]
    return {
        "model": "paper",
        "dataset": _dataset(dataset, seqs),
        "tree_space": {**{k: pop[k] for k in ("reference", "slots", "reference_slots", "components",
                                              "variance_explained")},
                       **{k: pop.get(k) for k in ("max_slots", "slots_opened", "dropped_share")}},
        "registration": {
            "within_sequence_mean": pop["within_sequence_distance_mean"],
            "cross_sequence": {"before": _spread(pop["cross_distance_before"]),
                               "after": _spread(pop["cross_distance_after"])},
            "temporal": {"before": _spread(rep["temporal_distance_before"]),
                         "after": _spread(rep["temporal_distance_after"])}},
        "mean_energies": rep["mean_energies"],
        "modes": {"count": rep["modes"], "variance": rep["mode_variance"],
                  "variance_ratio": rep["mode_variance_ratio"]},
        "reconstruction": _spread(rep["reconstruction_4d"]),
        "seconds": {**rep["seconds"], **seconds},
    }


def _organ_markdown(r: dict[str, Any]) -> list[str]:
    """The body of an :class:`~torch4dtree.model.OrganModel`'s report."""
    o, st = r["organs"], r["settings"]
    return [f"Organ table: {o['organs']} organs of {o['plants']} plants at {o['keys']} botanical keys; generated "
            f"plants have {o['ages']} frames.",
            f"Settings: bandwidth {st['bandwidth']:g} (used: {r.get('bandwidth_used', st['bandwidth']):.3g}, widened "
            f"for enough donor plants), persistence {st['persistence']:g}, jitter {st['jitter']:g}, c {st['c']:g}."]


def _bound_text(space: dict[str, Any]) -> str:
    """The layout bound's sentence (empty for models fitted without one)."""
    if space.get("max_slots") is None or space.get("dropped_share") is None:
        return ""
    return (f" Slots opened {space['slots_opened']}, kept at most {space['max_slots']}: "
            f"{100 * space['dropped_share']:.2f} % of the training frames' squared length dropped.")


def _paper_markdown(r: dict[str, Any]) -> list[str]:
    """The body of a :class:`~torch4dtree.model.FourDTreeModel`'s report (layout, distances, modes)."""
    reg = r["registration"]
    lines = [f"Layout: {r['tree_space']['slots']} slots; tree PCA {r['tree_space']['components']} components "
             f"({100 * r['tree_space']['variance_explained']:.1f} % of the frames' variance); "
             f"reference 4D tree {r['tree_space']['reference']}.{_bound_text(r['tree_space'])}", "",
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
              f"max {rec['max']:.4g}."]
    return lines


def model_report_markdown(r: dict[str, Any]) -> str:
    """A :func:`model_report` as Markdown (reports without ``model`` are the paper's)."""
    d = r["dataset"]
    kind = r.get("model", "paper")
    lines = [f"# torch4dtree fit: {d['path']}", "", f"Model: {MODEL_NAMES[kind]}.", "",
             f"{d['sequences']} 4D trees, {d['frames']} frames (days {d['time_min']:.4g}..{d['time_max']:.4g}).",
             *(_organ_markdown(r) if kind == "organs" else _paper_markdown(r)), "", "## Timings (s)", ""]
    lines += [f"* {k}: {v:.3f}" for k, v in r["seconds"].items()]
    if r.get("figures"):
        lines += ["", "## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in r["figures"]]
    return "\n".join(lines) + "\n"


def time_columns(seq: Any, columns: int = FIGURE_COLUMNS) -> Any:
    """The frames of a 4D tree at ``columns`` evenly spaced indices, first and last included (a figure's columns;
    fewer if the sequence is shorter).

    Example (any sequence indexable by a list of indices, as a :class:`~torch4dtree.trees.TreeSequence`):
        >>> import numpy as np
        >>> time_columns(np.arange(10), 4)
        array([0, 3, 6, 9])
    """
    n = len(seq)
    idx = sorted({round(j * (n - 1) / max(columns - 1, 1)) for j in range(columns)})
    return seq[idx]


def age_columns(seq: Any, columns: int = FIGURE_COLUMNS) -> Any:
    """The frames of a 4D tree nearest to ``columns`` evenly spaced normalised ages (``(t - t_first) / (t_last -
    t_first)``), so that rows of plants scanned on different days show the same ages; repeated frames are dropped.

    Example:
        >>> from torch4dtree.data import synthetic_plant
        >>> seq = synthetic_plant("maize", seed=0, n_frames=6, T=8).sequence
        >>> len(age_columns(seq, 3)), bool(age_columns(seq, 3).times[-1] == seq.times[-1])
        (3, True)
    """
    import torch

    t = seq.times.to(torch.float64)
    span = float(t[-1] - t[0])
    age = (t - t[0]) / span if span > 0 else torch.zeros_like(t)
    idx = sorted({int((age - j / max(columns - 1, 1)).abs().argmin()) for j in range(columns)})
    return seq[idx]


def _titled(title: str, note: str | None) -> str:
    return f"{title}\n{note}" if note else title


def write_sample_figure(model: Any, out: Path, size: int, seed: int, n_samples: int = 3, note: str | None = None,
                        real: Sequence[Any] = (), name: str = "samples.png") -> str:
    """``name`` (``samples.png``) in ``out``: ``n_samples`` samples of ``model`` (either model; ``seed``), one row
    each, and below them up to as many ``real`` plants (e.g. the training plants), at the same normalised ages in
    columns, one camera and one scale, each cell captioned with its time and a scale bar below
    (:func:`.figures.samples_figure`; ``size`` pixels of a cell's longer side, ``note`` a second title line).
    Returns the path written."""
    from .figures import samples_figure

    return str(samples_figure(model, real, out / name, seed, n_samples, note=note, cell=size))


def write_model_figures(model: Any, out: Path, size: int, seed: int, n_samples: int = 3, note: str | None = None,
                        real: Sequence[Any] = (), samples_name: str = "samples.png") -> list[str]:
    """``mean.png``, ``modes.png`` and the samples (``samples_name``) in ``out`` for a
    :class:`~torch4dtree.model.FourDTreeModel`, the samples only for an :class:`~torch4dtree.model.OrganModel` (module
    doc; ``size`` pixels per grid cell, ``seed`` of the samples); ``note`` (e.g. what the model was fitted on) is a
    second title line of each. Returns the paths written. ``real`` plants are shown below the samples
    (:func:`write_sample_figure`)."""
    from ..render import render_grid, save_image

    if model_kind(model) == "organs":
        return [write_sample_figure(model, out, size, seed, n_samples, note, real, samples_name)]
    written = []
    mean = model.decode_trajectories(model.mean.trajectory[None].to(model.pca.mean), ["mean"])[0]
    sub = time_columns(mean)
    img = render_grid([sub], row_labels=["4D mean"], col_labels=[f"t = {t:.3g}" for t in sub.times.tolist()],
                      title=_titled("mean 4D tree", note), size=size, color="label")
    written.append(str(save_image(out / "mean.png", img)))
    rows, labels = [], []
    for i, mode in enumerate(model.modes(MODE_TAUS, modes=min(FIGURE_MODES, model.n_modes))):
        for t, seq in zip(MODE_TAUS, mode):
            rows.append(time_columns(seq))
            labels.append(f"mode {i + 1}, {t:+.0f} sd")
    img = render_grid(rows, row_labels=labels, title=_titled("modes of variation (rows) over time (columns)", note),
                      size=size, color="label")
    written.append(str(save_image(out / "modes.png", img)))
    written.append(write_sample_figure(model, out, size, seed, n_samples, note, real, samples_name))
    return written


def write_model_report(model: Any, out: Path, dataset: str | Path, seqs: Sequence[Any], seconds: dict[str, float],
                       figures: bool = True, size: int = 256, seed: int = 0) -> dict[str, Any]:
    """Write the figures (with ``figures``; :func:`write_model_figures`), ``report.json`` and ``report.md`` of
    ``model`` (either model) into the folder ``out`` (existing files are not replaced); returns the report
    (:func:`model_report`, with ``figures``: their paths)."""
    from ..io.files import write_text_safely

    report = model_report(model, dataset, seqs, seconds)
    if figures:
        t0 = time.perf_counter()
        report["figures"] = write_model_figures(model, out, size, seed, real=seqs)
        report["seconds"]["figures"] = time.perf_counter() - t0
    write_text_safely(out / "report.json", json.dumps(report, indent=2))
    write_text_safely(out / "report.md", model_report_markdown(report))
    return report
