"""Offscreen rendering of trees and 4D trees (pyrender through EGL): images, videos, grids.

``pyrender``, ``trimesh``, ``imageio`` and ``Pillow`` are imported lazily, so importing this package
never needs OpenGL.
"""

from .frames import (
    branch_colors,
    close_renderer,
    render_grid,
    render_sequence,
    render_trees,
    save_frames,
    save_image,
    save_video,
    tree_meshes,
)
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
    "VIDEO_SUFFIXES", "VIEWS", "RenderOptions", "branch_colors", "close_renderer", "render_grid", "render_sequence",
    "render_trees", "save_frames", "save_image", "save_video", "tree_meshes",
]
