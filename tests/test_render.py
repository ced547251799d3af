"""``hlip-sweep render`` and ``run --render`` (hlip_jax.presentation.render): pictures of a stored Cassie
scenario, drawn by MuJoCo's renderer on a headless OpenGL (EGL or OSMesa, software on a CPU).

Fast tier: the frames of a known motion (Cassie's standing pose carried along x at 0.5 m/s,
legs swinging) show the robot, its motion and the keep-out disc; the CLI on a results
directory written by the fake closed loop of test_store.py, its replay
(:func:`hlip_jax.presentation.tick_report.runs`) replaced by that motion: the files it writes, the
results left byte for byte, and the one-line errors (exit 2) of a missing OpenGL backend or
video library, a bad scenario, option or output path.  Slow tier: the real replay of a
short Cassie run, drawn end to end.

A test skips only where no OpenGL backend can be created (the reason is the skip's message);
CI installs Mesa's where it is missing (.ci/run).
"""

from __future__ import annotations

import hashlib
import os
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from hlip_jax.presentation import cli, tick_report
from hlip_jax.core import steplog
from hlip_jax.sweepio import store, sweep
from hlip_jax.plants.cassie import model
from hlip_jax.presentation.render import RenderError, clip, files, frames, gl, markers, motion, output

SWEEP = """
name = "tiny"
[base]
plant = "cassie"
duration = 1.2
[base.path]
peak_speed = 0.3
[[paths]]
shape = "line"
length = 2.0
[[paths.overrides.obstacles]]
x = 0.5
y = 0.4
radius = 0.2
margin = 0.1
"""
SPEED = 0.5        # the known motion's forward speed [m/s]
DT = 1e-3          # one tick [s]
PER_STEP = 200     # ticks per step of the known motion


@pytest.fixture
def backend():
    """An OpenGL backend for mujoco.Renderer (MUJOCO_GL restored afterwards); skips, with the
    reason, only where none can be created."""
    old = os.environ.get("MUJOCO_GL")
    try:
        name = gl.select()
        gl.activate(name)
    except RenderError as err:
        pytest.skip(f"no OpenGL backend: {err}")
    yield name
    if old is None:
        os.environ.pop("MUJOCO_GL", None)
    else:
        os.environ["MUJOCO_GL"] = old


def known_qpos(n: int) -> np.ndarray:
    """(n, nq): Cassie's "stand" pose moving along +x at SPEED, hips swinging ±0.3 rad at
    1 Hz in opposite phase, one row per tick of DT."""
    m = mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    q = np.tile(m.key("stand").qpos, (n, 1))
    t = np.arange(n) * DT
    q[:, 0] += SPEED * t
    for side, sign in (("left", 1.0), ("right", -1.0)):
        q[:, m.jnt_qposadr[m.joint(f"{side}_hip_pitch").id]] += sign * 0.3 * np.sin(2 * np.pi * t)
    return q


def known_motion(cfg, step_log: dict, index: int = 0) -> motion.Motion:
    """The known motion over the steps of ``step_log`` (its plant clock set to PER_STEP ticks
    per step)."""
    K = len(step_log["valid"])
    log = dict(step_log, t_plant=np.arange(K) * PER_STEP * DT)
    q = known_qpos(K * PER_STEP)
    return motion.Motion(index, cfg, log, np.arange(K * PER_STEP) * DT, q, "known motion",
                         "chunk")


def known_runs(out_dir, indices, *, alone=False):
    """:func:`hlip_jax.presentation.tick_report.runs` with the known motion for the replay: the stored
    step logs, PER_STEP ticks of the known motion per step."""
    cfgs = [sweep.config_from_dict(c) for c in store.read_manifest(out_dir)["configs"]]
    logs = tick_report.stored_logs(out_dir, indices)
    for i in indices:
        mo = known_motion(cfgs[i], logs[i], i)
        K = len(mo.step_log["valid"])
        ticks = SimpleNamespace(qpos=mo.qpos.reshape(K, PER_STEP, -1),
                                phase=np.ones((K, PER_STEP), np.int32))
        yield i, cfgs[i], mo.step_log, ticks, "alone" if alone else "chunk"


