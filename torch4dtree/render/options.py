"""How trees are drawn: colours, views, output formats and :class:`RenderOptions`."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

# Layer colours of the paper's figures: red main branch, blue, yellow (deep enough to read on white), purple,
# then green, orange, cyan.
LAYER_COLORS: np.ndarray = np.array(
    [[214, 39, 40], [31, 94, 214], [230, 175, 0], [148, 62, 184], [44, 160, 44], [255, 127, 14], [23, 190, 207]],
    dtype=np.uint8,
)
# Correspondence colours (label l -> LABEL_PALETTE[l % 20]): distinct, saturated, no grey.
LABEL_PALETTE: np.ndarray = np.array(
    [[230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180], [70, 240, 240],
     [240, 50, 230], [210, 245, 60], [0, 128, 128], [170, 110, 40], [128, 0, 0], [0, 0, 128],
     [128, 128, 0], [255, 225, 25], [250, 190, 212], [170, 255, 195], [220, 190, 255], [255, 215, 180],
     [0, 200, 120], [100, 60, 200]],
    dtype=np.uint8,
)
UNLABELLED_COLOR: np.ndarray = np.array([150, 150, 150], dtype=np.uint8)
VIEWS = ("front", "side", "top", "orbit")
COLOR_MODES = ("layer", "label")
VIDEO_SUFFIXES = (".gif", ".mp4")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
# Debian/Ubuntu packages that give pyrender an EGL context on Mesa's software renderer (see .ci/system-packages.sh).
GL_PACKAGES = "libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libxrender1"


@dataclass(frozen=True)
class RenderOptions:
    """How trees are drawn. Every render function accepts these fields as keyword arguments.

    Attributes:
        size: frame (or grid cell) size in pixels, ``W`` or ``(W, H)``.
        view: ``front`` (looking along +y), ``side`` (along -x), ``top`` (down the up axis) or
            ``orbit`` (the camera circles the plant over the frames).
        elevation: camera height above the horizontal plane in degrees (front, side, orbit).
        azimuth: extra turn of the camera about the up axis in degrees.
        color: ``layer`` (red main, blue, yellow, purple, ...) or ``label`` (equal labels share a
            colour from :data:`LABEL_PALETTE`, label -1 grey).
        radius: main-branch tube radius as a fraction of the largest side of the scene's bounding box.
        thinning: radius factor per layer (layer ``d`` has ``radius * thinning**d``).
        taper: how much a tube narrows from its base to its tip (0 = cylinder).
        min_pixels: smallest tube radius in pixels, so thin deep branches stay visible at small sizes.
        sides: polygon sides of a tube's cross-section.
        margin: fraction of the frame left empty on every side.
        fog: how much the farthest parts fade towards the white background (depth cue, 0 = none).
        yfov: vertical field of view in degrees (perspective camera).
        up: index of the up axis (2 = z, as in Pheno4D).
        turns: full camera turns over an orbit.
    """

    size: int | tuple[int, int] = 512
    view: str = "front"
    elevation: float = 12.0
    azimuth: float = 0.0
    color: str = "layer"
    radius: float = 0.009
    thinning: float = 0.7
    taper: float = 0.35
    min_pixels: float = 0.75
    sides: int = 8
    margin: float = 0.05
    fog: float = 0.35
    yfov: float = 30.0
    up: int = 2
    turns: float = 1.0

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise ValueError(f"view must be one of {VIEWS}, got {self.view!r}")
        if self.color not in COLOR_MODES:
            raise ValueError(f"color must be one of {COLOR_MODES}, got {self.color!r}")
        w, h = self.wh
        if w < 8 or h < 8:
            raise ValueError(f"size must be at least 8 x 8 pixels, got {self.size}")
        if self.sides < 3 or self.radius <= 0 or not 0 <= self.taper < 1 or not 0 <= self.margin < 0.5:
            raise ValueError("need sides >= 3, radius > 0, 0 <= taper < 1 and 0 <= margin < 0.5")
        if self.up not in (0, 1, 2):
            raise ValueError(f"up must be 0, 1 or 2, got {self.up}")

    @property
    def wh(self) -> tuple[int, int]:
        """``(W, H)`` in pixels."""
        if isinstance(self.size, int):
            return int(self.size), int(self.size)
        return int(self.size[0]), int(self.size[1])


def resolve_options(options: RenderOptions | None, overrides: dict[str, Any]) -> RenderOptions:
    known = {f.name for f in fields(RenderOptions)}
    unknown = set(overrides) - known
    if unknown:
        raise TypeError(f"unknown render option(s) {sorted(unknown)}; known: {sorted(known)}")
    return replace(options or RenderOptions(), **overrides)
