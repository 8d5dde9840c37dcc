"""Text on images with Pillow: fitted labels, captions, titles and the tiling of cells into a labelled grid.

Text is shrunk, wrapped, then cut in the middle to fit, so long plant names never spill over a
picture; line heights do not depend on the letters, so a layout does not change with its text.
Pillow is imported where used.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["TEXT_INK", "compose", "draw_caption", "label_strip", "line_height", "load_font", "text_width"]

TEXT_INK = (30, 30, 30)
CAPTION_INK = (40, 40, 40)
WHITE = (255, 255, 255)
ELLIPSIS = "\u2026"


def load_font(px: int) -> Any:
    """Pillow's default font at ``px`` pixels (its fixed-size bitmap font on Pillow older than 10.1).

    Example:
        >>> line_height(load_font(12)) > 0
        True
    """
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)  # Pillow >= 10.1 ships a scalable font
    except (TypeError, OSError):
        return ImageFont.load_default()


def text_width(text: str, font: Any) -> int:
    """Width in pixels of ``text`` set in ``font``.

    Example:
        >>> font = load_font(12)
        >>> text_width("ab", font) > text_width("a", font)
        True
    """
    from PIL import Image, ImageDraw

    x0, _, x1, _ = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), text, font=font)
    return x1 - x0


def line_height(font: Any) -> int:
    """Height in pixels of a line of ``font`` whatever its letters (so that layouts do not change with the text)."""
    try:
        ascent, descent = font.getmetrics()
        return int(ascent + descent)
    except AttributeError:  # Pillow's old bitmap font
        from PIL import Image, ImageDraw

        _, y0, _, y1 = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), "Agy|", font=font)
        return y1 - y0


def _shorten(text: str, width: int, font: Any) -> str:
    """``text`` cut in the middle with an ellipsis until it fits ``width`` pixels."""
    if text_width(text, font) <= width:
        return text
    keep = len(text)
    while keep > 1:
        keep -= 1
        cut = text[: (keep + 1) // 2] + ELLIPSIS + text[len(text) - keep // 2:]
        if text_width(cut, font) <= width:
            return cut
    return ELLIPSIS


def _fit_text(text: str, width: int, px: int, min_px: int) -> tuple[list[str], Any]:
    """Lines of ``text`` (split at newlines) and a font of at most ``px`` pixels with which each fits ``width``:
    the font shrinks down to ``min_px``, then lines are wrapped at spaces, then cut in the middle."""
    lines = text.split("\n")
    size = px
    while size > min_px and max(text_width(ln, load_font(size)) for ln in lines) > width:
        size -= 1
    font = load_font(size)
    out: list[str] = []
    for ln in lines:
        cur = ""
        for word in ln.split(" "):
            cand = f"{cur} {word}" if cur else word
            if cur and text_width(cand, font) > width:
                out.append(cur)
                cur = word
            else:
                cur = cand
        out.append(cur)
    return [_shorten(ln, width, font) for ln in out], font


def _text_px(H: int, W: int) -> int:
    """Font size in pixels for the labels of ``H x W`` cells (readable, not dominating)."""
    return max(11, min(32, max(H, W) // 14))


def label_strip(frames: np.ndarray, text: str) -> np.ndarray:
    """``(n, H, W, 3)`` frames with a white strip on top holding ``text``, centred (shrunk or cut to fit)
    -> ``(n, H + h, W, 3)``.

    Example:
        >>> out = label_strip(np.zeros((2, 40, 60, 3), np.uint8), "tomato_01")
        >>> out.shape[0], out.shape[1] > 40, out.shape[2:]
        (2, True, (60, 3))
    """
    from PIL import Image, ImageDraw

    n, H, W, _ = frames.shape
    px = _text_px(H, W)
    lines, font = _fit_text(text, W - px // 2, px, max(8, px * 2 // 3))
    h = line_height(font) + px // 2
    strip = Image.new("RGB", (W, h), WHITE)
    ImageDraw.Draw(strip).text(((W - text_width(lines[0], font)) // 2, px // 4), lines[0], fill=TEXT_INK, font=font)
    top = np.broadcast_to(np.asarray(strip), (n, h, W, 3))
    return np.concatenate([top, frames], axis=1)


def draw_caption(frame: np.ndarray, text: str) -> np.ndarray:
    """The ``(H, W, 3)`` frame with ``text`` in its top-left corner (shrunk or cut to fit the frame's width).

    Example:
        >>> white = np.full((48, 64, 3), 255, np.uint8)
        >>> bool((draw_caption(white, "t = 3") < 255).any())
        True
    """
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    px = max(10, min(28, frame.shape[0] // 18))
    lines, font = _fit_text(text, frame.shape[1] - px, px, max(8, px * 2 // 3))
    ImageDraw.Draw(img).text((px // 2, px // 3), lines[0], fill=CAPTION_INK, font=font)
    return np.asarray(img)


def compose(
    cells: np.ndarray, row_labels: Sequence[str] | None, col_labels: Sequence[str] | None, title: str | None,
    subtitle: str | None = None,
) -> np.ndarray:
    """Tile ``cells (R, C, H, W, 3)`` into one ``(H', W', 3)`` image with a title (any lines, fitted to the
    width), a subtitle line (e.g. a video frame's time), column labels and row labels.

    Example:
        >>> cells = np.full((2, 3, 32, 32, 3), 200, np.uint8)
        >>> image = compose(cells, ["a", "b"], ["1", "2", "3"], "title")
        >>> image.shape[0] > 64 and image.shape[1] > 96
        True
    """
    from PIL import Image, ImageDraw

    R, C, H, W, _ = cells.shape
    px = _text_px(H, W)
    font = load_font(px)
    pad = px // 2
    left = max((text_width(str(t), font) for t in row_labels), default=0) + 2 * pad if row_labels else 0
    full = left + C * W
    title_lines, title_font = _fit_text(title, full - 2 * pad, int(px * 1.3), px * 2 // 3) if title else ([], font)
    sub_lines, sub_font = _fit_text(subtitle, full - 2 * pad, px, px * 2 // 3) if subtitle is not None else ([], font)
    col_texts, col_font = [], font
    if col_labels:
        col_texts = [str(c) for c in col_labels]
        size = px
        while size > max(8, px // 2) and max(text_width(c, load_font(size)) for c in col_texts) > W - pad:
            size -= 1
        col_font = load_font(size)
        col_texts = [_shorten(c, W - pad, col_font) for c in col_texts]
    lh_title, lh_sub, lh_col = line_height(title_font), line_height(sub_font), line_height(col_font)
    top_title = len(title_lines) * lh_title + (pad if title_lines else 0)
    top_sub = len(sub_lines) * lh_sub + (pad // 2 if sub_lines else 0)
    top_cols = lh_col + pad if col_labels else 0
    top = (top_title + top_sub + top_cols + pad) if (title_lines or sub_lines or col_labels) else 0
    img = Image.new("RGB", (full, top + R * H), WHITE)
    img.paste(Image.fromarray(cells.transpose(0, 2, 1, 3, 4).reshape(R * H, C * W, 3)), (left, top))
    draw = ImageDraw.Draw(img)
    y = pad
    for ln, f, lh in [(t, title_font, lh_title) for t in title_lines] + [(t, sub_font, lh_sub) for t in sub_lines]:
        draw.text(((full - text_width(ln, f)) // 2, y), ln, fill=TEXT_INK, font=f)
        y += lh
    for c, lab in enumerate(col_texts):
        draw.text((left + c * W + (W - text_width(lab, col_font)) // 2, top - top_cols), lab, fill=TEXT_INK,
                  font=col_font)
    if row_labels:
        for r, lab in enumerate(row_labels):
            draw.text((pad, top + r * H + (H - line_height(font)) // 2), str(lab), fill=TEXT_INK, font=font)
    return np.asarray(img)
