"""The Cassie test sets (docs/cassie_protocol/cassie_test.toml and cassie_test2.toml) have the
structure their acceptance needs and share no seed or push time with the training and
validation sets, nor the second with the first (but the paper's push, which is not held out)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pytest

from hlip_jax.simulation import arrays
from hlip_jax.sweepio import sweep

ROOT = Path(__file__).resolve().parents[1]
TEST_SET = ROOT / "docs" / "cassie_protocol" / "cassie_test.toml"
TEST_SET2 = ROOT / "docs" / "cassie_protocol" / "cassie_test2.toml"
TRAIN = [ROOT / "sweeps" / "cassie_train.toml",
         ROOT / "docs" / "experiments" / "cassie_train_pushes.toml",
         ROOT / "docs" / "experiments" / "cassie_sagittal_train.toml"]
VALIDATION = [ROOT / "sweeps" / "cassie_validation.toml",
              ROOT / "docs" / "experiments" / "cassie_speeds_val.toml"]
PAPER_PATHS = {"circle", "sinusoid", "square", "cardioid"}


@pytest.fixture(scope="module", params=[TEST_SET, TEST_SET2], ids=["test1", "test2"])
def test_set(request):
    return sweep.load_sweep(request.param).scenarios


def _seeds_and_times(files):
    seeds, times = set(), set()
    for f in files:
        for s in sweep.load_sweep(f).scenarios:
            seeds.add(s.seed)
            times.update(round(p.time, 6) for p in s.disturbance.pushes)
    return seeds, times


def _direction(deg):
    return round(deg % 360.0, 6)


def test_it_is_all_cassie_and_gpu_sized(test_set):
    assert all(s.plant == "cassie" for s in test_set)
    assert 150 <= len(test_set) <= 400
    assert max(s.duration for s in test_set) <= 40.0


def test_200n_pushes_from_four_directions_at_16_phases(test_set):
    times = defaultdict(set)
    for s in test_set:
        for p in s.disturbance.pushes:
            if p.force == 200.0 and s.name.startswith("push-200-"):
                assert p.duration == pytest.approx(0.1)
                assert s.path.shape == "line" and s.path.params.get("rotation", 0.0) == 0.0
                assert s.path.params.get("peak_speed", 0.5) == 0.5
                times[_direction(p.direction)].add(round(p.time, 6))
    # forward and backward along the line (+x), left and right of it
    assert set(times) == {0.0, 180.0, 90.0, 270.0}
    gait_step = max(s.hlip.t_ssp + s.hlip.t_dsp for s in test_set)
    for d, ts in times.items():
        assert len(ts) >= 16, d
        # spread over more than one stride of the preset's gait
        assert max(ts) - min(ts) > 2 * gait_step, d


def test_100n_pushes_from_diagonals_too(test_set):
    dirs = {_direction(p.direction) for s in test_set for p in s.disturbance.pushes
            if p.force == 100.0}
    assert {0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0} <= dirs


def test_noisy_runs_speeds_turns_and_replicates(test_set):
    noisy = [s for s in test_set if s.disturbance.noise_v == 0.03]
    assert len(noisy) >= 48
    assert {s.path.shape for s in noisy} >= {"line", "circle", "sinusoid"}
    speeds = {s.path.params["peak_speed"] for s in test_set
              if s.path.shape == "line" and not s.disturbance.pushes
              and s.disturbance.noise_v == 0.0}
    assert min(speeds) <= 0.3 and max(speeds) == 1.5 and len(speeds) >= 5
    turns = [s for s in test_set if s.path.shape == "circle" and s.path.params["radius"] == 0.1]
    assert {s.path.params.get("direction", "ccw") for s in turns} == {"ccw", "cw"}
    reps = defaultdict(set)
    for s in test_set:
        if "-rep" in s.name:
            reps[s.name.split("-rep")[0]].add(s.seed)
    assert all(len(v) >= 3 for v in reps.values()) and len(reps) >= 17


def test_the_paper_paths_with_the_classic_deadbeat_gain(test_set):
    by_gain = defaultdict(set)
    for s in test_set:
        if s.name.startswith("paper-") and s.path.shape in PAPER_PATHS:
            k = arrays.stepping_gain(s)
            by_gain[(s.gain.type, s.gain.with_position)].add(s.path.shape)
            if s.gain.type == "deadbeat" and not s.gain.with_position:
                # K = [1, T_D + coth(lambda T_S)/lambda] on [p, v], nothing on c
                assert k[0, 0] == 0.0 and k[0, 1] == pytest.approx(1.0)
            assert s.path.params.get("peak_speed", 0.5) == 0.5
    assert by_gain[("deadbeat", False)] == PAPER_PATHS
    assert by_gain[("lqr", True)] == PAPER_PATHS


def test_no_seed_or_push_time_of_training_or_validation(test_set):
    seeds = {s.seed for s in test_set}
    times = {round(p.time, 6) for s in test_set for p in s.disturbance.pushes}
    for files in (TRAIN, VALIDATION):
        other_seeds, other_times = _seeds_and_times(files)
        assert not seeds & other_seeds
        assert not times & other_times


def test_the_test_set_report_reads_every_block_of_the_test_set(test_set):
    """benchmarks/test_set_report.py sorts the test set's own scenario names into its blocks
    (none left out, none counted twice), and counts a run that is not back on the path by its
    end as the worst return."""
    from support import load_benchmark
    rep = load_benchmark("test_set_report")
    rows = [{"name": c.name, "status": "ok", "push_recovery_steps": ""} for c in test_set]
    counts = {
        "200 N": sum(len(v) for v in rep.grouped(rows, rep.PUSH200, "side").values()),
        "100 N": sum(len(v) for v in rep.grouped(rows, rep.PUSH100, "deg").values()),
        "noise": sum(len(v) for v in rep.grouped(rows, rep.NOISE, "path").values()),
        "lines": sum(len(v) for v in rep.grouped(rows, rep.LINE, "v").values()),
        "turns": sum(len(v) for v in rep.grouped(rows, rep.TURN, "dir").values()),
        "paper": sum(1 for r in rows if rep.PAPER.match(r["name"])),
    }
    assert counts == {"200 N": 64, "100 N": 32, "noise": 48, "lines": 28, "turns": 8,
                      "paper": 44}, counts
    assert sum(counts.values()) + 1 == len(rows)       # + the paper's push
    assert {len(v) for v in rep.grouped(rows, rep.PUSH200, "side").values()} == {16}
    steps = [{"push_recovery_steps": s} for s in ("4", "9", "12", "13", "")]
    assert rep.steps_text(steps) == "12 / not back (2 of 5 within 10)"


def test_the_second_test_set_shares_nothing_held_out_with_the_first():
    first, second = _seeds_and_times([TEST_SET]), _seeds_and_times([TEST_SET2])
    assert not first[0] & second[0]
    assert first[1] & second[1] == {10.0}          # the paper's push, reported before
    names = [s.name for s in sweep.load_sweep(TEST_SET2).scenarios]
    assert len(set(names)) == len(names) == 225