def read_video(path) -> np.ndarray:
    """(frames, H, W, 3) of an MP4 file (imageio-ffmpeg)."""
    import imageio.v2 as iio
    with warnings.catch_warnings():             # JAX's note on the fork that starts ffmpeg
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        with iio.get_reader(path) as r:         # (its len() is sys.maxsize: no list(r))
            return np.stack([frame for frame in r])


def tiny_config():
    return sweep.parse_sweep(SWEEP).scenarios[0]


def synthetic_log(K: int) -> dict:
    log = {k: v[0] for k, v in steplog.zeros(1, K).items()}
    log["valid"][:] = True
    log["stance"][:] = np.arange(K) % 2
    return log


def test_frames_show_the_robot_its_motion_and_the_keep_out_disc(backend):
    cfg = tiny_config()
    mo = known_motion(cfg, synthetic_log(6))
    times = np.array([0.0, 0.5, 1.0])
    mk = markers.scenario_markers(cfg, mo.step_log)
    req = clip.Request(camera="fixed", width=240, height=180)
    m = frames.scene_model(cfg, req.width, req.height)
    view = clip.view_of(mo, times, mk, req, float(m.vis.global_.fovy))
    style = frames.Style(req.width, req.height, legend=False)
    q = motion.poses(mo, times)
    gone = q.copy()
    gone[:, 2] -= 100.0                    # the robot far under the (opaque) floor
    caption = lambda f: [""]              # noqa: E731
    shot = np.stack(list(frames.render(m, q, view, mk, times, caption, style)))
    empty = np.stack(list(frames.render(m, gone, view, mk, times, caption, style)))
    assert shot.shape == (3, 180, 240, 3) and shot.dtype == np.uint8
    # the robot's pixels: where the frame differs from the same view without it by more than
    # 30 levels summed over R, G, B (the floor's texture repeats exactly between the two);
    # the robot covers 0.5 % to 40 % of the fixed view of a 2 m path
    robot = np.abs(shot.astype(int) - empty.astype(int)).sum(axis=-1) > 30
    share = robot.mean(axis=(1, 2))
    assert np.all((share > 0.005) & (share < 0.4)), share
    # it moves: 1 m along +x in 2 s shifts its pixels' centroid by more than 5 px (the fixed
    # camera looks along +y, so +x is to the right)
    cols = [np.flatnonzero(r.any(axis=0)).mean() for r in robot]
    assert cols[2] - cols[0] > 5, cols
    # the keep-out disc is drawn: strongly red pixels (R > 150, G and B < 90) in every frame
    red = (shot[..., 0] > 150) & (shot[..., 1] < 90) & (shot[..., 2] < 90)
    assert np.all(red.sum(axis=(1, 2)) > 20), red.sum(axis=(1, 2))


def test_markers_follow_the_step_log():
    # planned footstep j at c_H − p_H + u_H of row j, shown from SSP⁻_{j−1}; placed at
    # c_R − p_R + u_R from SSP⁻_j, none for step 0 (exact arithmetic: 1e-12)
    log = synthetic_log(3)
    log["t_plant"] = np.array([0.0, 0.4, 0.8])
    log["x_hlip"][:, 0] = [[1.0, 0.1, 0.0], [1.2, 0.1, 0.0], [1.4, -0.1, 0.0]]
    log["u_hlip"][:, 0] = [0.2, 0.25, 0.3]
    log["x_robot"][:] = log["x_hlip"]
    log["u_robot"][:, 0] = [0.2, 0.22, 0.28]
    plan, put = markers.footsteps(log)
    np.testing.assert_allclose(plan.pos[:, 0], [1.1, 1.35, 1.8], atol=1e-12)
    np.testing.assert_allclose(plan.shown, [0.0, 0.0, 0.4], atol=1e-12)
    np.testing.assert_allclose(put.pos[:, 0], [1.32, 1.78], atol=1e-12)
    np.testing.assert_allclose(put.shown, [0.4, 0.8], atol=1e-12)
    # step 1 starts on the right foot (stance 1 → the left foot lands)
    assert tuple(put.rgba[0]) == markers.FOOT_RGBA[0]
    assert markers.shown_at(put, 0.5, (0.0, 0.0), 10.0).tolist() == [0]


