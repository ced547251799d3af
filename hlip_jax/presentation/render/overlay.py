"""Text on the frames: the scenario's name and the plant time in the top left corner, a legend
of the markers in the bottom left, white on a dark box, drawn into the image with Pillow
(a dependency of matplotlib and imageio)."""

from __future__ import annotations

import functools

import numpy as np

#: the legend's entries: (label, RGB of its swatch)
LEGEND = (("path", (217, 217, 217)), ("H-LIP plan", (255, 217, 26)),
          ("left foot", (51, 128, 242)), ("right foot", (242, 128, 26)),
          ("keep-out", (217, 26, 26)))


@functools.lru_cache(maxsize=4)
def font(size: int):
    """Pillow's default font at ``size`` pixels (its fixed bitmap font where Pillow is older
    than 10.1)."""
    from PIL import ImageFont
    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


def font_size(height: int) -> int:
    """Text height [px] for an image ``height`` pixels high."""
    return max(10, round(height / 30))


def stamp(image: np.ndarray, lines, legend: bool = True) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with ``lines`` (strings, top left) and, with ``legend``, the
    markers' legend (bottom left); a new array."""
    from PIL import Image, ImageDraw
    h = image.shape[0]
    size = font_size(h)
    f = font(size)
    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil)
    pad = max(2, size // 4)
    text = "\n".join(lines)
    box = draw.multiline_textbbox((pad, pad), text, font=f, spacing=pad)
    draw.rectangle((0, 0, box[2] + pad, box[3] + pad), fill=(20, 20, 24))
    draw.multiline_text((pad, pad), text, font=f, fill=(255, 255, 255), spacing=pad)
    if legend:
        _legend(draw, f, size, pad, h)
    return np.asarray(pil)


def _legend(draw, f, size: int, pad: int, h: int) -> None:
    """The markers' legend, one row, along the bottom left."""
    x, y = pad, h - size - 2 * pad
    width = sum(size + pad + draw.textlength(label, font=f) + 2 * pad for label, _ in LEGEND)
    draw.rectangle((0, y - pad, x + width, h), fill=(20, 20, 24))
    for label, rgb in LEGEND:
        draw.ellipse((x, y + size * 0.15, x + size * 0.7, y + size * 0.85), fill=rgb)
        x += size * 0.7 + pad
        draw.text((x, y), label, font=f, fill=(255, 255, 255))
        x += draw.textlength(label, font=f) + 2 * pad
