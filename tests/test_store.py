"""Results store (hlip_jax.sweepio.store): chunked atomic writes, manifest, summary, resume.

Uses a small fake closed loop (``fake_simulate``) that produces a Log with the rollout
contract's fields from the H-LIP S2S map, deterministic in each config's seed; so these tests
check the store, not the controller, and run in well under a second per sweep.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from pathlib import Path

import jax
import numpy as np
import pytest

from hlip_jax.core import hlip, sets, steplog
from hlip_jax.analysis import metrics
from hlip_jax.sweepio import runner, store, sweep
from hlip_jax.analysis import errors

TINY = """
name = "tiny"
[base]
duration = 4.0
seed = 3
[base.disturbance]
noise_v = 0.02
[[base.obstacles]]
x = 1.0
y = 1.0
radius = 0.2
[[paths]]
shape = "circle"
[[paths]]
shape = "line"
[paths.overrides.gain]
with_position = false
[grid.product]
"gain.type" = ["deadbeat", "lqr"]
"mpc.alpha" = [0.01, 0.1]
"""


FakeLog = steplog.Log        # the fake closed loop fills the real step log


def fake_simulate(configs, chunk=None, calls=None):
    """A Log of the rollout contract: x⁺ = A x + B u + w per plane with a deadbeat law (on
    [c, p, v] or on [p, v] as ``gain.with_position`` says).

    The H-LIP walks at 0.3 m/s along x (u = v̄T + K x on [p, v]); the robot adds uniform w
    (half-width from the config's noise) seeded by the config's seed.  A scenario named with
    ``gain.type=lqr`` and ``mpc.alpha=0.1`` is marked fallen at step 3 (a failure to report).
    """
    if calls is not None:
        calls.append(len(configs))
    S = len(configs)
    Ks = [math.ceil(c.duration / (c.hlip.t_ssp + c.hlip.t_dsp)) for c in configs]
    K = max(Ks)
    log = steplog.zeros(S, K)          # every field, with its documented shape and dtype
    log["qp_status"][:] = 1
    status = np.zeros(S, np.int32)
    fail = -np.ones(S, np.int32)
    A_all, B_all, K_all = np.zeros((S, 3, 3)), np.zeros((S, 3)), np.zeros((S, 2, 3))
    for s, c in enumerate(configs):
        h = c.hlip
        T = h.t_ssp + h.t_dsp
        A, B = (np.asarray(m) for m in hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp))
        if c.gain.with_position:      # deadbeat on [c, p, v]
            Kd = np.asarray(hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp, with_position=True))
        else:                         # deadbeat on [p, v], no feedback of c
            Kd = np.concatenate([[0.0], np.asarray(hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp))])
        A_all[s], B_all[s], K_all[s] = A, B, Kd
        rng = np.random.default_rng(c.seed)
        xh = np.zeros((2, 3))
        xr = np.zeros((2, 3))
        nv = max(c.disturbance.noise_v, 1e-3)
        for k in range(Ks[s]):
            t = (k + 1) * T
            uh = np.array([0.3 * T, 0.0]) + xh @ Kd
            ur = uh + (xr - xh) @ Kd
            log["t"][s, k] = t
            log["t_plant"][s, k] = t
            log["stance"][s, k] = k % 2
            log["x_hlip"][s, k], log["x_robot"][s, k] = xh, xr
            log["x_est"][s, k] = xr
            log["e"][s, k] = xr - xh
            log["u_hlip"][s, k], log["u_robot"][s, k] = uh, ur
            log["ref_pos"][s, k] = [0.3 * t, 0.05 * math.sin(t)]
            log["ref_vel"][s, k] = [0.3, 0.05 * math.cos(t)]
            log["clearance"][s, k] = math.hypot(xr[0, 0] - 1.0, xr[1, 0] - 1.0) - 0.2
            w = np.zeros((2, 3))                                   # (plane, [c, p, v])
            w[:, 1] = rng.uniform(-nv / 4, nv / 4, 2)
            w[:, 2] = rng.uniform(-nv, nv, 2)
            log["w"][s, k] = w
            xh = xh @ A.T + np.outer(uh, B)
            xr = xr @ A.T + np.outer(ur, B) + w
            log["valid"][s, k] = True
        if c.swept.get("gain.type") == "lqr" and c.swept.get("mpc.alpha") == 0.1:
            status[s], fail[s] = 1, 3
            log["valid"][s, 3:] = False
    log.update(status=status, fail_step=fail, A=A_all, B=B_all, K_gain=K_all)
    return FakeLog(**log)


def _tiny(**kw):
    return sweep.parse_sweep(TINY, **kw)


def _arrays(out: Path) -> dict:
    return {f.name: store.load_chunk(f) for f in store.chunk_files(out)}


def test_run_writes_manifest_chunks_summary(tmp_path):
    sw = _tiny()
    calls = []
    res = runner.run_sweep(sw, tmp_path / "r", batch=3, progress=False,
                          simulate=lambda c: fake_simulate(c, calls=calls))
    assert res.complete and res.n_chunks == 3 and res.chunks_run == 3
    assert calls == [3, 3, 3], "last chunk padded to the batch size"
    man = json.loads((tmp_path / "r" / "manifest.json").read_text())
    assert man["sweep_text"] == TINY and man["n_scenarios"] == 8 and man["batch"] == 3
    assert man["status"] == "complete" and man["start_time"] and man["end_time"]
    assert "jax" in man["versions"] and man["jax"]["backend"]
    assert len(man["configs"]) == 8 and man["configs"][0]["name"] == sw.scenarios[0].name
    files = store.chunk_files(tmp_path / "r")
    assert [f.name for f in files] == ["chunk_00000.npz", "chunk_00001.npz", "chunk_00002.npz"]
    last = store.load_chunk(files[-1])
    assert list(last["index"]) == [6, 7] and last["x_robot"].shape[0] == 2
    assert not list((tmp_path / "r").rglob("*.tmp")), "no temporaries left"

    with open(tmp_path / "r" / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 8
    for col in ("name", "path", "shape", "gain.type", "mpc.alpha", "status", "rms_track_err",
                "max_track_err", "final_pos_err", "emax_x_p", "emax_y_v", "cov_x_inner",
                "cov_y_outer", "cov_x_heldout", "qp_failures", "min_clearance"):
        assert col in rows[0], col
    fell = [r for r in rows if r["status"] == "fell"]
    assert len(fell) == 2 and all(r["steps"] == "3" for r in fell)
    ok = [r for r in rows if r["status"] == "ok"]
    for r in ok:
        # deadbeat A_cl with box W: in-sample coverage of the outer set is 1 by construction
        assert float(r["cov_x_outer"]) == 1.0 and float(r["cov_y_outer"]) == 1.0
        assert 0.0 <= float(r["cov_x_heldout"]) <= 1.0
        assert float(r["rms_track_err"]) <= float(r["max_track_err"])


def test_error_model_state_size():
    sw = _tiny()
    log = fake_simulate([sw.scenarios[0], sw.scenarios[4]])._asdict()
    A, B, K, sl = errors.error_model(log, 0)
    assert A.shape == (3, 3) and K.shape == (2, 3) and sl == slice(0, 3)
    # deadbeat on [c, p, v]: (A + BK)^3 = 0 (Ackermann).  The gains come from JAX in float32
    # (x64 off here): entries of A are O(10), so 1e-4 absolute covers the float32 rounding.
    np.testing.assert_allclose(np.linalg.matrix_power(A + np.outer(B, K[0]), 3), 0, atol=1e-4)
    A, B, K, sl = errors.error_model(log, 1)
    assert A.shape == (2, 2) and K.shape == (2, 2) and sl == slice(1, 3)
    np.testing.assert_allclose(np.linalg.matrix_power(A + np.outer(B, K[0]), 2), 0, atol=1e-4)


def test_metrics_against_hand_computation():
    log = fake_simulate(_tiny().scenarios[:1])._asdict()
    m = metrics.scenario_metrics(log, 0, with_coverage=False)
    c = log["x_robot"][0][:, :, 0]
    r = log["ref_pos"][0]
    d = np.linalg.norm(c - r, axis=1)
    # exact formulas, float64: 1e-12 relative
    assert m["rms_pos_err"] == pytest.approx(np.sqrt(np.mean(d ** 2)), rel=1e-12)
    assert m["final_pos_err"] == pytest.approx(d[-1], rel=1e-12)
    assert m["emax_y_v"] == pytest.approx(np.abs(log["e"][0][:, 1, 2]).max(), rel=1e-12)
    assert m["min_clearance"] == pytest.approx(log["clearance"][0].min(), rel=1e-12)
    # the distance to the polyline never exceeds the distance to the time-indexed point
    assert m["max_track_err"] <= d.max() + 1e-15


def _rerun_with_placement(log: dict, du: np.ndarray) -> None:
    """Re-run scenario 0's robot of a fake log (in place) with the foot-placement errors du
    (K, 2) added to the stepping law's steps; the H-LIP and the S2S noise w stay."""
    A, B, K = log["A"][0], log["B"][0], log["K_gain"][0]
    x_h, x_r, u_h = log["x_hlip"][0], log["x_robot"][0].copy(), log["u_hlip"][0]
    u_r = log["u_robot"][0].copy()
    n = x_r.shape[0]
    for k in range(n):
        u_r[k] = u_h[k] + np.sum(K * (x_r[k] - x_h[k]), axis=1) + du[k]
        if k + 1 < n:
            x_r[k + 1] = x_r[k] @ A.T + np.outer(u_r[k], B) + log["w"][0, k]
    log["x_robot"][0], log["u_robot"][0], log["e"][0] = x_r, u_r, x_r - x_h


def test_placement_metrics_and_coverage_count_the_placement_error():
    """A robot that lands its steps a_k = 1 cm ± 1.2 cm (alternating) further along its
    (constant, 30°) heading than the law asks: place_err_along = mean a_k, place_err_rms =
    RMS a_k (1e-12: float64 sums), both 0 on the untouched log; with δu counted in W the
    in-sample coverage stays 1 (the errors obey e⁺ = A_cl e + w + B δu exactly and W ∋ 0)."""
    sc = _tiny().scenarios[0]
    log = fake_simulate([sc])._asdict()
    m0 = metrics.scenario_metrics(log, 0, with_coverage=False)
    assert m0["place_err_rms"] < 1e-12 and abs(m0["place_err_along"]) < 1e-12
    th = np.deg2rad(30.0)
    n = log["x_robot"].shape[1]
    a = 0.01 + 0.012 * (-1.0) ** np.arange(n)
    du = a[:, None] * np.array([np.cos(th), np.sin(th)])
    _rerun_with_placement(log, du)
    log["ref_heading"][0] = th
    m = metrics.scenario_metrics(log, 0, with_coverage=True)
    v = np.asarray(log["valid"][0], bool)
    assert v.all()
    assert m["place_err_along"] == pytest.approx(a.mean(), abs=1e-12)
    assert m["place_err_rms"] == pytest.approx(np.sqrt(np.mean(a ** 2)), abs=1e-12)
    assert m["cov_x_outer"] == 1.0 and m["cov_y_outer"] == 1.0


def test_polyline_distance():
    R = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    P = np.array([[0.5, 0.2], [1.3, 0.5], [2.0, 2.0], [-1.0, 0.0]])
    np.testing.assert_allclose(metrics._seg_dist(P, R), [0.2, 0.3, math.sqrt(2.0), 1.0],
                               rtol=1e-12)


def test_kill_and_resume_is_identical(tmp_path):
    sw = _tiny()
    ref = tmp_path / "ref"
    runner.run_sweep(sw, ref, batch=3, progress=False, simulate=fake_simulate)
    part = tmp_path / "part"
    r1 = runner.run_sweep(sw, part, batch=3, progress=False, simulate=fake_simulate, max_chunks=1)
    assert not r1.complete and r1.chunks_run == 1
    assert json.loads((part / "manifest.json").read_text())["status"] == "incomplete"
    assert not (part / "summary.csv").exists()

    # an interruption inside the second chunk (exception raised by the closed loop)
    def boom(cfgs):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        runner.run_sweep(sw, part, resume=True, progress=False, simulate=boom)
    assert json.loads((part / "manifest.json").read_text())["status"] == "incomplete"
    calls = []
    r2 = runner.run_sweep(sw, part, resume=True, progress=False,
                         simulate=lambda c: fake_simulate(c, calls=calls))
    assert r2.complete and r2.chunks_skipped == 1 and r2.chunks_run == 2 and calls == [3, 3]
    a, b = _arrays(ref), _arrays(part)
    assert a.keys() == b.keys()
    for f in a:
        assert a[f].keys() == b[f].keys()
        for k in a[f]:
            assert a[f][k].tobytes() == b[f][k].tobytes(), (f, k)
    assert (ref / "summary.csv").read_bytes() == (part / "summary.csv").read_bytes()


def test_resume_refuses_other_config(tmp_path):
    out = tmp_path / "r"
    runner.run_sweep(_tiny(), out, batch=3, progress=False, simulate=fake_simulate, max_chunks=1)
    other = sweep.parse_sweep(TINY.replace("0.01, 0.1", "0.01, 0.2"))
    with pytest.raises(store.StoreError, match="refusing to resume.*config differs"):
        runner.run_sweep(other, out, resume=True, progress=False, simulate=fake_simulate)
    with pytest.raises(store.StoreError, match="chunk size differs"):
        runner.run_sweep(_tiny(), out, batch=4, resume=True, progress=False, simulate=fake_simulate)
    with pytest.raises(store.StoreError, match="already holds a run"):
        runner.run_sweep(_tiny(), out, batch=3, progress=False, simulate=fake_simulate)
    res = runner.run_sweep(other, out, batch=3, overwrite=True, progress=False, simulate=fake_simulate)
    assert res.complete and res.chunks_run == 3


def test_load_log_pads_and_selects(tmp_path):
    text = TINY.replace('[[paths]]\nshape = "line"', '[[paths]]\nshape = "line"\n[paths.overrides]\nduration = 6.0')
    out = tmp_path / "r"
    runner.run_sweep(sweep.parse_sweep(text), out, batch=4, progress=False, simulate=fake_simulate)
    log = store.load_log(out)
    assert log["t"].shape == (8, 15) and log["x_robot"].shape == (8, 15, 2, 3)
    assert not log["valid"][:4, 10:].any() and np.isnan(log["t"][0, 12])
    assert np.isinf(log["clearance"][0, 12])
    sub = store.load_log(out, [6, 1])
    assert list(sub["index"]) == [6, 1]
    np.testing.assert_array_equal(sub["x_robot"][1], log["x_robot"][1])


def test_chunk_written_before_the_anchor_field_still_loads(tmp_path):
    """A chunk of an older results directory has no ``anchor`` array: it is still sound (no
    re-simulation on --resume) and loads with the tube's anchor (zeros: every run before the
    field existed planned that way), which keeps its analysis as it was."""
    out = tmp_path / "r"
    runner.run_sweep(_tiny(), out, batch=4, progress=False, simulate=fake_simulate)
    f = store.chunk_files(out)[0]
    z = dict(np.load(f))
    del z["anchor"]
    np.savez(f, **z)
    assert store.chunk_problem(f, 0, 4) is None
    store.check_chunks(out)
    log = store.load_log(out)
    assert log["anchor"].shape == (8, 3) and not log["anchor"].any()


def test_atomic_write_leaves_old_file_on_failure(tmp_path, monkeypatch):
    p = tmp_path / "f.txt"
    store.write_atomic(p, "old")

    def bad_replace(a, b):
        raise OSError("disk full")

    monkeypatch.setattr(store.os, "replace", bad_replace)
    with pytest.raises(OSError):
        store.write_atomic(p, "new")
    assert p.read_text() == "old" and list(tmp_path.iterdir()) == [p]


def test_missing_results_dir(tmp_path):
    with pytest.raises(store.StoreError, match="not found"):
        store.read_manifest(tmp_path / "nope")
    with pytest.raises(store.StoreError, match="not a results directory"):
        store.read_manifest(tmp_path)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_kill_and_resume_real_closed_loop(tmp_path):
    """Same equality with the real H-LIP closed loop (one compile, reused in-process):
    resumed chunks must be bit-identical, i.e. the rollout is deterministic per chunk."""
    from hlip_jax.simulation import execution
    sw = sweep.parse_sweep("""
[base]
duration = 2.0
[base.disturbance]
noise_v = 0.02
[[paths]]
shape = "circle"
[grid.product]
"gain.type" = ["deadbeat", "lqr"]
""")
    runner.run_sweep(sw, tmp_path / "ref", batch=1, progress=False, simulate=execution.simulate)
    r1 = runner.run_sweep(sw, tmp_path / "part", batch=1, progress=False,
                         simulate=execution.simulate, max_chunks=1)
    assert not r1.complete
    r2 = runner.run_sweep(sw, tmp_path / "part", resume=True, progress=False,
                         simulate=execution.simulate)
    assert r2.complete and r2.chunks_skipped == 1 and r2.chunks_run == 1
    a, b = _arrays(tmp_path / "ref"), _arrays(tmp_path / "part")
    for f in a:
        for k in a[f]:
            assert a[f][k].tobytes() == b[f][k].tobytes(), (f, k)
    assert a["chunk_00000.npz"]["valid"].any()


def test_no_coverage_option(tmp_path):
    out = tmp_path / "r"
    runner.run_sweep(_tiny(), out, batch=4, progress=False, simulate=fake_simulate,
                    with_coverage=False)
    rows = store.read_summary(out)
    assert all(math.isnan(r["cov_x_outer"]) for r in rows)
    assert all(math.isfinite(r["rms_track_err"]) for r in rows)
    with pytest.raises(store.StoreError, match="coverage setting differs"):
        runner.run_sweep(_tiny(), out, resume=True, progress=False, simulate=fake_simulate)


def test_push_recovery_counts_steps_until_back_and_staying():
    t = np.arange(10) * 0.5                       # pre-impact times [s]
    d = np.array([0.05, 0.05, 0.05, 0.30, 0.20, 0.10, 0.16, 0.12, 0.10, 0.08])
    # push at 1.2 s: samples from t = 1.5 on (index 3); outside 0.15 m last at index 6
    peak, steps = metrics.push_recovery(d, t, 1.2, failed=False)
    assert peak == 0.30 and steps == 4.0          # back at index 7 = 4 samples after index 3
    assert metrics.push_recovery(d, t, 1.2, failed=True) == (0.30, pytest.approx(np.nan, nan_ok=True))
    # never left the band: 0 steps; still outside at the end: NaN; push after the run: NaN
    assert metrics.push_recovery(np.full(10, 0.1), t, 1.0, failed=False) == (0.1, 0.0)
    peak, steps = metrics.push_recovery(np.r_[d[:-1], 0.2], t, 1.2, failed=False)
    assert peak == 0.30 and np.isnan(steps)
    assert all(np.isnan(metrics.push_recovery(d, t, 100.0, failed=False)))


def test_coverage_in_the_heading_frame_survives_turning_round():
    """A robot walks out and back (heading 0, a turn of 15°/step, then 180°) and over-steps by
    a ∈ [0, 1.2] cm along its own heading (±2 mm sideways).  The held-out coverage trains W on
    the first half of the steps (walking +x) and tests on the second (walking −x).  In the
    heading frame the bias is the same on both halves, so the later errors lie in E (measured
    0.96 / 0.98: the turn's own frame term puts a step or two outside; bound 0.9); in the world
    frame (selected by making the lateral gain differ by 1e-9) the second half's errors are
    pushed the other way along x (measured 0.06; bound 0.2)."""
    sc = dataclasses.replace(_tiny().scenarios[0], duration=40.0)
    log = fake_simulate([sc])._asdict()
    n = log["x_robot"].shape[1]
    k_turn = n // 2 - 6
    th = np.deg2rad(np.clip(15.0 * (np.arange(n) - k_turn), 0.0, 180.0))
    rng = np.random.default_rng(8)
    a = rng.uniform(0.0, 0.012, n)
    b = rng.uniform(-0.002, 0.002, n)
    du = np.stack([a * np.cos(th) - b * np.sin(th), a * np.sin(th) + b * np.cos(th)], axis=1)
    _rerun_with_placement(log, du)
    log["ref_heading"][0] = th
    assert errors.analysis_frame(log, 0) == "heading"
    m = metrics.scenario_metrics(log, 0)
    world = {k: v.copy() for k, v in log.items()}
    world["K_gain"][0, 1] += 1e-9
    assert errors.analysis_frame(world, 0) == "world"
    mw = metrics.scenario_metrics(world, 0)
    assert m["cov_x_heldout"] >= 0.9 and m["cov_y_heldout"] >= 0.9
    assert mw["cov_x_heldout"] < 0.2


def test_in_chunk_news_gives_simulated_time_and_an_eta_without_the_compile(monkeypatch):
    # _step_news on a fake clock: the first news (after the compile) only sets the reference;
    # later news give ETA = seconds per step × (steps left in this chunk + n × later chunks),
    # and the share of the scenarios' duration simulated so far; news closer than `every`
    # seconds are dropped except the chunk's last step
    heard = []

    class Bar:
        def update(self, done, note="", eta=None):
            heard.append((done, note, eta))

    clock = [100.0]
    monkeypatch.setattr(runner.time, "monotonic", lambda: clock[0])
    hear = runner._step_news(Bar(), 16, 0, 3, duration=30.0, later=1, every=5.0)
    hear(1, 10)                                   # after a long compile: reference only
    assert heard[-1] == (16, "chunk 1/3: step 1/10 (≈ 3.0 of 30 s simulated)", None)
    clock[0] = 102.0
    hear(2, 10)                                   # within `every`: dropped
    assert len(heard) == 1
    clock[0] = 106.0
    hear(4, 10)                                   # 2 s per step: (6 + 10 · 1) steps left
    assert heard[-1] == (16, "chunk 1/3: step 4/10 (≈ 12.0 of 30 s simulated)", 32.0)
    clock[0] = 107.0
    hear(10, 10)                                  # the last step is always told
    assert heard[-1][2] == pytest.approx(7.0 / 9.0 * 10)
    # with the step period the simulated time is k periods, at most the duration
    hear = runner._step_news(Bar(), 0, 1, 3, duration=30.0, every=0.0, step_period=0.4)
    hear(4, 100)
    assert heard[-1][1] == "chunk 2/3: step 4/100 (≈ 1.6 of 30 s simulated)"
    hear(100, 100)
    assert heard[-1][1] == "chunk 2/3: step 100/100 (≈ 30.0 of 30 s simulated)"


def test_progress_line_takes_the_in_chunk_eta_until_chunks_give_a_rate():
    import io
    out = io.StringIO()
    bar = runner.Progress(10, "s", stream=out)
    bar.update(0, "chunk 1/2: step 3/10", eta=42.0)
    assert "ETA 42s" in out.getvalue().splitlines()[-1]
    bar.update(0, "chunk 1/2: step 4/10")
    assert "ETA -" in out.getvalue().splitlines()[-1]


def test_chunk_metrics_equal_each_scenario_alone_and_the_per_set_reference():
    """A chunk's metrics are computed with every scenario's coverage sets batched: the rows
    must be those of each scenario computed alone (bit for bit: the same sets and the same
    tests), and the coverage columns those of the per-set path (estimators.fit's box method,
    sets.mrpi, the float64 gauge; tolerance 1e-9 on fractions, 1e-12 relative on volumes)."""
    from hlip_jax.analysis import estimators, runs
    cfgs = [dataclasses.replace(c, duration=6.0) for c in _tiny().scenarios]
    arrays = store.log_to_arrays(fake_simulate(cfgs), len(cfgs))
    pushes = [metrics.push_windows(c) for c in cfgs]
    batch = runner.chunk_metrics(arrays, pushes, True)
    assert sum(math.isfinite(row["cov_x_outer"]) for row in batch) == 6     # two fell early
    assert len(batch) == len(cfgs)
    for s, row in enumerate(batch):
        alone = metrics.scenario_metrics(arrays, s, True, pushes[s])
        assert row.keys() == alone.keys()
        np.testing.assert_array_equal(np.array(list(row.values()), float),
                                      np.array(list(alone.values()), float))
        Acl, _, run = runs.run_errors(arrays, s, pushes[s], 4)
        walked = run.masks.alive & ~run.masks.push_window
        for p, plane in enumerate("xy"):
            d = run.d[walked[1:] & walked[:-1], p]
            E = estimators.fit("box", Acl[p], [d], [np.zeros((0, d.shape[-1]))], [False], 0.5).E
            pts = run.kept_e(p)
            if not len(pts):                       # fell before the warm-up ended
                assert math.isnan(row[f"cov_{plane}_inner"])
                continue
            g_in, g_out = sets.gauge(E.inner, pts), sets.gauge(E.outer, pts)
            assert row[f"cov_{plane}_inner"] == pytest.approx(np.mean(g_in <= 1 + 1e-5), abs=1e-9)
            assert row[f"cov_{plane}_outer"] == pytest.approx(np.mean(g_out <= 1 + 1e-5), abs=1e-9)
            assert row[f"e_size_{plane}"] == pytest.approx(float(E.volume()), rel=1e-12)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_progress_output_does_not_change_the_cassie_numbers(tmp_path):
    """The same on the Cassie plant (two robots, 0.6 s, one process): with progress output and
    without, the chunks are the same bytes."""
    import io
    text = ('[base]\nplant = "cassie"\nduration = 0.6\n[[paths]]\nshape = "line"\n'
            '[grid.product]\nseed = [1, 2]\n')
    sw = sweep.parse_sweep(text)
    runner.run_sweep(sw, tmp_path / "loud", progress=True, stream=io.StringIO())
    runner.run_sweep(sw, tmp_path / "quiet", progress=False)
    loud, quiet = store.chunk_files(tmp_path / "loud"), store.chunk_files(tmp_path / "quiet")
    assert len(loud) == len(quiet) == 1
    assert loud[0].read_bytes() == quiet[0].read_bytes()


def test_progress_output_does_not_change_the_numbers(tmp_path):
    """The real H-LIP closed loop with progress output and with --quiet's none: the chunks are
    the same bytes (the loop runs the same segmented program either way; before, --quiet ran
    one whole-loop program whose float32 numbers differed, 0 of 4 chunks equal)."""
    import io
    text = ('[base]\nplant = "hlip"\nduration = 6.0\n[base.disturbance]\nnoise_v = 0.05\n'
            '[[paths]]\nshape = "circle"\n[grid.product]\nseed = [1, 2, 3]\n')
    sw = sweep.parse_sweep(text)
    runner.run_sweep(sw, tmp_path / "loud", batch=2, progress=True, stream=io.StringIO())
    runner.run_sweep(sw, tmp_path / "quiet", batch=2, progress=False)
    loud, quiet = store.chunk_files(tmp_path / "loud"), store.chunk_files(tmp_path / "quiet")
    assert len(loud) == len(quiet) == 2
    for a, b in zip(loud, quiet):
        assert a.read_bytes() == b.read_bytes(), a.name


def test_a_chunk_of_another_run_is_not_taken_for_this_ones(tmp_path):
    """A chunk copied from a run of another sweep into an interrupted run: --resume names it
    and simulates it again (the summary then holds this sweep's numbers); a finished
    directory holding such a chunk is refused by check_chunks (report, coverage)."""
    import shutil
    sw = _tiny()
    other = sweep.parse_sweep(TINY.replace("seed = 3", "seed = 4"))
    runner.run_sweep(other, tmp_path / "other", batch=3, progress=False, simulate=fake_simulate)
    part = tmp_path / "part"
    runner.run_sweep(sw, part, batch=3, progress=False, simulate=fake_simulate, max_chunks=1)
    shutil.copy(store.chunk_path(tmp_path / "other", 1), store.chunk_path(part, 1))
    news, calls = io.StringIO(), []
    r = runner.run_sweep(sw, part, resume=True, progress=True, stream=news,
                         simulate=lambda c: fake_simulate(c, calls=calls))
    assert r.complete and r.chunks_run == 2 and "written by another run" in news.getvalue()
    ref = tmp_path / "ref"
    runner.run_sweep(sw, ref, batch=3, progress=False, simulate=fake_simulate)
    assert (ref / "summary.csv").read_bytes() == (part / "summary.csv").read_bytes()
    shutil.copy(store.chunk_path(tmp_path / "other", 0), store.chunk_path(part, 0))
    with pytest.raises(store.StoreError, match="written by another run"):
        store.check_chunks(part)


def test_resume_in_another_precision_is_refused(tmp_path, monkeypatch):
    sw = _tiny()
    part = tmp_path / "part"
    runner.run_sweep(sw, part, batch=3, progress=False, simulate=fake_simulate, max_chunks=1)
    monkeypatch.setattr(runner, "_x64", lambda: not jax.config.jax_enable_x64)
    with pytest.raises(store.StoreError, match="precision differs"):
        runner.run_sweep(sw, part, resume=True, progress=False, simulate=fake_simulate)


def test_numpy_numbers_are_written_as_plain_numbers(tmp_path):
    """coverage.csv cells from numpy scalars read back as numbers: no 'np.float64(…)' text
    (numpy 2's repr), the same digits as Python's float repr, booleans in lower case."""
    from hlip_jax.analysis import coverage as cov
    row = {c: np.float64(0.1) + np.float64(0.2) for c in cov.COLUMNS}
    row.update(note=np.bool_(True), state="[p, v]")
    store.write_coverage_rows(tmp_path, [row])
    text = (tmp_path / store.COVERAGE).read_text()
    assert "np." not in text and repr(0.1 + 0.2) in text and ",true" in text


def test_summary_coverage_follows_the_sweeps_warmup(tmp_path):
    """The summary's per-scenario coverage leaves out the sweep's ``[analysis] warmup`` steps:
    a warm-up of 1000 steps (more than the runs have) leaves no kept error, so its coverage
    columns are NaN, where the default warm-up gives numbers (for the runs that walked)."""
    sw = _tiny()
    long = sweep.parse_sweep(TINY + "\n[analysis]\nwarmup = 1000\n")
    assert long.analysis.warmup == 1000
    runner.run_sweep(sw, tmp_path / "a", progress=False, simulate=fake_simulate)
    runner.run_sweep(long, tmp_path / "b", progress=False, simulate=fake_simulate)
    a, b = store.read_summary(tmp_path / "a"), store.read_summary(tmp_path / "b")
    walked = [r for r in a if r["status"] == "ok"]
    assert walked and all(0.0 <= float(r["cov_x_outer"]) <= 1.0 for r in walked)
    assert all(math.isnan(float(r["cov_x_outer"])) for r in b)


def test_a_run_times_its_stages(tmp_path):
    """RunResult.stages: the wall seconds of the simulation, the per-scenario analysis and
    summary.csv with coverage.csv, each >= 0, together within the run's own seconds."""
    res = runner.run_sweep(_tiny(), tmp_path / "r", batch=3, progress=False,
                           simulate=fake_simulate)
    assert set(res.stages) == {"simulation", "analysis", "summary.csv and coverage.csv"}
    assert all(v >= 0.0 for v in res.stages.values())
    assert sum(res.stages.values()) <= res.seconds + 1e-6


def test_the_first_segment_of_a_run_is_timed_from_its_chunk_start(tmp_path):
    """A closed loop that reports its walking steps (the segmented Cassie loop): the stage
    FIRST_SEGMENT is the time from the first chunk's start to its first news (the compile
    when the cache is cold), within the simulation stage; later chunks do not move it."""
    import time
    from hlip_jax.runtime import progress

    def slow_first(configs):
        time.sleep(0.2)                       # a compile stand-in before the first news
        progress.step_done(0, 2)
        progress.step_done(1, 2)
        return fake_simulate(configs)

    res = runner.run_sweep(_tiny(), tmp_path / "r", batch=3, progress=False,
                           simulate=slow_first)
    assert res.chunks_run >= 2
    first = res.stages[runner.FIRST_SEGMENT]
    assert 0.2 <= first <= res.stages["simulation"]
    assert first < 0.2 * res.chunks_run        # the first chunk's only
    assert list(res.stages)[:2] == ["simulation", runner.FIRST_SEGMENT]
