"""The figures of ``torch4dtree evaluate``: small PNGs written beside ``report.md`` (and linked from it).

* ``registration.png``: two consecutive frames of one plant of the primary source (``mat`` if present, else
  ``synthetic``, else ``swc``) and the geodesic between them; a branch's colour is the branch of the later frame
  it is matched to, so matched branches share a colour, and branches matched to nothing are grey.
* ``geodesic4d.png``: the 4D geodesic between two plants of one kind (the paper's Figs. 8 and 5): rows are steps
  along the geodesic, columns are times; the top half before registration (index-order correspondence, identity
  time warp), the bottom half after the spatial and temporal registration. Colours are the common slots.
* ``mean.png``, ``modes.png``, ``samples.png``: a :class:`~torch4dtree.model.FourDTreeModel` fitted on the plants
  of one kind (:func:`.model_report.write_model_figures`).

:func:`line_plot` draws curves with Pillow (matplotlib is not a dependency) for sections that report curves.
A figure that cannot be made (no GL, too few plants) is left out with a note in ``report["figure_notes"]``: the
report of a long evaluation is never lost to a picture.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from .data import EvalData, EvalSettings, Plant4D, primary_source
from .model_report import FIGURE_COLUMNS, time_columns, write_model_figures

if TYPE_CHECKING:
    from ..temporal import SpatiotemporalRegistration
    from ..trees.registration import TreeRegistration
    from ..trees.structures import Trees

__all__ = ["FigureLayout", "correspondence_labels", "figure_layout", "index_order_registration", "line_plot",
           "primary_data", "registration_pair", "registration_row", "write_figures"]

@dataclass(frozen=True)
class FigureLayout:
    """Sizes of the figures: ``cell`` pixels per grid cell (the longer side), ``steps`` trees along a geodesic
    (ends included), ``columns`` times shown of a 4D tree, ``n_t`` time samples of the 4D geodesic and of the
    model, ``max_plants`` plants the model is fitted on (``None``: all of the kind)."""

    cell: int
    steps: int
    columns: int
    n_t: int
    max_plants: int | None


def figure_layout(settings: EvalSettings) -> FigureLayout:
    """The layout for ``settings``: tiny with ``quick``; otherwise a modest ``n_t`` (at most 16) keeps the model
    fit on Pheno4D tomato around a minute."""
    if settings.quick:
        return FigureLayout(cell=96, steps=3, columns=FIGURE_COLUMNS, n_t=min(settings.n_t, 8), max_plants=3)
    return FigureLayout(cell=160, steps=5, columns=FIGURE_COLUMNS, n_t=min(settings.n_t, 16), max_plants=None)


def primary_data(datas: Mapping[str, EvalData]) -> EvalData | None:
    """The plants the figures show (:func:`.data.primary_source`; ``None`` if there are none)."""
    name = primary_source(dict(datas))
    return datas[name] if name is not None else None


def _kind_with(data: EvalData, plants: int) -> str | None:
    """The first kind (tomato before maize) with at least ``plants`` plants of at least two frames."""
    return next((k for k in data.kinds if sum(len(p.sequence) >= 2 for p in data.by_kind(k)) >= plants), None)


def _plants_of(data: EvalData, kind: str) -> list[Plant4D]:
    return [p for p in data.by_kind(kind) if len(p.sequence) >= 2]


# ------------------------------------------------------------------------------------ registration
def registration_pair(data: EvalData) -> tuple[Plant4D, int] | None:
    """The plant and frame ``k`` of the registration figure: frames ``k`` and ``k + 1`` of the first plant of the
    first kind, its last two (the most branches, so the most correspondences to see)."""
    kind = _kind_with(data, 1)
    if kind is None:
        return None
    plant = _plants_of(data, kind)[0]
    return plant, len(plant.sequence) - 2


def correspondence_labels(res: TreeRegistration) -> tuple[Tensor, Tensor, Tensor]:
    """Colour labels of a registration: ``(moving (Nm,), reference (Nr,), slot (S,))``.

    A matched pair ``(i, j)`` gets label ``j`` in both trees, and so does slot ``j`` of the common layout (the
    geodesic's branches carry their slot as label); branches matched to a null branch get ``-1`` (grey)."""
    aligned = res.aligned
    n_ref = int((aligned.source[1] >= 0).sum())  # the reference fills slots 0..Nr-1, in its packed order
    moving = torch.full((res.gamma.shape[0],), -1, dtype=torch.long)
    reference = torch.full((n_ref,), -1, dtype=torch.long)
    slot = torch.full((aligned.q.shape[1],), -1, dtype=torch.long)
    for i, j in res.matches:
        moving[i] = reference[j] = slot[j] = j
    return moving, reference, slot


def _labelled(trees: Trees, label: Tensor) -> Trees:
    return dataclasses.replace(trees, label=label.to(trees.label.device))


def registration_row(moving: Trees, reference: Trees, res: TreeRegistration, steps: int) -> Trees:
    """What ``registration.png`` shows: the moving tree, the inside of the geodesic (``steps - 2`` trees) and the
    reference, as one batch whose labels are :func:`correspondence_labels` (matched branches share a label)."""
    from ..trees.geodesic import geodesic
    from ..trees.structures import Trees

    lab_m, lab_r, lab_slot = correspondence_labels(res)
    inside = geodesic(res, steps)[list(range(1, steps - 1))]
    parts = [_labelled(moving, lab_m)]
    if inside.num_trees:
        parts.append(_labelled(inside, lab_slot[inside.label.cpu()]))
    parts.append(_labelled(reference, lab_r))
    return Trees.cat(parts)


def _registration_figure(data: EvalData, settings: EvalSettings, lay: FigureLayout, path: Path) -> Path | None:
    from ..render import fit_size, format_time, render_grid, save_image
    from ..trees.registration import register_trees

    picked = registration_pair(data)
    if picked is None:
        return None
    plant, k = picked
    seq = plant.sequence
    a, b = seq.frames[k], seq.frames[k + 1]
    # the earlier frame onto the later one: left to right is growth, new branches grow from grey
    res = register_trees(a, b, lambdas=settings.lambdas)
    row = registration_row(a, b, res, lay.steps)
    ta, tb = (float(t) for t in seq.times[k:k + 2])
    cols = [format_time(ta)] + [f"tau = {j / (lay.steps - 1):.2f}" for j in range(1, lay.steps - 1)] + \
        [format_time(tb)]
    title = (f"{plant.name} ({data.source}): {format_time(ta)} registered onto {format_time(tb)}, geodesic between\n"
             f"matched branches share a colour, grey = matched to nothing; tree distance "
             f"{float(res.distance_before):.3g} (index order) -> {float(res.distance):.3g}")
    img = render_grid([row], col_labels=cols, title=title, color="label", size=fit_size([row], lay.cell))
    return save_image(path, img)


# ---------------------------------------------------------------------------------- 4D geodesic
def index_order_registration(res: SpatiotemporalRegistration) -> SpatiotemporalRegistration:
    """``res`` as it was before registration: the index-order correspondence of the two 4D trees (identity warps
    and rotation) and the identity time warp, so that ``.geodesic()`` is the paper's Fig. 8 (its length is
    ``res.distance_before``)."""
    from ..temporal.spatiotemporal import combine_sequences, layout_trajectories, representative_tree
    from ..trees.registration import index_order_matches

    n_t = len(res.times)
    ident_t = torch.linspace(0, 1, n_t, dtype=res.warp.dtype)
    if res.kept_index_order:  # the spatial layout already is the index-order one
        return res._replace(alpha_mov_registered=res.alpha_mov, warp=ident_t)
    A, B = res.sequences
    rep_a, rep_b = representative_tree(A), representative_tree(B)
    matches = index_order_matches(rep_b, rep_a)
    ident = torch.linspace(0, 1, rep_b.T, dtype=torch.float64).expand(rep_b.points.shape[0], -1)
    layout = combine_sequences(A, B, matches, ident, torch.eye(rep_b.dim, dtype=torch.float64), res.layout.lambdas)
    # as register4d builds its "before" state (all components: nothing of the shapes is lost)
    pca, alpha_a, alpha_b = layout_trajectories(layout, len(A), A.times, B.times, n_t, None)
    return res._replace(pca=pca, layout=layout, alpha_ref=alpha_a, alpha_mov=alpha_b, alpha_mov_registered=alpha_b,
                        alpha_mov_fine=None, matches=matches, warp=ident_t)


def _geodesic4d_figure(data: EvalData, settings: EvalSettings, lay: FigureLayout, path: Path) -> Path | None:
    from ..render import format_time, render_grid, save_image
    from ..temporal import register4d

    kind = _kind_with(data, 2)
    if kind is None:
        return None
    ref, mov = _plants_of(data, kind)[:2]
    res = register4d(ref.sequence, mov.sequence, lambdas=settings.lambdas, rotation=settings.rotation, n_t=lay.n_t,
                     cross=settings.cross_settings())
    before = index_order_registration(res)
    rows, labels = [], []
    for name, r in (("before", before), ("after", res)):
        for j, s in enumerate(r.geodesic(lay.steps)):
            rows.append(time_columns(s, lay.columns))
            labels.append(f"{name}, tau = {j / (lay.steps - 1):.2f}")
    cols = [format_time(float(t)) for t in rows[0].times]
    title = (f"4D geodesic {ref.name} -> {mov.name} ({data.source}); rows: steps along it, columns: time\n"
             f"before registration (index order, identity time warp): 4D distance {res.distance_before:.3g}; "
             f"after spatial + temporal registration: {res.distance_after_temporal:.3g}")
    img = render_grid(rows, row_labels=labels, col_labels=cols, title=title, color="label", size=lay.cell)
    return save_image(path, img)


# ---------------------------------------------------------------------------------------- model
def _model_figures(data: EvalData, settings: EvalSettings, lay: FigureLayout, out: Path) -> list[str]:
    from ..model import FourDTreeModel

    kind = _kind_with(data, 2)
    if kind is None:
        return []
    plants = _plants_of(data, kind)[:lay.max_plants]
    model = FourDTreeModel(settings.model_settings(lay.n_t))
    model.fit([p.sequence for p in plants])
    note = f"fitted on {len(plants)} {kind} plants ({data.source}), {model.n_modes} modes, n_t = {lay.n_t}"
    return write_model_figures(model, out, lay.cell, settings.seed, note=note, real=[p.sequence for p in plants])


# ------------------------------------------------------------------------------------- driver
def write_figures(report: dict, datas: dict[str, EvalData], settings: EvalSettings, out: Path) -> list[str]:
    """Write the figures (module doc) into ``out``; returns their paths. Adds ``report["timings"]["figures"]`` and,
    for each figure left out and why, ``report["figure_notes"]``."""
    data = primary_data(datas)
    notes: list[str] = []
    written: list[str] = []
    t0 = time.perf_counter()
    if data is None:
        notes.append("no plants: no figures")
    else:
        lay = figure_layout(settings)
        jobs = (("registration.png", lambda: _registration_figure(data, settings, lay, out / "registration.png")),
                ("geodesic4d.png", lambda: _geodesic4d_figure(data, settings, lay, out / "geodesic4d.png")),
                ("mean.png, modes.png, samples.png", lambda: _model_figures(data, settings, lay, out)))
        if report.get("robustness"):  # the curves of that section, when it ran
            jobs += (("robustness.png", lambda: robustness_figure(report, out / "robustness.png")),)
        for name, job in jobs:
            try:
                made = job()
            except Exception as e:  # noqa: BLE001 - a picture must not cost the report (GL missing, odd data)
                warnings.warn(f"figure {name} left out: {type(e).__name__}: {e}", stacklevel=2)
                notes.append(f"{name}: {type(e).__name__}: {e}")
                continue
            if not made:
                notes.append(f"{name}: not enough plants in the {data.source} source")
            written += [str(p) for p in ([made] if isinstance(made, Path) else made or [])]
    if notes:
        report["figure_notes"] = notes
    report.setdefault("timings", {})["figures"] = {
        "seconds": time.perf_counter() - t0, "paper_seconds": None,
        "what": "the figures (their registrations, a model fit and the rendering)"}
    return written


TICK_TOL = 1e-9  # a tick count within rounding of a whole number is that number
ROBUSTNESS_PANELS = (("noise", "node noise (sigma, % of the plant's height)"),
                     ("drop", "side branches dropped (%)"), ("split", "segments split (%)"))


def robustness_figure(report: dict, path: Path) -> Path | None:
    """The robustness curves of the report (identity precision against each perturbation's level, one curve per
    source, hierarchy mode and kind), one panel per perturbation side by side; None without a robustness section."""
    from ..render import save_image

    sources = report.get("robustness", {}).get("sources", {})
    panels = []
    for key, xlabel in ROBUSTNESS_PANELS:
        series = {f"{src} {mode} {kind}": ([100 * row["level"] for row in rows], [100 * row["precision"]
                                                                                  for row in rows])
                  for src, kinds in sources.items() for kind, r in kinds.items()
                  for mode, curves in r["curves"].items() for k, rows in curves.items() if k == key and rows}
        if series:
            panels.append(line_plot(series, title=f"identity precision (%) vs {key}", xlabel=xlabel,
                                    ylabel="precision (%)"))
    if not panels:
        return None
    return save_image(path, np.concatenate(panels, axis=1))


# ---------------------------------------------------------------------------------- line plots
def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About ``n`` round tick values (1, 2, 5 times a power of ten) covering ``[lo, hi]``.

    Example:
        >>> nice_ticks(0.0, 0.93), nice_ticks(0.0, 20.0)
        ([0.0, 0.5, 1.0], [0, 5, 10, 15, 20])
    """
    if not hi > lo:  # a constant: centred in a range 10 % of its size (a flat 100 % line sits mid-plot)
        pad = 0.05 * abs(lo) or 1.0
        lo, hi = lo - pad, hi + pad
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.floor(lo / step) * step
    return [first + i * step for i in range(int(math.ceil((hi - first) / step - TICK_TOL)) + 1)]


def line_plot(series: Mapping[str, tuple[Sequence[float], Sequence[float]]], title: str = "", xlabel: str = "",
              ylabel: str = "", size: tuple[int, int] = (560, 360)) -> np.ndarray:
    """A line chart ``(H, W, 3)`` uint8 of named curves ``{name: (x, y)}`` (non-finite points are gaps), with axes,
    round ticks, a legend and a title, drawn with Pillow (save it with :func:`torch4dtree.render.save_image`)."""
    from PIL import Image, ImageDraw

    from ..render import LABEL_PALETTE
    from ..render.text import TEXT_INK, line_height, load_font, text_width

    W, H = size
    font, small = load_font(max(11, H // 26)), load_font(max(10, H // 32))
    lh = line_height(font)
    pts = [(float(x), float(y)) for xs, ys in series.values() for x, y in zip(xs, ys)
           if math.isfinite(float(x)) and math.isfinite(float(y))]
    xs_all, ys_all = [p[0] for p in pts] or [0.0, 1.0], [p[1] for p in pts] or [0.0, 1.0]
    xt, yt = nice_ticks(min(xs_all), max(xs_all)), nice_ticks(min(ys_all), max(ys_all))

    def label(v: float) -> str:
        return f"{v:.4g}"

    left = max(text_width(label(v), small) for v in yt) + lh + 14
    top, bottom, right = (2 * lh if title else lh), 2 * lh + 10, 12
    x0, x1, y0, y1 = left, W - right, top, H - bottom  # the plotting box (y0 at the top)

    def px(x: float, y: float) -> tuple[float, float]:
        return (x0 + (x - xt[0]) / (xt[-1] - xt[0]) * (x1 - x0), y1 - (y - yt[0]) / (yt[-1] - yt[0]) * (y1 - y0))

    img = Image.new("RGB", (W, H), (255, 255, 255))
    d = ImageDraw.Draw(img)
    for v in xt:
        x, _ = px(v, yt[0])
        d.line([(x, y0), (x, y1)], fill=(225, 225, 225))
        d.text((x - text_width(label(v), small) / 2, y1 + 4), label(v), fill=TEXT_INK, font=small)
    for v in yt:
        _, y = px(xt[0], v)
        d.line([(x0, y), (x1, y)], fill=(225, 225, 225))
        d.text((x0 - 6 - text_width(label(v), small), y - lh / 2), label(v), fill=TEXT_INK, font=small)
    d.rectangle([x0, y0, x1, y1], outline=TEXT_INK)
    for k, (xs, ys) in enumerate(series.values()):
        color = tuple(int(c) for c in LABEL_PALETTE[k % len(LABEL_PALETTE)])
        run: list[tuple[float, float]] = []
        for x, y in [*zip(xs, ys), (math.nan, math.nan)]:  # a trailing gap flushes the last run
            if math.isfinite(float(x)) and math.isfinite(float(y)):
                run.append(px(float(x), float(y)))
                continue
            if len(run) > 1:
                d.line(run, fill=color, width=2)
            for cx, cy in run:
                d.ellipse([cx - 3, cy - 3, cx + 3, cy + 3], fill=color)
            run = []
    ly = y0 + 6
    for k, name in enumerate(series):  # legend: top right, inside the box
        color = tuple(int(c) for c in LABEL_PALETTE[k % len(LABEL_PALETTE)])
        tx = x1 - 8 - text_width(name, small)
        d.line([(tx - 24, ly + lh / 2), (tx - 6, ly + lh / 2)], fill=color, width=3)
        d.text((tx, ly), name, fill=TEXT_INK, font=small)
        ly += lh
    if title:
        d.text(((W - text_width(title, font)) / 2, lh / 3), title, fill=TEXT_INK, font=font)
    if xlabel:
        d.text(((x0 + x1 - text_width(xlabel, font)) / 2, H - lh - 4), xlabel, fill=TEXT_INK, font=font)
    if ylabel:  # rotated text: draw it on its own strip and turn it
        strip = Image.new("RGB", (text_width(ylabel, font) + 4, lh + 2), (255, 255, 255))
        ImageDraw.Draw(strip).text((2, 0), ylabel, fill=TEXT_INK, font=font)
        strip = strip.rotate(90, expand=True)
        img.paste(strip, (2, int((y0 + y1 - strip.height) / 2)))
    return np.asarray(img)
