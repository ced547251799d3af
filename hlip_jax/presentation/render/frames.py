"""The frames: the robot at each frame's pose, drawn by ``mujoco.Renderer`` (MuJoCo's own
OpenGL renderer, on the backend :mod:`hlip_jax.presentation.render.gl` activated), with the markers
(:mod:`hlip_jax.presentation.render.markers`), the camera (:mod:`hlip_jax.presentation.render.camera`) and the text
(:mod:`hlip_jax.presentation.render.overlay`).

The model drawn is the scene the scenario walked on: the robot on the flat floor, or with the
terrain block and the height field placed as its ground puts them
(:mod:`hlip_jax.plants.cassie.terrain`).  A ground slope (``realism.slope_*``) tilts gravity,
not the floor, in the simulation, so the frames show a flat floor there too.  Per frame only
the kinematics run (``mj_kinematics``, ``mj_comPos``, ``mj_camlight``): positions, nothing else.
Shadows are off: on a software rasteriser they cost a second pass for little.
"""

from __future__ import annotations

from typing import Iterator, NamedTuple

import mujoco
import numpy as np

from hlip_jax import plants
from hlip_jax.presentation.render import camera, markers, overlay

#: how far around the camera's target markers are drawn, in camera distances
REACH = 2.5


class Style(NamedTuple):
    """How the frames look."""
    width: int = 640          # [px]
    height: int = 480         # [px]
    legend: bool = True       # the markers' legend at the bottom
    shadows: bool = False     # MuJoCo's shadow pass (slow on a software rasteriser)


def scene_model(cfg, width: int, height: int) -> mujoco.MjModel:
    """The C MuJoCo model of scenario ``cfg``'s scene (module doc), its off-screen buffer at
    least ``width`` × ``height`` pixels; a model of its own (the simulation's is not
    touched)."""
    m = plants.tools(cfg.plant).scene(cfg)
    m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), width)
    m.vis.global_.offheight = max(int(m.vis.global_.offheight), height)
    return m


def _pose(m: mujoco.MjModel, d: mujoco.MjData, qpos: np.ndarray) -> None:
    """``d`` at joint positions ``qpos``: the positions and frames of every body, geom, camera
    and light."""
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_camlight(m, d)


def render(m: mujoco.MjModel, qpos: np.ndarray, view: camera.View, mk: markers.Markers,
           times: np.ndarray, captions, style: Style = Style()) -> Iterator[np.ndarray]:
    """Yield the frames (H, W, 3) uint8 of the poses ``qpos`` (F, nq) at plant ``times`` (F,)
    [s], seen by ``view``, with the markers shown by then and ``captions(f)``, the text lines
    of frame f."""
    d = mujoco.MjData(m)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.azimuth, cam.elevation = view.azimuth, view.elevation
    option = mujoco.MjvOption()
    with mujoco.Renderer(m, style.height, style.width) as r:
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = style.shadows
        for f in range(len(times)):
            _pose(m, d, qpos[f])
            cam.lookat[:] = view.lookat[f]
            cam.distance = view.distance[f]
            r.update_scene(d, cam, option)
            markers.add_to_scene(r.scene, mk, times[f], view.lookat[f], REACH * view.distance[f])
            yield overlay.stamp(r.render(), captions(f), style.legend)
