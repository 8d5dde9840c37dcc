"""Load the Pheno4D subset and compare the longest-path rule on the raw SWC skeletons with the
hand-corrected `.mat` trees of the paper, day by day.

    python scripts/pheno4d_report.py [--data ../shared/data/pheno4d] [--min-branch-length 0]
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

from torch4dtree.io import LoadOptions, read_sequence

PAIRS = {"tomato_1": "tom_1_seq", "tomato_2": "tom_2_seq", "Tomato_3": "tom_3_seq", "Tomato_4": "tom_4_seq",
         "Tomato_5": "tom_5_seq", "Maize01": "maize01_seq", "Maize02": "maize02_seq", "Maize03": "maize03_seq",
         "Maize04": "maize04_seq"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "pheno4d"))
    ap.add_argument("--min-branch-length", type=float, default=0.0)
    ap.add_argument("--T", type=int, default=64)
    args = ap.parse_args()
    data = Path(args.data)
    swc_opts = LoadOptions(T=args.T, repair=True, min_branch_length=args.min_branch_length)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        swc = {p: read_sequence(data / "swc" / p, swc_opts).sequence for p in PAIRS}
    t_swc = time.perf_counter() - t0
    t0 = time.perf_counter()
    mat = {p: read_sequence(data / "mat" / m, LoadOptions(T=args.T)).sequence for p, m in PAIRS.items()}
    t_mat = time.perf_counter() - t0
    n_swc = sum(len(s) for s in swc.values())
    n_mat = sum(len(s) for s in mat.values())
    print(f"loaded {n_swc} SWC frames in {t_swc:.2f} s, {n_mat} .mat frames in {t_mat:.2f} s (T={args.T})")
    print(f"{'plant':<10} {'day':>4} {'SWC branches/layer':<26} {'.mat branches/layer':<26} {'SWC h':>6} {'mat h':>6}")
    total_swc = total_mat = 0
    for plant in PAIRS:
        s, m = swc[plant], mat[plant]
        m_by_day = {float(t): i for i, t in enumerate(m.times)}
        s_layers, m_layers = s.frames.branches_per_layer(), m.frames.branches_per_layer()
        s_h, m_h = s.frames.height(), m.frames.height()
        for i, t in enumerate(s.times.tolist()):
            j = m_by_day.get(t)
            mat_txt = str(m_layers[j]) if j is not None else "-"
            mh = f"{float(m_h[j]):6.1f}" if j is not None else "     -"
            if j is not None:
                total_swc += sum(s_layers[i])
                total_mat += sum(m_layers[j])
            print(f"{plant:<10} {int(t):>4} {str(s_layers[i]):<26} {mat_txt:<26} {float(s_h[i]):6.1f} {mh}")
    print(f"branches on days present in both: SWC longest-path rule {total_swc}, .mat {total_mat} "
          f"(ratio {total_swc / total_mat:.2f})")


if __name__ == "__main__":
    main()
