"""The batched box mRPI brackets (hlip_jax.core.box_mrpi) against the one-set path
(sets.mrpi, sets.gauge in float64 numpy): the same sets bit for bit, the same membership
decisions away from the threshold, and a failed row that marks only itself."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hlip_jax.core import box_mrpi, hlip, sets


def _stable(rng, n: int) -> np.ndarray:
    """A random Schur-stable matrix (spectral radius 0.5-0.9)."""
    A = rng.normal(size=(n, n))
    return A * rng.uniform(0.5, 0.9) / np.max(np.abs(np.linalg.eigvals(A)))


def _boxes(rng, R: int, n: int):
    lo = rng.uniform(-0.05, 0.01, (R, n))
    hi = lo + rng.uniform(0.001, 0.06, (R, n))
    hi[0, -1] = lo[0, -1]                  # a flat axis: widened to min_halfwidth
    return lo, hi


@pytest.mark.parametrize("n", [1, 2, 3])
def test_each_row_is_the_one_set_path_bit_for_bit(n):
    """s, α, centre, facet half-widths and volume equal sets.mrpi's for every row (exact
    equality: the batch runs the same float operations in the same order)."""
    rng = np.random.default_rng(n)
    A = _stable(rng, n)
    lo, hi = _boxes(rng, 12, n)
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6)
    assert bs.ok.all()
    for r in range(len(lo)):
        E = sets.mrpi(A, sets.Box(lo[r], hi[r]), min_halfwidth=1e-6)
        assert (E.s, E.alpha) == (bs.s[r], bs.alpha[r])
        np.testing.assert_array_equal(E.inner.center, bs.centre[r])
        np.testing.assert_array_equal(E.inner.offsets, bs.offsets[r])
        assert float(E.volume()) == bs.volume[r]


def test_a_deadbeat_gain_gives_the_exact_finite_sum():
    """The H-LIP deadbeat closed loop on [p, v] is nilpotent (A_cl² = 0): s = 2, α = 0, the
    inner and outer sets coincide (sets.mrpi says exact)."""
    A, B = (np.asarray(m, np.float64) for m in hlip.s2s_matrices(0.8, 0.3, 0.1))
    K = np.asarray(hlip.deadbeat_gain(0.8, 0.3, 0.1), np.float64)
    Acl = A[1:, 1:] + np.outer(B[1:], K)
    bs = box_mrpi.box_sets(Acl, [[-0.01, -0.03]], [[0.01, 0.03]], 1e-6)
    E = sets.mrpi(Acl, sets.Box(np.array([-0.01, -0.03]), np.array([0.01, 0.03])))
    assert E.exact and bs.s[0] == E.s == 2 and bs.alpha[0] == 0.0
    pts = np.random.default_rng(0).uniform(-0.08, 0.08, (200, 2))
    cov = box_mrpi.coverage(bs, [pts])
    assert cov.inner[0] == cov.outer[0] == pytest.approx(np.mean(sets.gauge(E.inner, pts) <= 1.0))


@pytest.mark.parametrize("n", [2, 3])
def test_membership_decides_as_the_float64_gauge(n):
    """Coverage fractions of random points equal the float64 numpy gauge's decisions
    (g ≤ 1 + tol inner, g ≤ (1 + tol)/(1 − α) outer), points within 1e-4 of either threshold
    left out (the kernel computes in float32 without x64)."""
    rng = np.random.default_rng(10 + n)
    A = _stable(rng, n)
    lo, hi = _boxes(rng, 9, n)
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6)
    pts = []
    for r in range(len(lo)):
        E = sets.mrpi(A, sets.Box(lo[r], hi[r]), min_halfwidth=1e-6)
        scale = np.max(np.abs(E.outer.offsets)) * 1.5
        P = bs.centre[r] + rng.uniform(-scale, scale, (int(rng.integers(1, 60)), n))
        gi, go = sets.gauge(E.inner, P), sets.gauge(E.outer, P)
        pts.append(P[(np.abs(gi - 1) > 1e-4) & (np.abs(go - 1) > 1e-4)])
    cov = box_mrpi.coverage(bs, pts)
    for r, P in enumerate(pts):
        E = sets.mrpi(A, sets.Box(lo[r], hi[r]), min_halfwidth=1e-6)
        if not len(P):
            assert math.isnan(cov.inner[r])
            continue
        assert cov.inner[r] == np.mean(sets.gauge(E.inner, P) <= 1.0)
        assert cov.outer[r] == np.mean(sets.gauge(E.outer, P) <= 1.0)
        assert cov.n[r] == len(P)


def test_rows_split_over_several_calls_give_the_same_coverage(monkeypatch):
    """A template's rows go to the kernel at most ROWS_PER_CALL at a time (bounding the host's
    padded arrays for chunks of thousands of scenarios): two rows per call, or all at once,
    give equal fractions."""
    rng = np.random.default_rng(5)
    A = _stable(rng, 3)
    lo, hi = _boxes(rng, 7, 3)
    lo[3:], hi[3:] = lo[3], hi[3]               # four equal boxes: one template for them
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6)
    assert len(set(bs.template)) == 4
    pts = [rng.normal(0, 0.03, (int(rng.integers(1, 30)), 3)) for _ in range(7)]
    whole = box_mrpi.coverage(bs, pts)
    monkeypatch.setattr(box_mrpi, "ROWS_PER_CALL", 2)
    split = box_mrpi.coverage(bs, pts)
    np.testing.assert_array_equal(whole.inner, split.inner)
    np.testing.assert_array_equal(whole.outer, split.outer)


def test_a_failed_row_marks_only_itself():
    """A box with a NaN bound and one whose order exceeds s_max get ok = False and NaN
    coverage and volume; the other rows are those of a batch without them."""
    rng = np.random.default_rng(3)
    A = np.diag([0.9, 0.5, 0.2])      # α(s) = 0.9^s: ~100 terms for 3 cm, ~150 for 5 m
    lo, hi = _boxes(rng, 4, 3)
    lo[1, 0] = np.nan
    hi[2, 0] = lo[2, 0] + 10.0
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6, s_max=120)
    assert bs.ok.tolist() == [True, False, False, True]
    assert np.isnan(bs.volume[1:3]).all() and bs.s[2] == 0
    alone = box_mrpi.box_sets(A, lo[[0, 3]], hi[[0, 3]], 1e-6, s_max=120)
    np.testing.assert_array_equal(alone.volume, bs.volume[[0, 3]])
    pts = [rng.normal(0, 0.02, (5, 3)) for _ in range(4)]
    cov = box_mrpi.coverage(bs, pts)
    assert np.isnan(cov.inner[1:3]).all() and np.isfinite(cov.inner[[0, 3]]).all()
    with pytest.raises(ValueError, match="s_max"):
        sets.mrpi(A, sets.Box(lo[2], hi[2]), s_max=120)


def test_the_tolerance_covers_the_kernels_precision():
    """The kernels compute in float32 without x64, float64 with it: the tolerance is at least
    50 epsilons of that precision (a boundary point must not be decided by rounding); a
    larger one is kept."""
    import jax
    eps = np.finfo(np.float64 if jax.config.jax_enable_x64 else np.float32).eps
    assert box_mrpi.compute_tolerance(1e-9) == max(1e-9, 50 * float(eps))
    assert box_mrpi.compute_tolerance(1e-3) == 1e-3


def test_templates_kept_on_disk_are_found_by_a_later_process_and_damage_is_ignored(tmp_path):
    """With a template store the facet templates are written once and read back equal (a new
    process's lru cache is empty, as here after cache_clear); a damaged or foreign file is
    ignored and the template built again, equal to the stored one."""
    from hlip_jax.runtime import array_cache
    rng = np.random.default_rng(7)
    A = _stable(rng, 3)
    lo, hi = _boxes(rng, 3, 3)
    store = array_cache.ArrayCache(tmp_path / "box_templates")
    sets.box_sum_template.cache_clear()
    sets.keep_templates_in(store)
    try:
        first = box_mrpi.box_sets(A, lo, hi, 1e-6)
        files = sorted(store.path.glob("*.npz"))
        assert files and len(files) == len({k for k in first.template})
        sets.box_sum_template.cache_clear()
        again = box_mrpi.box_sets(A, lo, hi, 1e-6)
        for a, b in zip(first.offsets, again.offsets):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(first.volume, again.volume)
        assert all(store.load(sets.template_key(*k)) is not None for k in first.template)
        files[0].write_bytes(b"not a template")
        for f in files[1:]:                      # a valid npz whose digest does not match
            np.savez(f, N=np.zeros((2, 3)), H=np.zeros((2, 3)), T=np.zeros((3, 3, 3)),
                     _digest=np.zeros(32, np.uint8))
        sets.box_sum_template.cache_clear()
        assert all(store.load(sets.template_key(*k)) is None for k in first.template)
        third = box_mrpi.box_sets(A, lo, hi, 1e-6)
        np.testing.assert_array_equal(first.volume, third.volume)
        assert all(store.load(sets.template_key(*k)) is not None for k in first.template)
        sizes = sorted(f.stat().st_size for f in store.path.glob("*.npz"))
        assert store.prune(budget=sum(sizes) - 1) >= sizes[0]          # least recently used go
        assert len(list(store.path.glob("*.npz"))) < len(sizes)
    finally:
        sets.keep_templates_in(None)
        sets.box_sum_template.cache_clear()
