"""Files of frames: an MP4 video (H.264 by the ffmpeg binary that ``imageio-ffmpeg`` brings),
an animated GIF, or a snapshot strip (PNG: the frames as a grid of thumbnails), written with
``imageio`` (``pip install 'hlip_jax[render]'``).  Every file is written under a temporary
name beside it and renamed when complete, so a failed render leaves no partial file."""

from __future__ import annotations

import importlib.util
import os
import warnings
from pathlib import Path
from typing import Iterable

import numpy as np

from hlip_jax.presentation.render import RenderError

#: the file types, by suffix
SUFFIXES = (".mp4", ".gif", ".png")
#: H.264 settings: x264's constant quality (lower is better; 23 is its default) and speed
CRF, PRESET = 23, "veryfast"
INSTALL = "pip install 'hlip_jax[render]'"


def installed(module: str) -> bool:
    """Whether Python module ``module`` can be imported here (without importing it)."""
    return importlib.util.find_spec(module) is not None


def require(path) -> None:
    """RenderError (one line: what to install, or which suffixes are allowed) unless a file
    like ``path`` can be written here."""
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise RenderError(f"-o: {str(path)!r}: unknown file type; allowed: a name ending in "
                          f"{', '.join(SUFFIXES)}")
    need = ["imageio"] + (["imageio_ffmpeg"] if suffix == ".mp4" else [])
    missing = [n for n in need if not installed(n)]
    if missing:
        raise RenderError(f"writing {suffix} files needs {' and '.join(missing)}: {INSTALL}")


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.stem}.part{path.suffix}")


def write(path, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write ``frames`` (H, W, 3) uint8 to ``path`` by its suffix (:data:`SUFFIXES`: ``.mp4``
    at ``fps`` frames per second, ``.gif`` with 1/fps s per frame, ``.png`` the snapshot
    strip of :func:`strip`); returns the number of frames."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary(path)
    try:
        n = {".mp4": _mp4, ".gif": _gif, ".png": _png}[path.suffix.lower()](tmp, frames, fps)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return n


def _mp4(path: Path, frames, fps: float) -> int:
    import imageio.v2 as iio
    n = 0
    with warnings.catch_warnings():
        # JAX warns of any fork in its process; ffmpeg's (started by the first frame) execs
        # at once
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        with iio.get_writer(str(path), format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            pixelformat="yuv420p", macro_block_size=2, ffmpeg_log_level="error",
                            output_params=["-crf", str(CRF), "-preset", PRESET]) as w:
            for frame in frames:
                w.append_data(frame)
                n += 1
    return n


def _gif(path: Path, frames, fps: float) -> int:
    import imageio.v3 as iio
    stack = np.stack(list(frames))
    iio.imwrite(path, stack, extension=".gif", duration=1000.0 / fps, loop=0)
    return len(stack)


def strip(frames, columns: int = 10) -> np.ndarray:
    """The frames as a grid of ``columns`` per row (the last row filled with white), with a
    2-pixel white gap between them."""
    frames = list(frames)
    h, w, _ = frames[0].shape
    rows = -(-len(frames) // columns)
    cols = min(columns, len(frames))
    out = np.full((rows * (h + 2) - 2, cols * (w + 2) - 2, 3), 255, np.uint8)
    for k, f in enumerate(frames):
        r, c = divmod(k, columns)
        out[r * (h + 2):r * (h + 2) + h, c * (w + 2):c * (w + 2) + w] = f
    return out


def _png(path: Path, frames, fps: float) -> int:
    import imageio.v3 as iio
    frames = list(frames)
    iio.imwrite(path, strip(frames), extension=".png")
    return len(frames)