def test_frame_times_and_poses():
    mo = known_motion(tiny_config(), synthetic_log(2))
    t = motion.frame_times(0.0, 0.399, 30.0, 1.0)
    np.testing.assert_allclose(t, np.arange(12) / 30.0, atol=1e-12)
    np.testing.assert_allclose(motion.frame_times(0.0, 1.0, 10.0, 2.0), [0.0, 0.2, 0.4, 0.6,
                                                                          0.8, 1.0], atol=1e-12)
    # the last tick at or before each time: 1 ms resolution
    q = motion.poses(mo, np.array([-1.0, 0.0105, 5.0]))
    np.testing.assert_allclose(q[:, 0] - q[0, 0], [0.0, SPEED * 0.010, SPEED * 0.399],
                               atol=1e-12)
    with pytest.raises(RenderError, match="--t0"):
        motion.window(mo, 3.0, None)


# --- the CLI on a stored (fake) run ---


@pytest.fixture
def stored(tmp_path, monkeypatch):
    """A results directory of the tiny sweep written by the fake closed loop, its replay the
    known motion (tick_report.runs replaced)."""
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "test_store:fake_simulate")
    f = tmp_path / "tiny.toml"
    f.write_text(SWEEP)
    out = tmp_path / "r"
    assert cli.main(["run", str(f), "--out", str(out), "--no-report", "--no-coverage",
                     "--quiet"]) == 0
    monkeypatch.setattr(tick_report, "runs", known_runs)
    return out


def digest(d: Path) -> dict:
    """{relative path: SHA-256} of every file under ``d`` but videos/."""
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*")) if p.is_file() and files.VIDEOS not in p.parts}


def test_render_writes_only_its_file(stored, tmp_path, backend, capsys):
    before = digest(stored)
    assert cli.main(["render", str(stored), "0", "--width", "160", "--height", "120",
                     "--fps", "10", "--t1", "0.5"]) == 0
    out = capsys.readouterr().out
    video = files.video(stored, 0, "line")
    assert f"render: {video}" in out and "6 frames" in out and "bit for bit" in out
    assert read_video(video).shape == (6, 120, 160, 3)   # 0 to 0.5 s at 10 frames per second
    import imageio.v3 as iio
    gif, png = tmp_path / "a.gif", tmp_path / "a.png"
    assert cli.main(["render", str(stored), "line", "-o", str(gif), "--width", "96",
                     "--height", "64", "--fps", "5", "--camera", "fixed"]) == 0
    assert iio.imread(gif).shape[0] == len(motion.frame_times(0.0, 1.199, 5.0, 1.0))
    assert cli.main(["render", str(stored), "0", "-o", str(png)]) == 0
    strip = iio.imread(png)                           # 0 and 1 s: one row of two 320x240
    assert strip.shape[:2] == (240, 2 * 320 + 2)
    assert digest(stored) == before                   # the results, byte for byte
    assert sorted(p.name for p in (stored / files.VIDEOS).iterdir()) == [video.name]


