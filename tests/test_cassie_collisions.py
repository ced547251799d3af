"""Leg–leg and foot–foot clearances (hlip_jax.plants.cassie.collisions) against independent
references: a ternary search for the segment distance, and C MuJoCo's own geom distance
(``mujoco.mj_geomDistance``) for the capsules of the Cassie model."""

from __future__ import annotations

import mujoco
import numpy as np
import jax.numpy as jnp

from hlip_jax.plants.cassie import collisions, model


def _point_segment(p, b0, b1):
    d = b1 - b0
    dd = d @ d
    t = 0.0 if dd == 0 else float(np.clip((p - b0) @ d / dd, 0.0, 1.0))
    return np.linalg.norm(p - b0 - t * d)


def _ternary(a0, a1, b0, b1):
    """min_s dist(a0 + s (a1 − a0), [b0, b1]): convex in s (the distance from a point moving on
    a line to a convex set), so a ternary search converges to the minimum."""
    lo, hi = 0.0, 1.0
    f = lambda s: _point_segment(a0 + s * (a1 - a0), b0, b1)
    for _ in range(200):
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        lo, hi = (lo, m2) if f(m1) <= f(m2) else (m1, hi)
    return f(0.5 * (lo + hi))


def test_segment_distance_matches_a_ternary_search():
    """Random segments, plus parallel, collinear, crossing and degenerate (point) ones; the
    closed form and the search agree to 1e-9 m (the search's bracket shrinks below 1e-30; the
    closed form's round-off is ~1e-15 m on metre-sized inputs)."""
    rng = np.random.default_rng(0)
    cases = [rng.normal(size=(4, 3)) for _ in range(300)]
    e = np.array([1.0, 0.0, 0.0])
    cases += [np.array([[0, 0, 0], e, [0, 1, 0], [0, 1, 0] + e]),             # parallel
              np.array([[0, 0, 0], e, 2 * e, 3 * e]),                          # collinear, apart
              np.array([[-1, 0, 0], e, [0, -1, 0], [0, 1, 0]]),                # crossing
              np.array([[0, 0, 0], [0, 0, 0], [1, 1, 0], [2, 1, 0]]),          # point vs segment
              np.array([[0, 0, 0], [0, 0, 0], [0, 0, 1], [0, 0, 1]])]          # two points
    a0, a1, b0, b1 = (np.array([c[i] for c in cases], float) for i in range(4))
    got = np.asarray(collisions.segment_distance(*(jnp.asarray(x) for x in (a0, a1, b0, b1))))
    want = np.array([_ternary(*(np.asarray(x, float) for x in c)) for c in cases])
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert got[-3] == 0.0 and abs(got[-1] - 1.0) < 1e-15


def _mujoco_gaps(m, d, caps):
    """(feet, legs) clearances from C MuJoCo's signed geom distances."""
    dist = np.array([[mujoco.mj_geomDistance(m, d, int(g), int(h), 1.0, None)
                      for h in caps.geoms[1]] for g in caps.geoms[0]])
    f = int(np.argmax(caps.is_foot))
    return dist[f, f], dist.min()


def test_capsules_and_gaps_match_mujoco():
    """The lower-leg capsules are the MJCF's shin (2), tarsus (2) and foot (1) capsules per
    leg, in the same order on both legs.  At the stand keyframe, and with the legs swung into
    each other (hip roll towards the midline, hip yaw crossed: the links overlap), the
    clearances equal the minimum over capsule pairs of C MuJoCo's mj_geomDistance to 1e-9 m
    (both are closed forms for capsule pairs)."""
    c = model.load()
    m = c.mj_model
    caps = collisions.capsules(m)
    assert caps.geoms.shape == (2, 5) and caps.is_foot.tolist() == [False] * 4 + [True]
    np.testing.assert_allclose(sorted(caps.radius[0]), [0.02, 0.02, 0.025, 0.03, 0.035])
    np.testing.assert_array_equal(caps.radius[0], caps.radius[1])
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "stand"))
    seen = []
    for roll, yaw in ((0.0, 0.0), (-0.3, 0.6)):
        for side, sign in (("left", 1.0), ("right", -1.0)):
            for j, v in ((f"{side}_hip_roll", sign * roll), (f"{side}_hip_yaw", sign * yaw)):
                d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)]] = v
        mujoco.mj_forward(m, d)
        got = np.asarray(collisions.gaps(caps, jnp.asarray(d.geom_xpos),
                                         jnp.asarray(d.geom_xmat.reshape(-1, 3, 3))))
        np.testing.assert_allclose(got, _mujoco_gaps(m, d, caps), atol=1e-9)
        seen.append(got)
    assert seen[0][1] > 0.05          # standing: the legs are well apart
    assert seen[1][1] < 0.0           # crossed: the links overlap, reported as negative
