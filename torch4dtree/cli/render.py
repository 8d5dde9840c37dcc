"""``torch4dtree render PATH --out FILE``: a tree, a sequence or a dataset to PNG / GIF / MP4 (offscreen)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..render.options import COLOR_MODES, IMAGE_SUFFIXES, VIDEO_SUFFIXES, VIEWS, RenderOptions
from .options import UsageError, add_config_arguments, check_output_file, config_from_args, positive_float, positive_int

# video defaults: frames per second, and video frames per interval between two scans (interpolated)
FPS = 12.0
FRAMES_PER_SCAN = 8
ORBIT_FRAMES = 48  # one turn around a single tree: 4 s at 12 fps
MAX_COLUMNS = 6  # a sequence picture wraps into rows of at most this many frames


def _parse_size(text: str) -> tuple[int, int]:
    try:
        parts = [int(p) for p in text.lower().replace("*", "x").split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 8:
        raise argparse.ArgumentTypeError(f"size must be WIDTH or WIDTHxHEIGHT (>= 8 pixels), got {text!r}")
    return parts[0], parts[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``torch4dtree render PATH --out FILE``."""
    parser.add_argument("path", type=Path,
                        help="a tree file (.swc, .mat), a sequence folder (frames over time) or a dataset folder "
                             "(one sequence folder per 4D tree, each framed on its own)")
    parser.add_argument("--out", "-o", type=Path, required=True, metavar="FILE",
                        help="output .png / .jpg (a tree; a row of frames for a sequence; rows x time for a "
                             "dataset), .gif or .mp4 (a video over time; a turn around the plant for one tree); its "
                             "folder must exist")
    parser.add_argument("--size", type=_parse_size, default=None, metavar="WxH",
                        help="pixels of a frame or grid cell, WIDTH or WIDTHxHEIGHT (default: shaped like the "
                             "plants, longer side 512 for one tree or sequence, 384 per plant of a dataset video, "
                             "256 per grid cell)")
    parser.add_argument("--view", choices=VIEWS, default="front", help="camera view (default: %(default)s)")
    parser.add_argument("--elevation", type=float, default=RenderOptions.elevation, metavar="DEGREES",
                        help="camera elevation in degrees (default: %(default)s)")
    parser.add_argument("--fps", type=positive_float, default=FPS,
                        help="video frames per second (default: %(default)s)")
    parser.add_argument("--frames", type=positive_int, default=None, metavar="N",
                        help=f"video frames (default: {FRAMES_PER_SCAN} per interval between scans, evenly spaced "
                             f"in time; {ORBIT_FRAMES} for a turn around one tree)")
    parser.add_argument("--no-interpolate", dest="interpolate", action="store_false",
                        help="videos show the latest scan at each frame's time instead of the geodesic between the "
                             "two scans around it (default: interpolate, one tree registration per pair of scans)")
    parser.add_argument("--color", choices=COLOR_MODES, default="layer",
                        help="colour branches by layer (red, blue, yellow, purple...) or by label (branch "
                             "identities from the SWC type column; equal labels share a colour) (default: "
                             "%(default)s)")
    parser.add_argument("--title", default=None,
                        help="title above grid images and videos (default: the sequence's name for a sequence image, "
                             "none otherwise)")
    parser.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")
    add_config_arguments(parser)


def _shared_times(seqs: list[Any]) -> bool:
    import torch

    return all(len(s) == len(seqs[0]) and torch.allclose(s.times, seqs[0].times) for s in seqs)


def _time_labels(times: Any, n: int) -> list[str]:
    """Labels of ``n`` evenly spaced video times over ``times`` (a sequence's scan times)."""
    import numpy as np

    from ..render.frames import format_time

    t = times.detach().cpu().double().numpy()
    return [format_time(float(x)) for x in (np.linspace(t[0], t[-1], n) if n > 1 else t[-1:])]


