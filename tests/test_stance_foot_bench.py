"""benchmarks/cassie_stance_foot.py's per-step measure of the stance foot's motion in SSP,
on synthetic foot tracks with known motion (exact: plain array arithmetic, 1e-12)."""


import numpy as np


from support import load_benchmark

stance_motion = load_benchmark("cassie_stance_foot").stance_motion


def test_stance_foot_motion_on_known_tracks():
    K, T = 3, 10
    feet = np.zeros((K, T, 2, 3))
    phase = np.zeros((K, T), int)
    phase[:, 2:] = 1                                        # ticks 2..9 are SSP
    s = np.linspace(0.0, 1.0, T)
    for k in range(K):
        stance, swing = k % 2, 1 - k % 2
        feet[k, :, swing, 0] = 0.3 * s                      # the swing foot travels 0.3 m
        feet[k, :, stance, 0] = 0.002 * (k + 1) * s         # the stance foot slides a little
        feet[k, :, stance, 2] = -0.001 * s
    valid = np.array([True, True, False])
    r = stance_motion(feet, phase, valid)
    assert r.shape == (2, 6)
    np.testing.assert_array_equal(r[:, 0], [0, 1])          # valid steps only
    np.testing.assert_array_equal(r[:, 1], [0, 1])          # stance = the foot that moved least
    slide = 0.002 * np.array([1, 2]) * (s[-1] - s[2])
    np.testing.assert_allclose(r[:, 2], slide, atol=1e-12)
    np.testing.assert_allclose(r[:, 3], 0.0, atol=1e-12)
    np.testing.assert_allclose(r[:, 4], slide, atol=1e-12)
    np.testing.assert_allclose(r[:, 5], -0.001 * (s[-1] - s[2]), atol=1e-12)
