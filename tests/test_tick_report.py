"""Per-tick diagnostics (``hlip-sweep ticks``): a replayed Cassie scenario matches the sweep's
own step log, and its tick log shows the controller's invariants."""

import json

import numpy as np
import pytest

from hlip_jax.presentation import cli, tick_report
from hlip_jax.sweepio import runner, store, sweep
from hlip_jax.plants.cassie import plant

# The replay is compared with the sweep to 1e-6 (below).  Its CLF-QP restarts ADMM from the
# default step size every tick: with the preset's carried step size (``qp_rho_start =
# "previous"``) a last-bit difference between the two programs reaches the next ticks' QPs
# through ρ as well, and the robot amplifies it (float64, this run with the preset's T_SSP
# 0.175 s: leg clearances 2.8e-6 m apart at step 2 and 2.5e-4 m at step 3; with the default
# start every compared number agrees to 4.5e-8 m).  The replay logic is the same either way.
SWEEP = """
name = "tiny"
[base]
plant = "cassie"
duration = 1.2
[base.cassie]
qp_rho_start = "default"
[base.path]
peak_speed = 0.3
[[paths]]
shape = "line"
length = 2.0
[[paths.overrides.disturbance.pushes]]
time = 0.5
force = 60.0
direction = 90.0
"""


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_replay_matches_the_sweep_and_logs_every_tick(tmp_path, capsys, float64):
    sw = sweep.parse_sweep(SWEEP)
    out = tmp_path / "r"
    runner.run_sweep(sw, out, batch=1, with_coverage=False, progress=False)
    assert cli.main(["ticks", str(out), "99"]) == 2                 # bad index: exit 2
    assert "allowed: 0..0" in capsys.readouterr().err
    rep = tick_report.replay(out, 0, alone=True)
    npz, png = rep.npz, rep.png
    assert png.is_file() and rep.within == "alone"
    flat = dict(np.load(npz))
    log = store.load_log(out)
    steps = int(log["valid"][0].sum())
    assert steps >= 3 and np.all(np.diff(flat["time"]) > 0)
    assert flat["step"].min() == 0 and flat["step"].max() == steps - 1
    # every tick that ran is logged once: 1 ms apart within a step, each step starting at the
    # plant clock of its SSP⁻
    for k in range(steps):
        t = flat["time"][flat["step"] == k]
        np.testing.assert_allclose(np.diff(t), 1e-3, atol=1e-9)
        np.testing.assert_allclose(t[0], log["t_plant"][0, k], atol=1e-9)
    # the step log's leg clearances are the minimum of the step's ticks (the same numbers, up
    # to the two programs' differences, see below: 4.5e-8 m seen; 1e-6 allowed); the walking
    # robot's legs stay apart
    for k in range(steps):
        np.testing.assert_allclose(log["leg_gap"][0, k], flat["gap"][flat["step"] == k].min(0),
                                   atol=1e-6)
    assert np.all(log["leg_gap"][0, :steps] > 0.0), log["leg_gap"][0, :steps]
    # passive stance foot: a foot with a site in the contact set has a zero foot motor
    c = plant.cassie()
    for f, sites in ((0, slice(0, 2)), (1, slice(2, 4))):
        on = flat["contact"][:, sites].max(axis=1) > 0.5
        assert on.any() and np.all(flat["tau"][on, c.index.actuators[f][4]] == 0.0)
    # replay = the sweep's run: the same ticks, run by a fixed-length scan with the tick log
    # (plant.step_with_log) instead of the while loop that ends at touchdown (plant.step).
    # The step starts above agree to 1e-9 s; the COM the replay measures at the first tick of
    # step k is the sweep's x_robot c at SSP⁻_k (k ≥ 1; step 0 starts from the H-LIP's x0).
    # In float64 the two agree to 1e-11 m at the first steps and to 3.4e-8 m at the last (the
    # preset before, T_SSP 0.2 s: 3.1e-7 m at one step), most likely where a CLF-QP
    # convergence test, evaluated on values that differ in their last bits, stops the ADMM at
    # another check, so that one tick's torques differ within the solver's tolerance (ε 1e-4);
    # 1e-6 allowed, far below a wrong tick's effect (a touchdown a tick apart moves the COM by
    # about v · 1 ms ≈ 5e-4 m).  In float32 the different fusion of the two programs changes the last bits,
    # and a contact event can turn that into a touchdown one tick apart, so float32 is no test
    # of the logic.
    first = np.array([np.flatnonzero(flat["step"] == k)[0] for k in range(1, steps)])
    np.testing.assert_allclose(flat["com"][first, :2], log["x_robot"][0, 1:steps, :, 0], atol=1e-6)
    # the logged COM-height velocity is the COM's.  A tick is two semi-implicit Euler steps of
    # h = dt / 2, each moving the positions with the velocity it has just updated, so with an
    # acceleration a constant over the tick the COM rises by h (v + ah) + h (v + 2ah), i.e.
    # Δz / dt = ¼ ẏ_i + ¾ ẏ_{i+1}.  5e-4 m/s allowed on 99 % of the ticks (the acceleration
    # changes between the substeps at contact events; the trapezoid rule ½ ẏ_i + ½ ẏ_{i+1}
    # misses by 2.3e-3 here); the measured accelerations are finite except at the last tick
    yd, z, t = flat["ydot"][:, 3], flat["com"][:, 2], flat["time"]
    rate = np.diff(z) / np.diff(t)
    assert np.quantile(np.abs(rate - (0.25 * yd[:-1] + 0.75 * yd[1:])), 0.99) < 5e-4
    assert np.all(np.isfinite(flat["ydd_meas"][:-1])) and np.all(np.isnan(flat["ydd_meas"][-1]))
    assert np.all(np.isfinite(flat["ydd_model"]))
    # an ideal robot senses perfectly: the step log's estimate is its true state, row for row
    np.testing.assert_array_equal(log["x_est"][0, :steps], log["x_robot"][0, :steps])