def error_line(capsys, *args) -> str:
    assert cli.main([str(a) for a in args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    return err


def test_render_errors_are_one_line_and_lose_nothing(stored, tmp_path, backend, capsys,
                                                     monkeypatch):
    before = digest(stored)
    out = tmp_path / "x.mp4"
    assert "allowed: 0..0" in error_line(capsys, "render", stored, "7", "-o", out)
    assert "allowed: 0..0" in error_line(capsys, "render", stored, "nope", "-o", out)
    assert "--fps" in error_line(capsys, "render", stored, "0", "-o", out, "--fps", "0")
    assert "--width" in error_line(capsys, "render", stored, "0", "-o", out, "--width", "15")
    assert ".mp4, .gif, .png" in error_line(capsys, "render", stored, "0", "-o", tmp_path / "x.avi")
    assert "inside the results directory" in error_line(capsys, "render", stored, "0", "-o",
                                                        stored / "summary.mp4")
    assert "--t0" in error_line(capsys, "render", stored, "0", "-o", out, "--t0", "9")
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    assert "allowed: egl, osmesa" in error_line(capsys, "render", stored, "0", "-o", out)
    # no OpenGL backend at all: which variable to set, which package to install
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr(gl, "LIBRARIES", {"egl": (("libEGL-missing.so",),),
                                          "osmesa": (("libOSMesa-missing.so",),)})
    err = error_line(capsys, "render", stored, "0", "-o", out)
    assert "MUJOCO_GL=egl" in err and "apt-get install libosmesa6" in err
    monkeypatch.undo()
    # the video library missing: what to install
    monkeypatch.setattr(output, "installed", lambda name: name != "imageio_ffmpeg")
    assert "pip install 'hlip_jax[render]'" in error_line(capsys, "render", stored, "0",
                                                          "-o", out)
    assert not out.exists() and digest(stored) == before


def test_run_render_draws_videos_and_strips_for_the_report(tmp_path, monkeypatch, backend,
                                                           capsys):
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "test_store:fake_simulate")
    f = tmp_path / "tiny.toml"
    f.write_text(SWEEP)
    out = tmp_path / "r"
    # before anything runs: a bad pattern, or no video library, is one line and no results
    assert "--render" in error_line(capsys, "run", f, "--out", out, "--render", "nomatch")
    with monkeypatch.context() as mp:
        mp.setattr(output, "installed", lambda name: False)
        assert "hlip_jax[render]" in error_line(capsys, "run", f, "--out", out, "--render", ".")
    assert not out.exists()
    monkeypatch.setattr(tick_report, "runs", known_runs)
    assert cli.main(["run", str(f), "--out", str(out), "--render", "line", "--no-coverage",
                     "--quiet"]) == 0
    printed = capsys.readouterr().out
    video, strip = files.video(out, 0, "line"), files.strip(out, 0, "line")
    assert video.is_file() and strip.is_file() and f"render: {video}" in printed
    html = (out / "report.html").read_text()
    assert f"<video controls muted loop preload='metadata' src='videos/{video.name}'" in html
    assert "snapshots of line" in html and "Videos (1)" in html
    assert f"(videos/{video.name})" in (out / "report.md").read_text()


# --- the real replay ---

# two robots in one chunk, 1.2 s each, the first pushed: tests/test_tick_report.py's chunk,
# whose replay that test finds bit for bit
from test_tick_report import CHUNK  # noqa: E402


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_replayed_cassie_run_is_drawn(tmp_path, backend, capsys):
    """A chunk of two 1.2 s Cassie runs (real closed loop, run by the CLI as `render` replays
    it: the same device split and program caches), the first drawn end to end: the replay is
    the stored run bit for bit, its tick log's qpos holds the pelvis it already logged, the
    video's frames show the robot walking."""
    f = tmp_path / "pair.toml"
    f.write_text(CHUNK)
    out = tmp_path / "r"
    assert cli.main(["run", str(f), "--out", str(out), "--batch", "2", "--no-coverage",
                     "--no-report", "--quiet"]) == 0
    before = digest(out)
    video = tmp_path / "cassie.mp4"
    assert cli.main(["render", str(out), "0", "-o", str(video), "--width", "320",
                     "--height", "240", "--camera", "fixed"]) == 0
    said = capsys.readouterr().out
    assert "the stored run, bit for bit" in said, said
    i, cfg, step_log, ticks, within = next(tick_report.runs(out, [0]))
    np.testing.assert_array_equal(ticks.qpos[..., :7], ticks.pelvis)
    assert ticks.qpos.shape[-1] == mujoco.MjModel.from_xml_path(str(model.SCENE_XML)).nq
    shots = read_video(video).astype(int)
    steps = int(step_log["valid"].sum())
    assert len(shots) >= 30 and steps >= 3
    # not blank: the frame's pixels spread (std > 10 levels); the robot moved: the first and
    # the last frame differ by more than 3 levels on average (H.264 changes a still image by
    # about one level)
    assert shots[0].std() > 10
    assert np.abs(shots[-1] - shots[0]).mean() > 3, np.abs(shots[-1] - shots[0]).mean()
    assert digest(out) == before
