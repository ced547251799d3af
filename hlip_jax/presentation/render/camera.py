"""The camera of every frame: MuJoCo's free camera (``mjvCamera``), set by the point it looks
at, its distance from it and two fixed angles.

* ``track``: looks at the pelvis, its horizontal position averaged over :data:`TRACK_SMOOTH`
  s around the frame (the pelvis sways sideways every step; the camera should not), from
  :data:`TRACK_DISTANCE` m, at azimuth :data:`TRACK_AZIMUTH` and elevation
  :data:`TRACK_ELEVATION` (world angles: the view does not turn with the robot);
* ``fixed``: one view of the whole run from above, looking at the centre of the box around
  the path and the robot's track, far enough away that the box fits the field of view.

MuJoCo's angles [deg]: azimuth about the vertical from world +x (the camera looks along
(cos az, sin az) horizontally), elevation negative looking down.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

CAMERAS = ("track", "fixed")
TRACK_DISTANCE, TRACK_AZIMUTH, TRACK_ELEVATION, TRACK_HEIGHT = 3.2, 120.0, -18.0, 0.65
TRACK_SMOOTH = 0.6
FIXED_AZIMUTH, FIXED_ELEVATION = 90.0, -60.0


class View(NamedTuple):
    """The camera of each frame."""
    lookat: np.ndarray     # (F, 3) the point looked at [m]
    distance: np.ndarray   # (F,) from the camera to it [m]
    azimuth: float         # [deg]
    elevation: float       # [deg]


def smoothed(times: np.ndarray, tick_time: np.ndarray, xy: np.ndarray, width: float) -> np.ndarray:
    """(len(times), 2) mean of the samples ``xy`` (n, 2) at ``tick_time`` (n,) [s] within
    ±width/2 of each time (the nearest sample where none is)."""
    csum = np.vstack([np.zeros((1, 2)), np.cumsum(xy, axis=0)])
    lo = np.searchsorted(tick_time, times - width / 2, side="left")
    hi = np.searchsorted(tick_time, times + width / 2, side="right")
    empty = hi <= lo
    near = np.clip(np.searchsorted(tick_time, times), 0, len(tick_time) - 1)
    lo, hi = np.where(empty, near, lo), np.where(empty, near + 1, hi)
    return (csum[hi] - csum[lo]) / (hi - lo)[:, None]


def track(times: np.ndarray, tick_time: np.ndarray, pelvis_xy: np.ndarray) -> View:
    """The ``track`` view at plant ``times`` [s], from the pelvis positions ``pelvis_xy``
    (n, 2) [m] at ``tick_time`` (n,) [s]."""
    xy = smoothed(np.asarray(times, float), tick_time, pelvis_xy, TRACK_SMOOTH)
    lookat = np.c_[xy, np.full(len(xy), TRACK_HEIGHT)]
    return View(lookat, np.full(len(xy), TRACK_DISTANCE), TRACK_AZIMUTH, TRACK_ELEVATION)


def fixed(n_frames: int, points_xy: np.ndarray, fovy: float, aspect: float) -> View:
    """The ``fixed`` view of ``n_frames`` frames that shows every point of ``points_xy``
    (n, 2) [m]: a camera of vertical field of view ``fovy`` [deg] and image width/height
    ``aspect``, 20 % of margin."""
    lo, hi = points_xy.min(axis=0), points_xy.max(axis=0)
    centre = np.r_[(lo + hi) / 2, 0.3]
    half = np.hypot(*((hi - lo) / 2)) + 0.6          # the box's half-diagonal, the robot's size
    half_fov = np.radians(fovy) / 2
    fit = half / np.tan(np.arctan(np.tan(half_fov) * min(aspect, 1.0)))
    return View(np.tile(centre, (n_frames, 1)), np.full(n_frames, 1.2 * fit),
                FIXED_AZIMUTH, FIXED_ELEVATION)
