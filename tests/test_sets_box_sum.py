"""The truncated sum of a box, F_s = ⊕_{i<s} A^i W (sets.truncated_sum's box path): its facets
from the per-(A, s) template, its half-widths H r and its closed-form volume, against the
general zonotope construction, the determinant sum and closed forms."""

import numpy as np
import pytest

from hlip_jax.core import sets


def _cases(n: int, count: int = 12, seed: int = 0):
    rng = np.random.default_rng(seed)
    for t in range(count):
        A = rng.normal(size=(n, n))
        A *= rng.uniform(0.3, 0.97) / max(abs(np.linalg.eigvals(A)))
        if t == 0:
            A = np.diag(np.linspace(0.5, 0.2, n))          # coplanar generator families
        if t == 1:
            A = np.eye(n, k=1)                             # nilpotent: terms vanish
        r = rng.uniform(0.001, 0.1, n)
        c = rng.normal(size=n) * 0.01
        s = int(rng.integers(2, 30))
        prefix = int(rng.integers(0, s // 2 + 1)) if (s >= 6 and n == 3) else 0
        yield A, r, c, s, prefix


@pytest.mark.parametrize("n", [1, 2, 3])
def test_box_sum_facets_and_volume_equal_the_general_construction(n):
    # tolerance: 1e-12 relative (the same sums in another order)
    rng = np.random.default_rng(1)
    for A, r, c, s, prefix in _cases(n):
        fast = sets.truncated_sum(A, sets.Box(c - r, c + r), s, n_prefix_terms=prefix)
        G = fast.generators
        # every stored normal's half-width is Σ_k |N_f · g_k| over the generators
        h = np.abs(fast.normals @ G.T).sum(axis=1)
        np.testing.assert_allclose(fast.offsets, h, rtol=1e-12, atol=0)
        ref = sets.zonotope(fast.center, G, n_prefix=prefix * n)
        if ref.prefix_offsets is not None:
            n0 = len(fast.prefix_offsets)
            h0 = np.abs(fast.normals[:n0] @ G[:prefix * n].T).sum(axis=1)
            np.testing.assert_allclose(fast.prefix_offsets, h0, rtol=1e-12, atol=0)
        else:
            assert fast.prefix_offsets is None
        # the same set: membership of random points agrees with the general facets
        pts = c + rng.normal(size=(3000, n)) * fast.offsets.max() * 0.4
        assert np.array_equal(np.asarray(fast.contains(pts)), np.asarray(ref.contains(pts)))
        direct = sets.Zonotope(fast.center, G).volume()            # the determinant sum
        assert fast.known_volume == pytest.approx(direct, rel=1e-12)


def test_box_sum_volume_closed_forms():
    # s = 1: the box itself, volume Π 2 r_j; diagonal A: F_s is the box of half-widths
    # r_j Σ_{i<s} |a_j|^i, volume Π 2 r_j (1 − |a_j|^s) / (1 − |a_j|)
    r = np.array([0.02, 0.05, 0.1])
    box = sets.truncated_sum(np.diag([0.9, -0.5, 0.3]), sets.Box(-r, r), 1)
    assert box.volume() == pytest.approx(np.prod(2 * r), rel=1e-13)
    a, s = np.array([0.9, -0.5, 0.3]), 17
    F = sets.truncated_sum(np.diag(a), sets.Box(-r, r), s)
    half = r * (1 - np.abs(a) ** s) / (1 - np.abs(a))
    assert F.volume() == pytest.approx(np.prod(2 * half), rel=1e-12)


def test_mrpi_outer_volume_is_the_scaled_inner_volume():
    # E_outer = (1 − α)⁻¹ (E_inner − c) + c: volume × (1 − α)⁻ⁿ; against the determinant sum
    A = np.array([[0.95, 0.1, 0.0], [-0.2, 0.6, 0.1], [0.0, 0.3, 0.5]])
    r = np.array([0.01, 0.02, 0.03])
    E = sets.mrpi(A, sets.Box(-r, r))
    assert not E.exact
    k = 1.0 / (1.0 - E.alpha)
    assert E.volume() == pytest.approx(E.inner.volume() * k ** 3, rel=1e-12)
    direct = sets.Zonotope(E.outer.center, E.outer.generators).volume()
    assert E.volume() == pytest.approx(direct, rel=1e-12)


def test_the_template_is_shared_across_boxes():
    # boxes of one A and s reuse one template: the second box costs no new facet search
    A = np.array([[0.8, 0.2, 0.0], [0.0, 0.7, 0.1], [0.1, 0.0, 0.6]])
    sets.truncated_sum(A, sets.Box(-np.ones(3), np.ones(3)), 9)
    before = sets.box_sum_cache_info().misses
    out = sets.truncated_sum(A, sets.Box(-np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0])), 9)
    assert sets.box_sum_cache_info().misses == before
    assert np.all(out.offsets > 0)


def test_vertices_survive_a_qhull_merge_failure(monkeypatch):
    # Qhull's exact merging can fail on thousands of nearly parallel facets (a report crashed
    # with "wide merge error" on a 1024-run GPU sweep); the vertices then come from joggled
    # input: their hull's volume is the zonotope's within 1e-9 (relative)
    import scipy.spatial

    real = scipy.spatial.HalfspaceIntersection

    def strict(halfspaces, interior, qhull_options=None, **kw):
        if qhull_options is None:
            raise scipy.spatial.QhullError("QH6271 qhull topology error (wide merge)")
        return real(halfspaces, interior, qhull_options=qhull_options, **kw)

    monkeypatch.setattr(scipy.spatial, "HalfspaceIntersection", strict)
    z = sets.zonotope(np.zeros(3), np.random.default_rng(3).normal(size=(10, 3)))
    V = sets.vertices(z)
    assert scipy.spatial.ConvexHull(V).volume == pytest.approx(z.volume(), rel=1e-9)
    assert np.all(np.asarray(z.contains(V, 1e-9)))


def test_gauge_within_decides_as_the_gauge_does():
    # the prefix facets decide most points, the rest take every facet: the same decision as
    # gauge <= level on a slow 3-state mRPI zonotope with prefix facets (exact: no tolerance)
    A = np.array([[0.97, 0.1, 0.0], [-0.2, 0.6, 0.1], [0.0, 0.3, 0.5]])
    r = np.array([0.01, 0.02, 0.03])
    E = sets.mrpi(A, sets.Box(-r, r))
    assert E.outer.prefix_offsets is not None
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(4000, 3)) * np.abs(sets.vertices(E)).max(axis=0) * 0.7
    for level in (0.5, 1.0, 1.3):
        want = sets.gauge(E, pts) <= level
        assert np.array_equal(sets.gauge_within(E, pts, level), want)
        assert 0 < want.sum() < len(pts)
    scaled = sets.Scaled(E, 0.8)
    assert np.array_equal(scaled.contains(pts, 1e-6), sets.gauge(E, pts) <= 0.8 * (1 + 1e-6))
