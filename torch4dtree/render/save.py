"""Writing rendered frames: one image (PNG, JPEG), numbered PNGs, or a video (looping GIF, H.264 MP4).

Every writer refuses to replace an existing file unless asked, and writes through a temporary
file, so a failure never leaves a truncated file where a good one was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .options import IMAGE_SUFFIXES, VIDEO_SUFFIXES

__all__ = ["pad_even", "save_frames", "save_image", "save_video"]

GIF_COLORS = 256
MP4_QUALITY = ("-crf", "18", "-preset", "veryfast", "-movflags", "+faststart")  # ffmpeg settings of the H.264 files


def pad_even(frames: np.ndarray) -> np.ndarray:
    """Pad ``(..., H, W, 3)`` with white to even ``H`` and ``W`` (H.264 with yuv420p needs it).

    Example:
        >>> pad_even(np.zeros((3, 5, 3), np.uint8)).shape
        (4, 6, 3)
    """
    H, W = frames.shape[-3:-1]
    ph, pw = H % 2, W % 2
    if not (ph or pw):
        return frames
    widths = [(0, 0)] * (frames.ndim - 3) + [(0, ph), (0, pw), (0, 0)]
    return np.pad(frames, widths, constant_values=255)


def _check_frames(frames: np.ndarray, what: str) -> np.ndarray:
    """``frames`` as an array, checked to be uint8 RGB(A) ``(..., H, W, 3 or 4)``."""
    arr = np.asarray(frames)
    if arr.dtype != np.uint8 or arr.shape[-1] not in (3, 4):
        raise ValueError(f"{what} must be uint8 RGB(A) with shape (..., H, W, 3), got {arr.dtype} {arr.shape}")
    return arr


def save_image(path: str | Path, image: np.ndarray, overwrite: bool = False) -> Path:
    """Write one ``(H, W, 3)`` uint8 image (format from the suffix: .png, .jpg); never replaces a file unless asked.

    Example:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> save_image(folder / "white.png", np.full((8, 8, 3), 255, np.uint8)).name
        'white.png'
    """
    import imageio.v3 as iio

    path = Path(path)
    img = _check_frames(image, "image")
    if img.ndim == 4 and len(img) == 1:
        img = img[0]
    if img.ndim != 3:
        raise ValueError(f"save_image takes one (H, W, 3) image, got {img.shape}; use save_video or save_frames")
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: image files must end in {', '.join(IMAGE_SUFFIXES)}")
    if path.exists() and not overwrite:  # fail before encoding
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    data = iio.imwrite("<bytes>", img, extension=suffix)
    from ..io.files import write_bytes_safely  # here: importing torch4dtree.io imports torch

    return write_bytes_safely(path, data, overwrite)


def save_frames(folder: str | Path, frames: np.ndarray, overwrite: bool = False, prefix: str = "frame") -> list[Path]:
    """Write ``(n, H, W, 3)`` frames as ``folder/<prefix>_0000.png`` ...; refuses to replace any existing file.

    Example:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> [p.name for p in save_frames(folder, np.zeros((2, 8, 8, 3), np.uint8))]
        ['frame_0000.png', 'frame_0001.png']
    """
    arr = _check_frames(frames, "frames")
    folder = Path(folder)
    paths = [folder / f"{prefix}_{k:04d}.png" for k in range(len(arr))]
    clash = [p for p in paths if p.exists()]
    if clash and not overwrite:
        raise FileExistsError(f"{clash[0]} exists; pass overwrite=True (--overwrite) to replace it")
    return [save_image(p, f, overwrite) for p, f in zip(paths, arr)]


def _gif_bytes(frames: np.ndarray, fps: float) -> bytes:
    """A looping GIF of ``(n, H, W, 3)`` frames, one GIF frame per input frame.

    Pillow's animated-GIF writer merges identical consecutive frames (a held time point), which
    would change the frame count, so the frames are written one by one with their own palettes.
    """
    from PIL import GifImagePlugin, Image

    ms = 1000.0 / fps
    ims = [Image.fromarray(f).quantize(colors=GIF_COLORS, dither=Image.Dither.NONE) for f in frames]
    out = bytearray()
    for chunk in GifImagePlugin.getheader(ims[0], None, {"loop": 0, "duration": ms})[0]:
        out += chunk
    for k, im in enumerate(ims):
        # GIF delays are in centiseconds: spread the rounding so the total duration stays right
        delay = 10 * (round((k + 1) * ms / 10) - round(k * ms / 10))
        for chunk in GifImagePlugin.getdata(im, duration=delay, include_color_table=True):
            out += chunk
    out += b";"
    return bytes(out)


def save_video(path: str | Path, frames: np.ndarray, fps: float = 4.0, overwrite: bool = False) -> Path:
    """Write ``(n, H, W, 3)`` uint8 frames as a GIF (looping) or an MP4 (H.264, yuv420p).

    The format comes from the suffix. MP4 uses imageio-ffmpeg's bundled ffmpeg; odd sizes are
    padded with white to even ones. Never replaces an existing file unless ``overwrite``.

    Example:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> save_video(folder / "clip.gif", np.zeros((3, 8, 8, 3), np.uint8), fps=2).name
        'clip.gif'
    """
    path = Path(path)
    arr = _check_frames(frames, "frames")
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or len(arr) == 0:
        raise ValueError(f"save_video takes (n >= 1, H, W, 3) frames, got {arr.shape}")
    arr = np.ascontiguousarray(arr[..., :3])
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: video files must end in {', '.join(VIDEO_SUFFIXES)} (use save_frames for PNGs)")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
    from ..io.files import publish_file, temporary_path, write_bytes_safely  # here: torch4dtree.io imports torch

    if suffix == ".gif":
        return write_bytes_safely(path, _gif_bytes(arr, fps), overwrite)
    import imageio_ffmpeg

    arr = pad_even(arr)
    n, H, W, _ = arr.shape
    tmp = temporary_path(path)
    try:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (W, H), fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
            macro_block_size=1, quality=None, ffmpeg_log_level="error", output_params=list(MP4_QUALITY),
        )
        try:
            writer.send(None)
            for f in arr:
                writer.send(f.tobytes())
            writer.close()
        except (OSError, RuntimeError) as e:  # ffmpeg's messages name the hidden temporary file
            raise type(e)(f"{path}: cannot encode the video: {str(e).replace(str(tmp), str(path))}") from None
        publish_file(tmp, path, overwrite)
    finally:
        tmp.unlink(missing_ok=True)
    return path
