"""Pictures of a stored Cassie scenario: replay it, sample the robot's pose at a frame rate and
draw it with MuJoCo's own OpenGL renderer, headless (``hlip-sweep render``, ``hlip-sweep run
--render``).

One concept per module, each a step of the pipeline:

* :mod:`~hlip_jax.presentation.render.gl`: the headless OpenGL backend (``MUJOCO_GL``: EGL, with a GPU's
  driver or Mesa's software one, or OSMesa), chosen and checked before anything runs;
* :mod:`~hlip_jax.presentation.render.motion`: the replay (:func:`hlip_jax.presentation.tick_report.runs`, the sweep's
  own run within its chunk) and the robot's joint positions at the frame times;
* :mod:`~hlip_jax.presentation.render.markers`: what the frames show besides the robot: the path, the
  planned H-LIP footsteps and the placed ones, the obstacles' keep-out discs;
* :mod:`~hlip_jax.presentation.render.camera`: the camera per frame (following the pelvis, or fixed over
  the whole path);
* :mod:`~hlip_jax.presentation.render.frames`: the frames themselves (``mujoco.Renderer``), with the
  scenario's name and the time written on them (:mod:`~hlip_jax.presentation.render.overlay`);
* :mod:`~hlip_jax.presentation.render.output`: MP4 and GIF files (``imageio`` with ``imageio-ffmpeg``, the
  optional extra ``pip install 'hlip_jax[render]'``) and snapshot strips (PNG).

Rendering reads the results directory and writes only the file it is asked for.
"""


class RenderError(Exception):
    """Rendering cannot start (no OpenGL backend, the video library missing, a bad request):
    one line naming what to set or install; the CLI reports it with exit code 2."""
