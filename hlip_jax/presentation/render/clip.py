"""One replayed scenario (:class:`hlip_jax.presentation.render.motion.Motion`) to one file: which frames,
seen from where, captioned how.

A video (``.mp4``, ``.gif``) has a frame every ``speed / fps`` simulated seconds of the
window; a snapshot strip (``.png``) one frame per simulated second (:data:`STRIP_EVERY`),
as a grid of thumbnails.  Every frame is captioned with the scenario's index and name, its
outcome and the plant time.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from hlip_jax.core import steplog
from hlip_jax.presentation.render import RenderError, camera, frames, markers, motion, output

#: spacing of a snapshot strip's frames [s of plant time]
STRIP_EVERY = 1.0


class Request(NamedTuple):
    """What to draw (the CLI's options)."""
    fps: float = 30.0             # frames per second of video
    speed: float = 1.0            # simulated seconds per second of video
    camera: str = "track"         # one of camera.CAMERAS
    t0: float | None = None       # window start [s of plant time]; None: the run's start
    t1: float | None = None       # window end [s]; None: the run's end
    width: int = 640              # [px]
    height: int = 480             # [px]


class Written(NamedTuple):
    """A file written by :func:`write`."""
    path: Path
    frames: int           # frames drawn
    simulated: float      # the window's length [s of plant time]
    seconds: float        # wall time of drawing and writing [s]


def check(req: Request) -> None:
    """RenderError naming the option, unless ``req`` is drawable."""
    for name, v in (("--fps", req.fps), ("--speed", req.speed)):
        if not (np.isfinite(v) and v > 0):
            raise RenderError(f"{name}: {v:g}; allowed: a number > 0")
    if req.camera not in camera.CAMERAS:
        raise RenderError(f"--camera: {req.camera!r}; allowed: {', '.join(camera.CAMERAS)}")
    for name, v in (("--width", req.width), ("--height", req.height)):
        if not (16 <= v <= 4096 and v % 2 == 0):
            raise RenderError(f"{name}: {v}; allowed: an even number of pixels "
                              "from 16 to 4096")
    for name, v in (("--t0", req.t0), ("--t1", req.t1)):
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise RenderError(f"{name}: {v:g}; allowed: a time >= 0 s")


def times_of(mo: motion.Motion, path: Path, req: Request) -> np.ndarray:
    """Plant times [s] of the frames of ``path``'s file (module doc)."""
    lo, hi = motion.window(mo, req.t0, req.t1)
    if Path(path).suffix.lower() == ".png":
        return motion.frame_times(lo, hi, 1.0, STRIP_EVERY)
    return motion.frame_times(lo, hi, req.fps, req.speed)


def view_of(mo: motion.Motion, times: np.ndarray, mk: markers.Markers, req: Request,
            fovy: float) -> camera.View:
    """The camera of every frame (:mod:`hlip_jax.presentation.render.camera`)."""
    if req.camera == "track":
        return camera.track(times, mo.time, mo.qpos[:, :2])
    pts = np.vstack([mk.pos[:, :2], mo.qpos[:, :2]])
    return camera.fixed(len(times), pts, fovy, req.width / req.height)


def captions(mo: motion.Motion, times: np.ndarray, speed: float):
    """f → the text lines of frame f: index, name and outcome; plant time."""
    status = steplog.STATUS_NAMES.get(int(mo.step_log["status"]), "?")
    head = f"#{mo.index} {mo.config.name} ({status})"
    rate = "" if speed == 1 else f"  (x{speed:g})"
    return lambda f: [head, f"t = {times[f]:6.2f} s{rate}"]


def write(mo: motion.Motion, path, req: Request) -> Written:
    """Draw ``mo`` as ``req`` asks and write it to ``path`` (its suffix picks the file type,
    :data:`hlip_jax.presentation.render.output.SUFFIXES`)."""
    start = time.perf_counter()
    path = Path(path)
    times = times_of(mo, path, req)
    mk = markers.scenario_markers(mo.config, mo.step_log)
    m = frames.scene_model(mo.config, req.width, req.height)
    view = view_of(mo, times, mk, req, float(m.vis.global_.fovy))
    style = frames.Style(req.width, req.height, legend=path.suffix.lower() != ".png")
    drawn = frames.render(m, motion.poses(mo, times), view, mk, times,
                          captions(mo, times, req.speed), style)
    n = output.write(path, drawn, req.fps)
    return Written(path, n, float(times[-1] - times[0]), time.perf_counter() - start)