def run(args: argparse.Namespace) -> int:
    """Run ``torch4dtree render``; returns the process exit code (errors go to stderr)."""
    import numpy as np

    from ..io import read_dataset, read_sequence, read_tree
    from ..io.dataset import is_sequence_folder
    from ..render.camera import prepare_camera
    from ..render.frames import (
        fit_size,
        format_time,
        render_grid,
        render_sequence,
        render_trees,
        save_image,
        save_video,
    )
    from ..render.geometry import tree_geometry
    from ..render.gl import draw_frames
    from ..render.text import compose

    out: Path = args.out
    video = out.suffix.lower() in VIDEO_SUFFIXES
    check_output_file(out, args.overwrite, IMAGE_SUFFIXES + VIDEO_SUFFIXES, "--out")
    # label colouring reads branch identities from the SWC type column (as synthetic plants store them)
    load = replace(config_from_args(args).load_options(), labels_from_type=args.color == "label")
    path: Path = args.path
    common = dict(view=args.view, color=args.color, elevation=args.elevation)
    described = ""
    if path.is_file():
        tree = read_tree(path, load)
        if tree is None:
            raise UsageError(f"{path}: empty tree file")
        size = args.size or fit_size([tree], 512, view="orbit" if video else args.view, elevation=args.elevation)
        if video:  # one tree: turn around it
            n = args.frames or ORBIT_FRAMES
            opts = RenderOptions(size=size, **{**common, "view": "orbit"})
            framing, r0, rmin = prepare_camera([tree], n, opts)
            frames = draw_frames(tree_geometry(tree, opts, r0, rmin), [0] * n, framing, opts)
            described = f"{n} frames, one turn"
        else:
            frames = render_trees(tree, size=size, **common)
    elif path.is_dir() and is_sequence_folder(path):
        seq = read_sequence(path, load).sequence
        if video:
            n = args.frames or (FRAMES_PER_SCAN * (len(seq) - 1) + 1)
            size = args.size or fit_size([seq], 512, **common)
            frames = render_sequence(seq, n, size=size, interpolate=args.interpolate, **common)
            labels = _time_labels(seq.times, n)
            frames = np.stack([compose(f[None, None], None, None, args.title or seq.name, lab)
                               for f, lab in zip(frames, labels)])
            described = f"{n} frames from {format_time(float(seq.times[0]))} to {float(seq.times[-1]):g}"
        else:
            cols = [format_time(t) for t in seq.times.tolist()]
            size = args.size or fit_size([seq], 256, **common)
            per_row = -(-len(seq) // -(-len(seq) // MAX_COLUMNS))  # balanced rows of at most MAX_COLUMNS
            frames = render_grid([seq], col_labels=cols, title=args.title or seq.name, size=size, wrap=per_row,
                                 **common)
    elif path.is_dir():
        seqs = [ls.sequence for ls in read_dataset(path, load)]
        names = [s.name for s in seqs]
        shared = _shared_times(seqs)
        longest = max(len(s) for s in seqs)
        # one camera per plant: tomatoes and maize differ in size too much to share one
        if video:
            n = args.frames or (FRAMES_PER_SCAN * (longest - 1) + 1)
            size = args.size or fit_size(seqs, 384, share_camera=False, **common)
            labels = _time_labels(seqs[0].times, n) if shared else [f"{k / max(n - 1, 1):.0%} of each plant's time"
                                                                   for k in range(n)]
            frames = render_grid(seqs, row_labels=names, title=args.title, video=True, n_frames=n,
                                 share_camera=False, size=size, frame_labels=labels, interpolate=args.interpolate,
                                 **common)
            described = f"{n} frames" + (f" from {format_time(float(seqs[0].times[0]))} to "
                                          f"{float(seqs[0].times[-1]):g}" if shared else "")
        else:
            size = args.size or fit_size(seqs, 256, share_camera=False, **common)
            cols = [format_time(t) for t in seqs[0].times.tolist()] if shared else None
            frames = render_grid(seqs, row_labels=names, col_labels=cols, title=args.title, share_camera=False,
                                 size=size, **common)
    else:
        raise FileNotFoundError(f"{path}: no such file or folder")
    if video:
        save_video(out, frames, fps=args.fps, overwrite=args.overwrite)
        h, w = frames.shape[1:3]
        print(f"wrote {out} ({w}x{h}, {described}, {len(frames) / args.fps:.1f} s at {args.fps:g} fps)")
    else:
        image = frames[0] if frames.ndim == 4 else frames
        save_image(out, image, overwrite=args.overwrite)
        print(f"wrote {out} ({image.shape[1]}x{image.shape[0]})")
    return 0
