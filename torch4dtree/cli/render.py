"""``torch4dtree render PATH --out FILE``: a tree, a sequence or a dataset to PNG / GIF / MP4 (offscreen)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import add_config_arguments, config_from_args
from ..render.options import COLOR_MODES, VIDEO_SUFFIXES, VIEWS, RenderOptions
from ..trees.structures import TreeError


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
    parser.add_argument("--out", "-o", type=Path, required=True,
                        help="output .png (a tree; a row of frames for a sequence; rows x time for a dataset), "
                             ".gif or .mp4 (a video over time; a turn around the plant for one tree)")
    parser.add_argument("--size", type=_parse_size, default=None,
                        help="WIDTH or WIDTHxHEIGHT in pixels of a frame, or of a grid cell "
                             "(default 512 for single frames and videos, 256 per grid cell)")
    parser.add_argument("--view", choices=VIEWS, default="front", help="camera view (default: front)")
    parser.add_argument("--elevation", type=float, default=RenderOptions.elevation,
                        help="camera elevation in degrees (default: %(default)s)")
    parser.add_argument("--fps", type=float, default=4.0, help="video frames per second (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=None,
                        help="video frames (default: one per time point; 36 for a turn around one tree)")
    parser.add_argument("--color", choices=COLOR_MODES, default="layer",
                        help="colour branches by layer (red, blue, yellow, purple...) or by label "
                             "(branch identities from the SWC type column; equal labels share a colour)")
    parser.add_argument("--title", default=None, help="title written above grid images and videos")
    parser.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")
    add_config_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``torch4dtree render``; returns the process exit code (errors go to stderr)."""
    from ..io import DatasetError, read_dataset, read_sequence, read_tree
    from ..io.dataset import is_sequence_folder
    from ..render.frames import (
        IMAGE_SUFFIXES,
        _compose,
        _prepare,
        _render_frames,
        _tree_geometry,
        render_grid,
        render_sequence,
        render_trees,
        save_image,
        save_video,
    )

    out: Path = args.out
    suffix = out.suffix.lower()
    video = suffix in VIDEO_SUFFIXES
    try:
        if not video and suffix not in IMAGE_SUFFIXES:
            raise ValueError(f"--out must end in .png, .jpg, .gif or .mp4, got {out.name!r}")
        if out.exists() and not args.overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
        # label colouring reads branch identities from the SWC type column (as synthetic plants store them)
        load = replace(config_from_args(args).load_options(), labels_from_type=args.color == "label")
        path: Path = args.path
        common = dict(view=args.view, color=args.color, elevation=args.elevation)
        single = args.size or (512, 512)
        cell = args.size or (256, 256)
        if path.is_file():
            tree = read_tree(path, load)
            if tree is None:
                raise DatasetError(f"{path}: empty tree file")
            if video:  # one tree: turn around it
                n = args.frames or 36
                opts = RenderOptions(size=single, **{**common, "view": "orbit"})
                framing, r0, rmin = _prepare([tree], n, opts)
                frames = _render_frames(_tree_geometry(tree, opts, r0, rmin), [0] * n, framing, opts)
            else:
                frames = render_trees(tree, size=single, **common)
        elif path.is_dir() and is_sequence_folder(path):
            seq = read_sequence(path, load).sequence
            if video:
                frames = render_sequence(seq, args.frames, size=single, caption=True, **common)
                if args.title:
                    frames = np.stack([_compose(f[None, None], None, None, args.title) for f in frames])
            else:
                cols = [f"t = {t:g}" for t in seq.times.tolist()]
                frames = render_grid([seq], col_labels=cols, title=args.title or seq.name, size=cell, **common)
        elif path.is_dir():
            loaded = read_dataset(path, load)
            seqs = [ls.sequence for ls in loaded]
            names = [s.name for s in seqs]
            # one camera per plant: tomatoes and maize differ in size too much to share one
            frames = render_grid(seqs, row_labels=names, title=args.title, video=video, n_frames=args.frames,
                                 share_camera=False, size=cell, **common)
        else:
            raise DatasetError(f"{path}: no such file or folder")
        if video:
            save_video(out, frames, fps=args.fps, overwrite=args.overwrite)
        else:
            save_image(out, frames[0] if frames.ndim == 4 else frames, overwrite=args.overwrite)
    except (FileExistsError, ValueError, TreeError, RuntimeError, OSError) as e:
        print(f"torch4dtree render: error: {e}", file=sys.stderr)
        return 1
    print(out)
    return 0

