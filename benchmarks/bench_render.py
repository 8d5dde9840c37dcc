"""Rendering speed on the largest Pheno4D tomato: a 10-frame 512 x 512 MP4 (target: under 10 s).

Run:  python benchmarks/bench_render.py [--size 512] [--frames 10] [--plant Tomato_5] [--out DIR]

Prints the time of each stage (load, first GL context, meshes, frames, encoding) and the total,
and, as a reference measured in the same run, the time of one naive per-segment trimesh build
(what the vectorised tube builder replaces).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from torch4dtree.io import LoadOptions, read_sequence
from torch4dtree.render.camera import prepare_camera
from torch4dtree.render.frames import RenderOptions, render_sequence, save_video, time_index
from torch4dtree.render.geometry import tree_geometry
from torch4dtree.render.gl import draw_frames

PHENO4D = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pheno4d"


def naive_tubes(points: np.ndarray, radius: float) -> float:
    """Seconds to build the same tubes as one trimesh cylinder per segment (the slow way)."""
    import trimesh

    t0 = time.perf_counter()
    parts = []
    for branch in points:
        for a, b in zip(branch[:-1], branch[1:]):
            if np.linalg.norm(b - a) > 0:
                parts.append(trimesh.creation.cylinder(radius=radius, segment=[a, b], sections=8))
    trimesh.util.concatenate(parts)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default=None, help="swc plant folder (default: the tomato with most nodes)")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None, help="keep the video in this folder")
    args = ap.parse_args()

    swc = PHENO4D / "swc"
    if args.plant is None:  # the tomato sequence with the most SWC nodes
        def nodes(d: Path) -> int:
            return sum(sum(1 for ln in f.open() if ln.strip() and not ln.startswith("#")) for f in d.glob("*.swc"))

        tomatoes = [d for d in swc.iterdir() if d.name.lower().startswith("tomato")]
        folder = max(tomatoes, key=nodes)
    else:
        folder = swc / args.plant

    t0 = time.perf_counter()
    seq = read_sequence(folder, LoadOptions(repair=True)).sequence
    t_load = time.perf_counter() - t0
    fr = seq.frames
    print(f"{folder.name}: {len(seq)} frames, {fr.points.shape[0]} branches x T={fr.T}, layers per frame "
          f"{[len(b) for b in fr.branches_per_layer()]}")

    t0 = time.perf_counter()
    render_sequence(seq[[0]], size=16)  # first EGL context + shader compilation, paid once per process
    t_gl = time.perf_counter() - t0

    opts = RenderOptions(size=args.size)
    t0 = time.perf_counter()
    framing, r0, rmin = prepare_camera([fr], args.frames, opts)
    geoms = tree_geometry(fr, opts, r0, rmin)
    t_mesh = time.perf_counter() - t0
    n_tri = sum(len(g.faces) for g in geoms)

    which = time_index(seq.times.double().numpy(), args.frames)
    t0 = time.perf_counter()
    frames = draw_frames(geoms, which, framing, opts)
    t_frames = time.perf_counter() - t0

    # the public call end to end (what a user pays after loading), orbit so every frame is drawn
    t0 = time.perf_counter()
    orbit = render_sequence(seq, n_frames=args.frames, size=args.size, view="orbit")
    t_orbit = time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.out or Path(tmp)
        t0 = time.perf_counter()
        path = save_video(out_dir / f"{folder.name}_{args.size}.mp4", frames, fps=4, overwrite=True)
        t_mp4 = time.perf_counter() - t0
        save_video(out_dir / f"{folder.name}_{args.size}_orbit.mp4", orbit, fps=4, overwrite=True)
        size_kb = path.stat().st_size / 1024

    t_naive = naive_tubes(fr.points.double().numpy(), r0)
    total = t_load + t_gl + t_mesh + t_frames + t_mp4
    print(f"load {t_load:6.2f} s | GL context {t_gl:5.2f} s | tube meshes {t_mesh:5.3f} s ({n_tri} triangles, "
          f"naive per-segment trimesh {t_naive:.2f} s = {t_naive / max(t_mesh, 1e-9):.0f}x slower)")
    print(f"{args.frames} frames {args.size}x{args.size} front: render {t_frames:5.2f} s "
          f"({1000 * t_frames / args.frames:.0f} ms/frame, held days drawn once) | mp4 encode {t_mp4:5.2f} s "
          f"({size_kb:.0f} kB)")
    print(f"orbit (every frame drawn), render_sequence end to end: {t_orbit:5.2f} s")
    print(f"TOTAL load + GL + meshes + frames + mp4: {total:5.2f} s  (target < 10 s: "
          f"{'OK' if total < 10 else 'SLOW'})")


if __name__ == "__main__":
    main()
