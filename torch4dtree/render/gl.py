"""Drawing tube meshes offscreen with pyrender through EGL (Mesa's ``llvmpipe`` serves without a GPU).

pyrender and OpenGL are imported on first use, and one renderer serves the whole process,
because creating an EGL context per frame is slow.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from .camera import Framing
from .geometry import TreeGeometry, unit_vectors
from .options import GL_PACKAGES, RenderOptions

__all__ = ["close_renderer", "draw_frames"]

_RENDERER: Any = None
FOG_SPAN_FLOOR = 1e-12  # a flat scene (near == far) still gets a positive fog depth range
# lights ride with the camera, so an orbit keeps the same modelling: key upper-left, fill right, rim behind
# (direction of the light's travel in the camera frame, intensity)
LIGHTS = (((0.6, -0.7, -0.8), 3.0), ((-0.9, 0.2, -0.5), 0.6), ((0.0, -0.4, 1.0), 1.0))
AMBIENT = 0.18
GL_TRIANGLES = 4


def _gl_error(err: BaseException) -> RuntimeError:
    """The error to raise when OpenGL cannot be set up, with the system packages to install."""
    return RuntimeError(
        f"offscreen OpenGL (EGL) rendering is unavailable: {type(err).__name__}: {err}. "
        f"Install the system libraries (Debian/Ubuntu: `apt-get install -y {GL_PACKAGES}`, or run "
        f".ci/system-packages.sh); with a GPU driver, its EGL vendor library works too. "
        f"PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r}."
    )


def _pyrender() -> Any:
    """Import pyrender on EGL, turning a missing package or GL library into a clear error."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before OpenGL is first imported
    if "pyglet" not in sys.modules and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        # pyrender imports pyglet's window code; without a display use its EGL backend, not X11's
        os.environ.setdefault("PYGLET_HEADLESS", "true")
    try:
        import pyrender
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in ("pyrender", "trimesh", "OpenGL", "pyglet"):
            raise ModuleNotFoundError(
                f"rendering needs the 'render' extra: pip install 'torch4dtree[render]' ({e})", name=e.name
            ) from e
        raise
    except Exception as e:  # ImportError('Unable to load EGL library'), OSError, AttributeError...
        raise _gl_error(e) from e
    return pyrender


def _renderer(W: int, H: int) -> Any:
    """The process-wide offscreen renderer, resized to ``W x H``."""
    global _RENDERER
    pyrender = _pyrender()
    if _RENDERER is None:
        try:
            _RENDERER = pyrender.OffscreenRenderer(W, H)
        except Exception as e:
            raise _gl_error(e) from e
        import atexit

        atexit.register(close_renderer)
    _RENDERER.viewport_width, _RENDERER.viewport_height = W, H
    return _RENDERER


def close_renderer() -> None:
    """Release the offscreen GL context (it is re-created on the next render).

    Example:
        >>> close_renderer()  # nothing to release: a no-op
    """
    global _RENDERER
    if _RENDERER is not None:
        try:
            _RENDERER.delete()
        except Exception:  # noqa: S110 - tearing down a dead context at exit is best effort
            pass
        _RENDERER = None


def _look_pose(direction: Sequence[float]) -> np.ndarray:
    """``(4, 4)`` pose whose -z axis points along ``direction`` (light travel, camera frame)."""
    z = -unit_vectors(np.asarray(direction, float))[0]
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.99 else np.cross([1.0, 0.0, 0.0], z)
    x = unit_vectors(x)[0]
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    return pose


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """pyrender multiplies vertex colours into linear light and gamma-encodes the result."""
    c = c.astype(np.float32) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _fog(color: np.ndarray, depth: np.ndarray, framing: Framing, amount: float) -> np.ndarray:
    """Fade ``(H, W, 3)`` pixels towards white with their depth ``(H, W)`` (0 = background)."""
    if amount <= 0:
        return color
    t = np.clip((depth - framing.near) / max(framing.far - framing.near, FOG_SPAN_FLOOR), 0.0, 1.0) * amount
    t[depth <= 0] = 0.0
    return (color + t[..., None] * (255.0 - color)).round().astype(np.uint8)


def draw_frames(geoms: list[TreeGeometry], which: Sequence[int], framing: Framing, opts: RenderOptions) -> np.ndarray:
    """``(len(which), H, W, 3)`` uint8 on white: frame ``k`` shows ``geoms[which[k]]`` from ``framing.poses[k]``.

    Consecutive frames of the same tree from the same pose are drawn once.
    """
    pyrender = _pyrender()
    W, H = opts.wh
    renderer = _renderer(W, H)
    scene = pyrender.Scene(bg_color=[1.0, 1.0, 1.0, 1.0], ambient_light=[AMBIENT] * 3)
    camera = pyrender.PerspectiveCamera(yfov=framing.yfov, aspectRatio=framing.aspect,
                                        znear=framing.znear, zfar=framing.zfar)
    cam_node = scene.add(camera, pose=framing.poses[0])
    for direction, intensity in LIGHTS:
        scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=intensity),
                  pose=_look_pose(direction), parent_node=cam_node)
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0,
                                                  roughnessFactor=0.5)
    meshes: dict[int, Any] = {}
    out = np.empty((len(which), H, W, 3), np.uint8)
    last: tuple[int, int] | None = None
    for k, (g, pose) in enumerate(zip(which, framing.poses)):
        if last is not None and last[0] == g and np.array_equal(framing.poses[last[1]], pose):
            out[k] = out[k - 1]  # the same tree from the same place: reuse the pixels
            continue
        geom = geoms[g]
        node = None
        if len(geom.faces):
            if g not in meshes:
                colors = np.concatenate([_srgb_to_linear(geom.colors), np.ones((len(geom.colors), 1), np.float32)], 1)
                prim = pyrender.Primitive(positions=geom.vertices, normals=geom.normals, color_0=colors,
                                          indices=geom.faces, material=material, mode=GL_TRIANGLES)
                meshes[g] = pyrender.Mesh([prim])
            node = scene.add(meshes[g])
        scene.set_pose(cam_node, pose)
        try:
            color, depth = renderer.render(scene)
        except Exception as e:
            raise _gl_error(e) from e
        out[k] = _fog(color[..., :3], depth, framing, opts.fog)
        if node is not None:
            scene.remove_node(node)
        last = (g, k)
    return out
