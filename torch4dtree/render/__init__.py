"""Offscreen rendering of trees and 4D trees (pyrender through EGL): images, videos, grids.

``pyrender``, ``trimesh``, ``imageio``, ``Pillow`` (and torch) are imported lazily, so importing this package
never needs OpenGL and stays cheap for the command line.
"""

from .compare import render_comparison
from .frames import (
    branch_colors,
    close_renderer,
    fit_size,
    format_time,
    render_grid,
    render_sequence,
    render_trees,
    save_frames,
    save_image,
    save_video,
    tree_meshes,
)
from .interpolate import interpolate_sequence
from .options import (
    COLOR_MODES,
    GL_PACKAGES,
    IMAGE_SUFFIXES,
    LABEL_PALETTE,
    LAYER_COLORS,
    UNLABELLED_COLOR,
    VIDEO_SUFFIXES,
    VIEWS,
    RenderOptions,
)

__all__ = [
    "COLOR_MODES", "GL_PACKAGES", "IMAGE_SUFFIXES", "LABEL_PALETTE", "LAYER_COLORS", "UNLABELLED_COLOR",
    "VIDEO_SUFFIXES", "VIEWS", "RenderOptions", "branch_colors", "close_renderer", "fit_size", "format_time",
    "interpolate_sequence", "render_comparison", "render_grid", "render_sequence", "render_trees", "save_frames",
    "save_image", "save_video", "tree_meshes",
]