def test_measured_accel_and_mismatch_are_exact_on_a_known_motion():
    # ẏ = a t per row (a constant acceleration): the forward difference returns a exactly;
    # a gap in the clock (a fall ends the log) gives NaN instead of a spurious acceleration
    t = np.r_[np.arange(20) * 1e-3, 0.5 + np.arange(5) * 1e-3]
    a = np.linspace(-3.0, 3.0, 16)
    phase = np.r_[np.zeros(10, int), np.ones(15, int)]
    flat = {"ydot": t[:, None] * a[None, :], "time": t, "phase": phase,
            "ydd_model": np.broadcast_to(a, (25, 16)) + 1.0}
    meas = tick_report.measured_accel(flat)
    ok = np.r_[np.ones(19, bool), False, np.ones(4, bool), False]
    np.testing.assert_allclose(meas[ok], np.broadcast_to(a, (ok.sum(), 16)), rtol=1e-9, atol=1e-9)
    assert np.all(np.isnan(meas[~ok]))
    flat["ydd_meas"] = meas
    mm = tick_report.mismatch(flat, "cassie")
    assert mm["dsp"] == pytest.approx((a[3], a[3] + 1.0)) and mm["ssp"] == pytest.approx((a[3], a[3] + 1.0))


# the sweep above with the preset's carried ADMM step size and a second, unpushed robot
CHUNK = SWEEP.replace('qp_rho_start = "default"', 'qp_rho_start = "previous"') + """
[[paths]]
name = "quiet"
shape = "line"
length = 2.0
"""


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_replay_within_its_chunk_is_the_sweeps_run_bit_for_bit(tmp_path, capsys, float64):
    # `run --ticks` replays the chosen scenario within its chunk (both robots, the preset's
    # carried ADMM step size): the tick log rides along with the same computation, so the
    # replayed step log must equal the stored one exactly (tolerance 0), which is what lets a
    # fall be explained from the results directory.  The CLI says so, and the report shows the
    # figure with that verdict; `ticks` replays the other robot of the chunk the same way.
    f = tmp_path / "chunk.toml"
    f.write_text(CHUNK)
    out = tmp_path / "r"
    assert cli.main(["run", str(f), "--out", str(out), "--batch", "2", "--no-coverage",
                     "--quiet", "--ticks", "^line$"]) == 0
    said = capsys.readouterr().out
    assert "within its chunk of 2" in said and "bit for bit" in said, said
    assert json.loads((out / "ticks" / "0.json").read_text())["identical"] is True
    report = (out / "report.md").read_text()
    assert "Per-tick logs (1)" in report and "ticks/0.png" in report
    assert "line: replayed within its chunk: the stored run, bit for bit" in report
    flat = dict(np.load(out / "ticks" / "0.npz"))
    log = store.load_log(out, [0])
    steps = int(log["valid"][0].sum())
    assert steps >= 3 and flat["step"].max() == steps - 1
    assert cli.main(["ticks", str(out), "quiet"]) == 0
    said = capsys.readouterr().out
    assert "ticks/1.png" in said and "bit for bit" in said, said


def _log(K=6):
    x = np.arange(K * 2 * 3, dtype=float).reshape(K, 2, 3)
    return {"x_robot": x, "valid": np.ones(K, bool), "status": np.int32(0),
            "fail_step": np.int32(-1)}


def test_compare_finds_the_first_differing_step_and_the_outcome():
    a, b = _log(), _log()
    assert tick_report.compare(a, b) == tick_report.Agreement(True, -1, 0.0)
    b["x_robot"] = b["x_robot"].copy()
    b["x_robot"][3, 1, 2] += 1e-12                      # one last-bit change at step 3
    got = tick_report.compare(a, b)
    assert not got.identical and got.first_step == 3 and 0 < got.largest < 1e-11
    c = _log()
    c["valid"] = c["valid"].copy()
    c["valid"][4:] = False                              # the replay falls at step 4
    c["x_robot"] = np.where(c["valid"][:, None, None], c["x_robot"], np.nan)
    c["status"], c["fail_step"] = np.int32(1), np.int32(4)
    got = tick_report.compare(a, c)
    assert not got.identical and got.first_step == 4 and got.largest == 0.0
    # a replay that ends the same way and differs nowhere, but logs fewer steps, is identical
    # over the steps both have
    assert tick_report.compare(a, {k: (v[:5] if np.ndim(v) else v) for k, v in a.items()}).identical
