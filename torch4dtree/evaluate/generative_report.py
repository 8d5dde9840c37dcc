"""The generative section's lines of ``report.md`` (:mod:`torch4dtree.evaluate.generative` measures them): the
organ model (the default of ``fit``) and the paper's model side by side, with their baselines."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .stats import fmt, md_table

__all__ = ["markdown"]

# rows of the 4D-metric table whose verdicts are given, and the baselines each is compared with
VERDICTS = {"organs": ("memorise_encoded", "mean"), "model": ("memorise", "paper_scalar", "mean")}
MODEL_NAMES = {"organs": "The organ model", "model": "The paper's model"}
EVENT_NAMES = {"organs": "organ model's samples", "model": "paper model's samples", "training": "training plants",
               "held_out": "held-out plants"}


def _pm(s: dict[str, float], percent: bool = False) -> str:
    d = 2 if percent else 3
    return f"{fmt(s['mean'], d, percent)} ± {fmt(s['std'], d, percent)}"


def _nna_gap(x: dict[str, Any]) -> float:
    """How far 1-NNA's accuracies on samples and on real plants are from 50 % (mean of both): a collapse (100 % / 0 %)
    reaches 1-NNA 50 % but is as far from ideal as separable sets."""
    return (abs(x["nna_samples"]["mean"] - 0.5) + abs(x["nna_real"]["mean"] - 0.5)) / 2


def _verdicts(r: dict[str, Any]) -> list[str]:
    """Plain sentences where each model loses to a baseline (on the means; 1-NNA by :func:`_nna_gap`)."""
    g = r["generators"]
    out = []
    badness: tuple[tuple[str, Callable[[dict[str, Any]], float]], ...] = (
        ("MMD", lambda x: x["mmd"]["mean"]), ("COV", lambda x: -x["cov"]["mean"]), ("1-NNA", _nna_gap))
    for model, baselines in VERDICTS.items():
        if model not in g:
            continue
        for label, bad in badness:
            better = [b for b in baselines if b in g and bad(g[b]) < bad(g[model])]
            if better:
                out.append(f"{MODEL_NAMES[model]}, {label}: beaten by {', '.join(better)}.")
    rec = r["reconstruction"]
    if rec["held_out"]["mean"] > rec["held_out_nearest_training"]["mean"]:
        out.append("Reconstruction: held-out plants are farther from their reconstruction than from the nearest "
                   "training plant.")
    f = r["forecast"]
    if f["plants"]:
        for b, what in (("last", "the last observed frame"), ("mean", "the 4D mean")):
            for space, label in ((f, "layout"), (f["tree_pca"], "tree-PCA coordinates")):
                if space["model"]["mean"] >= space[b]["mean"]:
                    out.append(f"Forecast of the paper's model ({label}): its mean error is not below {what}'s.")
    of = r.get("organ_forecast", {})
    if of.get("plants"):
        for b, what in (("last", "the last observed frame"), ("mean", "the 4D mean")):
            if of["organs"]["mean"] >= of[b]["mean"]:
                out.append(f"Forecast of the organ model: its mean error is not below {what}'s.")
    return out or ["Neither model is beaten by a baseline on these means."]


def _generator_table(g: dict[str, Any], r: dict[str, Any]) -> list[str]:
    gs = r["generators"]
    return md_table(["generator", "MMD", "COV", "1-NNA", "1-NNA samples / real", "what"],
                    [[name, _pm(gs[name]["mmd"]), _pm(gs[name]["cov"], True), _pm(gs[name]["nna"], True),
                      f"{fmt(gs[name]['nna_samples']['mean'], 2, True)} / "
                      f"{fmt(gs[name]['nna_real']['mean'], 2, True)}", g["generators"].get(name, name)]
                     for name in gs])


def _median_worst(s: dict[str, float], worst: str, percent: bool = False) -> str:
    """``median (worst)`` over draws; ``worst`` the summary key of the worst draw (``min`` or ``max``)."""
    d = 2 if percent else 3
    if s["n"] <= 1:
        return fmt(s["median"], d, percent)
    return f"{fmt(s['median'], d, percent)} ({fmt(s[worst], d, percent)})"


def _morpho_table(g: dict[str, Any], mo: dict[str, Any]) -> list[str]:
    ages = list(next(iter(mo.values())).get("worst_by_age", {}))
    return ["", "Morphometrics (decoded samples against the held-out plants; length, height, spread, tips, branch "
            "points at ages 1/4 to 1; each draw as many samples as held-out plants; median over draws (worst draw); "
            "worst median ratio: min(ratio, 1 / ratio) over the features, 1 ideal; the memorising generator's one "
            "draw is the training plants, the scale; 1-NNA ideally 50 %):", "",
            *md_table(["generator", "draws", "worst median ratio", *(f"@ {u}" for u in ages), "KS max", "1-NNA",
                       "what"],
                      [[name, str(mo[name].get("draws", "-")), _median_worst(mo[name]["worst_ratio"], "min"),
                        *(_median_worst(mo[name]["worst_by_age"][u], "min") for u in ages),
                        _median_worst(mo[name]["ks_max"], "max"), _median_worst(mo[name]["one_nna"], "max", True),
                        g["generators"].get(name, name)] for name in mo])]


def _events_table(ev: dict[str, Any]) -> list[str]:
    return ["", "Organs between consecutive frames (identities from the within-sequence registration; per organ "
            "and frame step; shrink: more than 10 % shorter):", "",
            *md_table(["4D trees", "shrink", "vanish", "organ steps"],
                      [[EVENT_NAMES.get(who, who), fmt(e["shrink"], 2, True), fmt(e["vanish"], 2, True),
                        f"{e['organ_steps']:.0f}"] for who, e in ev.items()])]


def _forecast_tables(r: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    f = r["forecast"]
    if f["plants"]:
        fp = f["tree_pca"]
        lines += md_table(["forecast of the paper's model (second half)", "tree distance in the layout",
                           "in tree-PCA coordinates", "model wins (layout)"],
                          [["paper's model", _pm(f["model"]), _pm(fp["model"]), "-"],
                           ["last observed frame stays", _pm(f["last"]), _pm(fp["last"]),
                            f"{f['wins_vs_last']} / {f['plants']}"],
                           ["4D mean at the same age", _pm(f["mean"]), _pm(fp["mean"]),
                            f"{f['wins_vs_mean']} / {f['plants']}"]]) + [""]
    of = r.get("organ_forecast", {})
    if of.get("plants"):
        fl = of["final_length"]
        lines += md_table(["forecast of the organ model (second half; guesses written in the layout with the "
                           "observed frames)", "tree distance in the layout", "final total length, relative error",
                           "organ model wins"],
                          [[f"organ model ({of.get('point', 'mean of its continuations')})", _pm(of["organs"]),
                            _pm(fl["organs"], True), f"{of['wins_vs_both']} / {of['plants']} against both"],
                           *([["organ model, mean of its continuations", _pm(of["organs_mean"]), "-",
                               f"{of['mean_wins_vs_both']} / {of['plants']} against both"]] if "organs_mean" in of
                             else []),
                           *([["organ model, one continuation", _pm(of["organs_draw"]), "-",
                               f"{of['draw_wins_vs_both']} / {of['plants']} against both"]] if "organs_draw" in of
                             else []),
                           ["last observed frame stays", _pm(of["last"]), _pm(fl["last"], True),
                            f"{of['wins_vs_last']} / {of['plants']}"],
                           ["4D mean at the same age", _pm(of["mean"]), "-",
                            f"{of['wins_vs_mean']} / {of['plants']}"]]) + [""]
    return lines


def markdown(report: dict[str, Any]) -> list[str]:
    """The section's lines of ``report.md``."""
    g = report.get("generative")
    if not g:
        return []
    lines = ["## Generative models (held-out plants; beyond the paper)", ""]
    if g["source"] is None:
        return lines + ["No data source.", ""]
    lines += [f"Source `{g['source']}`" + (f" (skipped: {', '.join(g['skipped_sources'])})" if g["skipped_sources"]
                                         else "") + ". Each fold is held out once and both models are fit on the "
              "other plants, or (a held-out folder) fit on the data folder's plants. "
              "Ground metric: the 4D distance after temporal registration of trajectories in each fold's "
              "slot layout of the paper's model (tree PCA plus what it misses of the held-out frames); the organ "
              "model's samples and, for its reference row, the training plants are written in that layout as the "
              "held-out plants are. Each draw has as many samples as held-out plants; MMD lower is better, COV "
              "higher, 1-NNA ideally 50 % (its accuracy on samples / on real plants beside it). With a handful of "
              "plants these are coarse checks, not a ranking.", ""]
    for kind, r in g["kinds"].items():
        lines += [f"### {kind}", ""]
        if "skipped" in r:
            lines += [f"Skipped: {r['skipped']}.", ""]
            continue
        folds = r["folds"]
        lines += [f"{r['plants']} plants, {r.get('split', f'{len(folds)} fold(s)')}: " + "; ".join(
            f"{len(f['held_out'])} held out / {len(f['train'])} fit, {f['modes']} mode(s), {f['draws']} draws"
            for f in folds) + ".", ""]
        lines += _generator_table(g, r)
        if r.get("morphometrics"):
            lines += _morpho_table(g, r["morphometrics"])
        if r.get("organ_events"):
            lines += _events_table(r["organ_events"])
        s, nv, rec = r["sanity"], r["novelty"], r["reconstruction"]
        lines += ["", f"Held-out plants are {_pm(r['held_out_pairs'])} apart and {_pm(rec['held_out_to_mean'])} "
                  "from the 4D mean: where the first is larger, a generator that stays near the mean makes every "
                  "real plant's nearest neighbour a sample and reaches 1-NNA 50 % by collapse (samples 100 % / "
                  "real 0 %).",
                  "", f"Sanity (training set memorised, against itself): MMD {fmt(s['mmd'])}, COV "
                  f"{fmt(s['cov'], 2, True)}, 1-NNA {fmt(s['nna'], 2, True)} (must be 0, 100 %, 0 %). "
                  "Novelty (share of samples closer to a training plant than the median training nearest-neighbour "
                  "distance / 4): " + ", ".join(f"{k} {fmt(v['share_closer'], 2, True)} (threshold "
                                                f"{fmt(v['threshold'])})" for k, v in nv.items()) + ".", ""]
        lines += md_table(["reconstruction by the paper's model (4D distance)", "held out", "training"],
                          [["through the model", _pm(rec["held_out"]), _pm(rec["training"])],
                           ["the 4D mean alone", _pm(rec["held_out_to_mean"]), _pm(rec["training_to_mean"])],
                           ["nearest training plant", _pm(rec["held_out_nearest_training"]), "0"]])
        lines += ["", "Held-out mass outside the layout: the paper's model drops branches that match no slot, "
                  f"{_pm(rec['outside'])} (tree distance, RMS over frames), {_pm(rec['outside_share'], True)} of "
                  "the frames' squared norm; the organ model cannot write organs at botanical keys no training "
                  f"plant had, {_pm(rec['outside_keys_share'], True)} of the squared SRVF norm (summed length) "
                  "over frames. Held-out frames off the training tree PCA (in the ground metric, out of the paper "
                  f"model's reach): {_pm(rec['off_tree_space'])} (RMS), {_pm(rec['off_tree_space_share'], True)} "
                  "of their squared spread about the tree mean.", ""]
        lines += _forecast_tables(r)
        lines += ["**Where the models lose:** " + " ".join(_verdicts(r)), ""]
    return lines
