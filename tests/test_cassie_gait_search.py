"""The gait search's draws (benchmarks/cassie_gait_search.py): ranges, the reach <= s*
constraint, the reference set, the committed round-14 sweep file and the ranking."""

import csv

import numpy as np
import pytest

from hlip_jax.plants.cassie import gaits
from support import ROOT, load_benchmark

gs = load_benchmark("cassie_gait_search")

#: a drawn value is rounded to 4 decimals, so it may lie up to half a unit of the last digit
#: outside its range
RANGE_TOL = 5e-5


def test_round14_draws_meet_the_ranges_and_reach_within_landing():
    rnd = gs.ROUNDS["round14"]
    cols = gs.draw(48, 14, None, 0.15, rnd["ranges"], rnd["reach_within_landing"])
    n = len(cols["cassie.reach"])
    assert n == 48
    for k, (lo, hi, _log) in rnd["ranges"].items():
        drawn = np.array(cols[k][1:])
        assert drawn.min() >= lo - RANGE_TOL and drawn.max() <= hi + RANGE_TOL, k
    for i in range(1, n):
        s = {k: cols[k][i] for k in cols}
        # exact (REACH_TOL = 0): the check is made on the rounded values that are stored
        assert s["cassie.reach"] <= gs.landing_fraction(s["cassie.clearance"], s["cassie.strike"])
    ref = {k: cols[k][0] for k in cols}
    assert ref == {k: float(gaits.PRESETS["paper"][k]) for k in cols}
    # set 0, the reference, is the preset whose blend ends at 0.9333 / 0.8067 = 1.157 T_SSP
    assert not gs.reach_ok(ref)
    assert ref["cassie.reach"] / gs.landing_fraction(ref["cassie.clearance"],
                                                      ref["cassie.strike"]) == pytest.approx(1.157, abs=1e-3)


def test_landing_fraction_matches_the_controller():
    from hlip_jax.plants.cassie import outputs
    for c, k in [(0.0647, 0.0174), (0.05, 0.02), (0.15, 0.0), (0.1, 0.01)]:
        assert gs.landing_fraction(c, k) == pytest.approx(float(outputs.landing_fraction(c, k)), abs=1e-6)


def test_committed_round14_file_is_what_the_script_writes(tmp_path):
    committed = ROOT / "docs" / "experiments" / "cassie_gait_round14.toml"
    out = tmp_path / "r14.toml"
    gs.main(["--ranges", "round14", "--sets", "48", "--seed", "14", "--duration", "8",
             "--out", str(out)])
    # the first line names the --out path of the command that wrote it
    assert out.read_text().splitlines()[1:] == committed.read_text().splitlines()[1:]
    assert "it violates reach <= s*" in out.read_text()


def test_unconstrained_default_draws_are_unchanged():
    # the earlier rounds' draws (RANGES, no constraint) do not move with the new options
    a = gs.draw(5, 0, None, 0.15)
    b = gs.draw(5, 0, None, 0.15, gs.RANGES, False)
    assert a == b and list(a) == list(gs.RANGES)


def test_rank_marks_the_reference_and_reads_replayed_heights(tmp_path, capsys):
    ref = gaits.PRESETS["paper"]
    fields = ["cassie.clearance", "cassie.strike", "cassie.reach"]
    other = {"cassie.clearance": 0.1, "cassie.strike": 0.01, "cassie.reach": 0.7}
    rows = []
    for i, vals in enumerate([ref, other, ref, other]):
        rows.append({"index": i, "name": f"s{i}", "status": "ok" if i != 2 else "fell",
                     "rms_track_err": 0.1, **{k: vals[k] for k in fields}})
    with open(tmp_path / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    gs.rank(tmp_path, 5)
    text = capsys.readouterr().out
    assert "not measurable" in text and "[reference: the paper preset]" in text
    assert "(reach > s*)" in text
    (tmp_path / "ticks").mkdir()
    y_err = np.zeros((4, 16))
    y_err[:, 3] = [0.02, -0.02, 0.02, -0.02]
    np.savez(tmp_path / "ticks" / "1.npz", y_err=y_err)
    gs.rank(tmp_path, 5)
    text = capsys.readouterr().out
    assert "|z - z0| mean 0.020 rms 0.020 m (1 runs)" in text


def test_validation_sweep_takes_the_best_drawn_set_that_meets_the_constraint(tmp_path):
    """--validation: the reference and a set with reach > s* are passed over although they
    walk more; the file extends the 148-robot validation sweep with the chosen set's values
    (read back through the sweep loader: every scenario carries them exactly)."""
    from hlip_jax.sweepio import sweep
    ref = {k: gaits.PRESETS["paper"][k] for k in ("cassie.clearance", "cassie.strike", "cassie.reach")}
    bad = {"cassie.clearance": 0.1, "cassie.strike": 0.02, "cassie.reach": 0.99}
    good = {"cassie.clearance": 0.1, "cassie.strike": 0.01, "cassie.reach": 0.7}
    assert not gs.reach_ok(bad) and gs.reach_ok(good)
    rows = []
    for i, (vals, ok) in enumerate([(ref, 2), (bad, 2), (good, 1)]):
        for j in range(2):
            rows.append({"index": 2 * i + j, "name": f"s{i}-{j}", "status": "ok" if j < ok else "fell",
                         "rms_track_err": 0.1, "hlip.t_ssp": 0.35, **vals})
    res = tmp_path / "round"
    res.mkdir()
    with open(res / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    out = tmp_path / "val" / "v.toml"
    out.parent.mkdir()
    assert gs.validation_sweep(res, out) == {"hlip.t_ssp": "0.35", **{k: str(v) for k, v in good.items()}}
    sw = sweep.load_sweep(out)
    assert len(sw.scenarios) == 148
    for c in sw.scenarios:
        assert (c.hlip.t_ssp, c.cassie.clearance, c.cassie.strike, c.cassie.reach) == (0.35, 0.1, 0.01, 0.7)
