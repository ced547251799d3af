"""Edge cases of the batched box mRPI brackets (hlip_jax.core.box_mrpi) in float32, of the
template store on disk (hlip_jax.runtime.array_cache) and of the set outlines
(hlip_jax.presentation.set_figures).

The suite runs JAX in float64 (conftest); the ``float32`` fixture switches x64 off for one
test, so the membership kernel computes as it does by default (float32, tolerance 50 eps₃₂)."""

from __future__ import annotations

import errno
import threading

import numpy as np
import pytest

from hlip_jax.core import box_mrpi, sets
from hlip_jax.presentation import set_figures
from hlip_jax.runtime import array_cache

A3 = np.array([[0.6, 0.2, 0.1], [-0.1, 0.5, 0.2], [0.05, 0.1, 0.3]])   # spectral radius ~0.6


def _support_points(E, D) -> np.ndarray:
    """c + Σ_j sign(dᵀg_j) g_j of a zonotope E for each row d of D: points on E's boundary
    (a vertex where d is inside a normal cone), gauge 1 exactly in real arithmetic."""
    c, G = sets.as_float64(E.center), sets.as_float64(E.generators)
    return c + np.sign(D @ G.T) @ G


# ---------------------------------------------------------------------------------------------
# 1. float32 edge cases
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("centre, halfwidth", [(1.0, 1e-3), (0.5, 1e-9), (100.0, 1e-3),
                                               (0.0, 1e-12), (0.0, 1e3)])
def test_a_small_set_off_the_origin_is_decided_in_float32(float32, centre, halfwidth):
    """The vertices of F_s (gauge 1 in float64) count inside and those vertices scaled by 1.01
    about c* (gauge 1.01) outside, also for a set whose width is tiny against its distance
    from the origin: (x − c*) formed in float32 kept none of its digits (a 1 mm box 1 m away
    put its own vertices outside).  Tolerance: the kernel's, 50 eps₃₂ = 6e-6 of the gauge."""
    assert box_mrpi.compute_tolerance(1e-9) == 50 * float(np.finfo(np.float32).eps)
    lo, hi = np.full((1, 3), centre - halfwidth), np.full((1, 3), centre + halfwidth)
    bs = box_mrpi.box_sets(A3, lo, hi, 0.0)
    E = sets.mrpi(A3, sets.Box(lo[0], hi[0]))
    V = _support_points(E.inner, np.random.default_rng(0).normal(size=(64, 3)))
    c = bs.centre[0]
    # float64 itself rounds c* + Σ g_j to eps₆₄ |c*|: 1e-7 of the gauge for the 1e-9 box
    np.testing.assert_allclose(sets.gauge(E.inner, V), 1.0, rtol=1e-6)
    assert box_mrpi.coverage(bs, [V]).outer[0] == 1.0
    bs2 = box_mrpi.box_sets(A3, np.repeat(lo, 2, 0), np.repeat(hi, 2, 0), 0.0)
    cov = box_mrpi.coverage(bs2, [V, c + 1.01 * (V - c)])
    assert cov.inner.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("min_halfwidth", [1e-6, 0.0])
def test_edge_boxes_in_float32_fail_alone_and_equal_the_one_set_path(float32, min_halfwidth):
    """One batch with a flat axis, a box flat in every axis, a 1e-12 and a 1e3 half-width, and
    NaN / ±inf bounds: the non-finite rows (and, without widening, the flat ones) get ok =
    False, s = 0 and NaN coverage and volume, and the other rows are those of a batch without
    them; every ok row is sets.mrpi's bit for bit (s, α, c*, offsets, volume: exact equality)
    and its coverage is the float64 gauge's decision for points at least 1e-4 from either
    threshold (the kernel is float32); a NaN or inf point counts outside its own row only."""
    rng = np.random.default_rng(1)
    lo = rng.uniform(-0.05, 0.0, (8, 3))
    hi = lo + rng.uniform(0.001, 0.05, (8, 3))
    hi[0, 2] = lo[0, 2]                                   # one flat axis
    lo[1, 0] = np.nan
    hi[2, 1] = np.inf
    lo[3, 2] = -np.inf
    hi[4] = lo[4]                                         # flat in every axis
    lo[5, 0], hi[5, 0] = 0.3, 0.3 + 2e-12                 # 1e-12 half-width
    lo[6, 1], hi[6, 1] = -1e3, 1e3                        # 1e3 half-width
    with np.errstate(invalid="ignore"):
        bs = box_mrpi.box_sets(A3, lo, hi, min_halfwidth)
    good = [0, 4, 5, 6, 7] if min_halfwidth else [5, 6, 7]
    assert np.flatnonzero(bs.ok).tolist() == good
    bad = ~bs.ok
    assert np.isnan(bs.volume[bad]).all() and (bs.s[bad] == 0).all()
    alone = box_mrpi.box_sets(A3, lo[good], hi[good], min_halfwidth)
    np.testing.assert_array_equal(alone.volume, bs.volume[good])
    np.testing.assert_array_equal(alone.offsets[-1], bs.offsets[7])
    pts = [rng.normal(0, 0.03, (6, 3)) for _ in range(8)]
    for r in good:
        E = sets.mrpi(A3, sets.Box(lo[r], hi[r]), min_halfwidth=min_halfwidth)
        assert (E.s, E.alpha) == (bs.s[r], bs.alpha[r])
        np.testing.assert_array_equal(E.inner.center, bs.centre[r])
        np.testing.assert_array_equal(E.inner.offsets, bs.offsets[r])
        assert float(E.volume()) == bs.volume[r]
        extent = np.sum(np.abs(sets.as_float64(E.inner.generators)), axis=0)
        P = bs.centre[r] + rng.uniform(-1.2, 1.2, (300, 3)) * extent
        gi, go = sets.gauge(E.inner, P), sets.gauge(E.outer, P)
        pts[r] = P[(np.abs(gi - 1) > 1e-4) & (np.abs(go - 1) > 1e-4)]
        assert 0 < np.mean(sets.gauge(E.inner, pts[r]) <= 1) < 1      # both decisions occur
    whole = box_mrpi.coverage(bs, pts)
    pts_bad = [np.concatenate([p, [[np.nan, 0, 0], [np.inf, 0, 0]]]) for p in pts]
    cov = box_mrpi.coverage(bs, pts_bad)
    assert np.isnan(cov.inner[bad]).all() and np.isnan(cov.outer[bad]).all()
    for r in good:
        E = sets.mrpi(A3, sets.Box(lo[r], hi[r]), min_halfwidth=min_halfwidth)
        assert whole.inner[r] == np.mean(sets.gauge(E.inner, pts[r]) <= 1.0)
        assert whole.outer[r] == np.mean(sets.gauge(E.outer, pts[r]) <= 1.0)
        k = len(pts[r])                              # the two non-finite points count outside
        assert cov.inner[r] * (k + 2) == pytest.approx(whole.inner[r] * k, abs=1e-9)
        assert cov.outer[r] * (k + 2) == pytest.approx(whole.outer[r] * k, abs=1e-9)


@pytest.mark.parametrize("A", [np.diag([1.0, 1.0], 1), np.zeros((3, 3)),
                               np.array([[0.0, 1.0], [0.0, 0.0]])],
                         ids=["shift3", "zero3", "shift2"])
def test_deadbeat_matrices_and_points_on_facets_in_float32(float32, A):
    """A nilpotent A_cl (A^s = 0, s = n for a shift, 1 for zero): s and α = 0 as sets.mrpi
    (exact), outer = inner; points on the set's boundary (support points, gauge 1 in float64)
    count inside, the same scaled by 1 + 1e-3 about c* outside."""
    n = A.shape[0]
    lo, hi = np.array([[-0.01, -0.03, 0.02][:n]]), np.array([[0.01, 0.05, 0.03][:n]])
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6)
    E = sets.mrpi(A, sets.Box(lo[0], hi[0]), min_halfwidth=1e-6)
    assert E.exact and bs.s[0] == E.s and bs.alpha[0] == 0.0
    np.testing.assert_array_equal(bs.offsets[0], E.inner.offsets)
    V = _support_points(E.inner, np.random.default_rng(2).normal(size=(128, n)))
    c = bs.centre[0]
    cov = box_mrpi.coverage(box_mrpi.box_sets(A, np.repeat(lo, 2, 0), np.repeat(hi, 2, 0),
                                              1e-6), [V, c + (1 + 1e-3) * (V - c)])
    assert cov.inner.tolist() == [1.0, 0.0] and cov.outer.tolist() == [1.0, 0.0]


# ---------------------------------------------------------------------------------------------
# 2.-3. padding and chunking
# ---------------------------------------------------------------------------------------------

def _spy(monkeypatch) -> list:
    """Record (y.shape, h.shape, N.shape, rows, points) of each call of the membership
    kernel."""
    calls, kernel = [], box_mrpi._gauges

    def spy(N, h, y, rows, points):
        calls.append((y.shape, h.shape, N.shape, rows, points))
        return kernel(N, h, y, rows=rows, points=points)

    monkeypatch.setattr(box_mrpi, "_gauges", spy)
    return calls


def _fast_boxes(rng, R: int):
    """R boxes of one template under A = diag(0.1, 0.2) (s = 7 for all), and their points."""
    lo = -rng.uniform(0.010, 0.011, (R, 2))
    hi = rng.uniform(0.010, 0.011, (R, 2))
    return lo, hi, [rng.normal(0, 0.012, (int(k), 2)) for k in rng.integers(1, 20, R)]


@pytest.mark.parametrize("R", [0, 1, 512, 513, 1100])
def test_rows_are_padded_and_chunked_and_decide_as_float64(float32, monkeypatch, R):
    """R rows of one template (R = 0, 1, 512, 513, 1100): one kernel call per ROWS_PER_CALL
    rows (⌈R/512⌉ calls), each of at most 512 padded rows, so the largest call's arrays
    (rows × points × n, rows × facets) do not grow with R; the fractions equal the float64
    gauge's decisions (points within 1e-4 of the threshold left out)."""
    rng = np.random.default_rng(R)
    A = np.diag([0.1, 0.2])
    lo, hi, pts = _fast_boxes(rng, R)
    bs = box_mrpi.box_sets(A, lo.reshape(R, 2), hi.reshape(R, 2), 1e-6)
    assert bs.ok.all() and len(set(bs.template)) == min(R, 1)
    for r in range(R):
        z = sets.zonotope(bs.centre[r], np.concatenate([np.diag(bs.radius[r]) @ np.linalg
                                                        .matrix_power(A, i).T
                                                        for i in range(bs.s[r])]))
        g = sets.gauge(z, pts[r])
        pts[r] = pts[r][np.abs(g - 1) > 1e-4] if np.any(np.abs(g - 1) > 1e-4) else pts[r][:0]
    calls = _spy(monkeypatch)
    cov = box_mrpi.coverage(bs, pts)
    assert cov.n.dtype.kind == "i" and cov.n.shape == (R,)
    counted = sum(len(p) > 0 for p in pts)
    assert len(calls) == -(-counted // 512)
    assert all(y[0] <= box_mrpi.ROWS_PER_CALL and h[0] == y[0] for y, h, _, _, _ in calls)
    for (y, h, N, rows, points) in calls:                  # one block's entries are bounded
        assert rows * points * N[0] <= box_mrpi.GAUGE_BLOCK
        assert y[0] % rows == 0 and y[1] % points == 0
    for r in range(R):
        if not len(pts[r]):
            assert np.isnan(cov.inner[r])
            continue
        z = sets.zonotope(bs.centre[r], np.concatenate([np.diag(bs.radius[r]) @ np.linalg
                                                        .matrix_power(A, i).T
                                                        for i in range(bs.s[r])]))
        np.testing.assert_allclose(z.offsets, bs.offsets[r], rtol=1e-12)
        assert cov.inner[r] == np.mean(sets.gauge(z, pts[r]) <= 1.0)


def test_a_block_is_bounded_also_when_one_rows_points_exceed_it(float32, monkeypatch):
    """With GAUGE_BLOCK below one row's points × facets (a long run against a set of
    thousands of facets), the kernel splits the points too: every block has at most
    GAUGE_BLOCK entries (it had a whole row's), and the gauges are those of one block per
    row (equal to 1e-6 relative: float32 sums in another grouping)."""
    rng = np.random.default_rng(6)
    lo = rng.uniform(-0.05, -0.01, (3, 3))
    bs = box_mrpi.box_sets(A3, lo, lo + 0.04, 1e-6)
    rows = np.flatnonzero([t == bs.template[0] for t in bs.template])
    pts = [rng.normal(0, 0.03, (300, 3)) for _ in rows]
    whole = box_mrpi.gauges(bs, rows, pts)
    F = sets.bucket(len(bs.offsets[0]))
    monkeypatch.setattr(box_mrpi, "GAUGE_BLOCK", 32 * F)
    calls = _spy(monkeypatch)
    split = box_mrpi.gauges(bs, rows, pts)
    (y, _, N, blk, points), = calls
    assert y[1] == 512 and blk == 1 and points == 32 and blk * points * N[0] <= 32 * F
    for a, b in zip(whole, split):
        np.testing.assert_allclose(a, b, rtol=1e-6)


def test_rows_of_different_orders_go_to_separate_calls(float32, monkeypatch):
    """Boxes that need different s (a wider box needs more terms for the same ε) have
    different templates; each kernel call holds rows of one template only (its facet count),
    and each row's fraction is the one it gets alone."""
    rng = np.random.default_rng(4)
    A = np.diag([0.5, 0.3])
    scale = np.repeat([1e-3, 1e-1, 1e1], 3)
    lo, hi = -scale[:, None] * np.ones((9, 2)), scale[:, None] * np.ones((9, 2))
    bs = box_mrpi.box_sets(A, lo, hi, 1e-6)
    assert len(set(bs.s.tolist())) == 3 and len(set(bs.template)) == 3
    pts = [rng.normal(0, 2 * s, (10, 2)) for s in scale]
    calls = _spy(monkeypatch)
    cov = box_mrpi.coverage(bs, pts)
    assert len(calls) == 3
    for r in range(9):
        one = box_mrpi.coverage(box_mrpi.box_sets(A, lo[[r]], hi[[r]], 1e-6), [pts[r]])
        assert (cov.inner[r], cov.outer[r]) == (one.inner[0], one.outer[0])


# ---------------------------------------------------------------------------------------------
# 4. the template store on hostile directories
# ---------------------------------------------------------------------------------------------

ARRAYS = {"N": np.arange(6.0).reshape(2, 3), "H": np.ones((2, 3))}


def _same(a: dict, b: dict) -> bool:
    return a is not None and set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)


def test_another_keys_file_under_this_keys_name_is_not_returned(tmp_path):
    """A valid file of key k2 copied to k1's name (same names, dtypes and shapes) is a
    mismatch, not k1's arrays: load gives None, and a save of k1 replaces it."""
    store = array_cache.ArrayCache(tmp_path / "c")
    other = {"N": -ARRAYS["N"], "H": 2 * ARRAYS["H"]}
    store.save(b"k1", ARRAYS)
    store.save(b"k2", other)
    assert _same(store.load(b"k2"), other)
    store.file(b"k1").write_bytes(store.file(b"k2").read_bytes())
    assert store.load(b"k1") is None
    store.save(b"k1", ARRAYS)
    assert _same(store.load(b"k1"), ARRAYS)


def test_a_swapped_template_file_does_not_change_the_sets(tmp_path):
    """End to end: the store's files of two closed loops (both 3-state) swapped; box_sets
    with an empty in-process cache builds each template again and its sets equal those made
    without a store (exact equality)."""
    rng = np.random.default_rng(7)
    lo = rng.uniform(-0.05, -0.01, (2, 3))
    hi = lo + 0.04
    A2 = A3 * 0.9
    store = array_cache.ArrayCache(tmp_path / "box_templates")
    sets.box_sum_template.cache_clear()
    try:
        plain = [box_mrpi.box_sets(A, lo, hi, 1e-6) for A in (A3, A2)]
        sets.box_sum_template.cache_clear()
        sets.keep_templates_in(store)
        for A in (A3, A2):
            box_mrpi.box_sets(A, lo, hi, 1e-6)
        f1, f2 = (store.file(sets.template_key(*b.template[0])) for b in plain)
        b1, b2 = f1.read_bytes(), f2.read_bytes()
        f1.write_bytes(b2)
        f2.write_bytes(b1)
        sets.box_sum_template.cache_clear()
        for A, ref in zip((A3, A2), plain):
            got = box_mrpi.box_sets(A, lo, hi, 1e-6)
            np.testing.assert_array_equal(got.volume, ref.volume)
            for a, b in zip(got.offsets, ref.offsets):
                np.testing.assert_array_equal(a, b)
    finally:
        sets.keep_templates_in(None)
        sets.box_sum_template.cache_clear()


def _foreign_files(tmp_path) -> dict:
    """name → writer of a damaged or foreign file under a key's name."""
    def npy(f):
        with open(f, "wb") as fh:
            np.save(fh, np.ones(3))

    def compressed_damaged(f):
        np.savez_compressed(f, N=np.arange(2000.0), _digest=np.zeros(32, np.uint8))
        b = bytearray(f.read_bytes())
        b[200:300] = bytes(range(100))
        f.write_bytes(bytes(b))

    def truncated(f):
        array_cache.ArrayCache(tmp_path / "src").save(b"k", ARRAYS)
        b = array_cache.ArrayCache(tmp_path / "src").file(b"k").read_bytes()
        f.write_bytes(b[:len(b) // 2])

    def wrong_digest(f):
        np.savez(f, **ARRAYS, _digest=np.zeros(32, np.uint8))

    def pickled(f):
        np.savez(f, N=np.array([{"a": 1}], dtype=object), _digest=np.zeros(32, np.uint8))

    return {"npy": npy, "compressed_damaged": compressed_damaged, "truncated": truncated,
            "garbage": lambda f: f.write_bytes(b"PK\x03\x04" + bytes(500)),
            "empty": lambda f: f.write_bytes(b""), "directory": lambda f: f.mkdir(),
            "wrong_digest": wrong_digest, "pickled": pickled}


@pytest.mark.parametrize("kind", list(_foreign_files(None)))
def test_damaged_or_foreign_files_are_ignored_and_replaced(tmp_path, kind):
    """load gives None (never raises) for a .npy, a damaged compressed member, a truncated
    archive, garbage, an empty file, a directory, a wrong digest, a pickled array; save then
    stores the right arrays (a directory in the way: save gives up, load still None)."""
    store = array_cache.ArrayCache(tmp_path / "c")
    store.path.mkdir()
    _foreign_files(tmp_path)[kind](store.file(b"k"))
    assert store.load(b"k") is None
    store.save(b"k", ARRAYS)
    if kind == "directory":
        assert store.load(b"k") is None and store.file(b"k").is_dir()
    else:
        assert _same(store.load(b"k"), ARRAYS)
    assert not list(store.path.glob("*.tmp"))


def test_prune_skips_what_it_cannot_or_must_not_delete(tmp_path, monkeypatch):
    """prune with a directory named like an entry, a symbolic link to a file outside the
    cache, and a file whose deletion fails (EACCES): no exception, the outside file and the
    directory stay, the deletable files go (budget 0)."""
    store = array_cache.ArrayCache(tmp_path / "c")
    for k in (b"a", b"b", b"c"):
        store.save(k, ARRAYS)
    (store.path / "d.npz").mkdir()
    outside = tmp_path / "outside.npz"
    outside.write_bytes(b"x" * 100)
    (store.path / "link.npz").symlink_to(outside)
    stuck = store.file(b"b")
    unlink = type(stuck).unlink

    def failing(self, missing_ok=False):
        if self == stuck:
            raise PermissionError(errno.EACCES, "read-only", str(self))
        return unlink(self, missing_ok=missing_ok)

    sizes = [store.file(k).stat().st_size for k in (b"a", b"c")]
    monkeypatch.setattr(type(stuck), "unlink", failing)
    assert store.prune(budget=0) == sum(sizes)
    assert outside.read_bytes() == b"x" * 100 and (store.path / "link.npz").is_symlink()
    assert (store.path / "d.npz").is_dir() and stuck.exists()
    assert not store.file(b"a").exists() and not store.file(b"c").exists()


def test_a_link_in_the_cache_is_replaced_not_written_through(tmp_path):
    """A key's name that is a symbolic link to a file outside the cache: load does not take
    the outside file's arrays (another key's, digest mismatch), save replaces the link by a
    regular file and leaves the outside file as it was."""
    src = array_cache.ArrayCache(tmp_path / "elsewhere")
    src.save(b"other", ARRAYS)
    outside = src.file(b"other")
    before = outside.read_bytes()
    store = array_cache.ArrayCache(tmp_path / "c")
    store.path.mkdir()
    store.file(b"k").symlink_to(outside)
    assert store.load(b"k") is None
    store.save(b"k", {"N": np.zeros(2)})
    assert not store.file(b"k").is_symlink() and outside.read_bytes() == before
    assert _same(store.load(b"k"), {"N": np.zeros(2)})


def test_an_unusable_directory_neither_fails_nor_writes(tmp_path, monkeypatch):
    """A file where the directory should be, and a directory where creating a file fails
    (EACCES, as a read-only directory gives a non-root user; root ignores modes, so it is
    simulated): save, load and prune return quietly, nothing is written, the file is kept."""
    blocker = tmp_path / "c"
    blocker.write_bytes(b"not a directory")
    store = array_cache.ArrayCache(blocker)
    store.save(b"k", ARRAYS)
    assert store.load(b"k") is None and store.prune(0) == 0
    assert blocker.read_bytes() == b"not a directory"
    ro = array_cache.ArrayCache(tmp_path / "ro")
    ro.path.mkdir()

    def denied(*a, **k):
        raise PermissionError(errno.EACCES, "read-only directory")

    monkeypatch.setattr(array_cache.tempfile, "mkstemp", denied)
    ro.save(b"k", ARRAYS)
    assert ro.load(b"k") is None and not list(ro.path.iterdir())


def test_a_full_disk_leaves_no_file(tmp_path, monkeypatch):
    """np.savez failing half-way with ENOSPC: save returns quietly, neither the entry nor its
    temporary file remains, and load gives None; with space again the entry is stored."""
    store = array_cache.ArrayCache(tmp_path / "c")
    savez = np.savez

    def full(fh, **arrays):
        fh.write(b"PK\x03\x04partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(array_cache.np, "savez", full)
    store.save(b"k", ARRAYS)
    assert not list(store.path.iterdir()) and store.load(b"k") is None
    monkeypatch.setattr(array_cache.np, "savez", savez)
    store.save(b"k", ARRAYS)
    assert _same(store.load(b"k"), ARRAYS)


def test_threads_saving_one_key_at_once_leave_one_whole_file(tmp_path):
    """Eight threads save one key at the same moment, each its own arrays, while others read
    it: every load is None or one writer's arrays whole, the end state is one writer's arrays,
    no temporary file is left."""
    store = array_cache.ArrayCache(tmp_path / "c")
    versions = [{"N": np.full((64, 3), float(i))} for i in range(8)]
    start, seen = threading.Barrier(12), []

    def write(v):
        start.wait()
        for _ in range(5):
            store.save(b"k", v)

    def read():
        start.wait()
        for _ in range(20):
            seen.append(store.load(b"k"))

    threads = [threading.Thread(target=write, args=(v,)) for v in versions]
    threads += [threading.Thread(target=read) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(s is None or any(_same(s, v) for v in versions) for s in seen)
    assert any(_same(store.load(b"k"), v) for v in versions)
    assert [f.name for f in store.path.iterdir()] == [store.file(b"k").name]


# ---------------------------------------------------------------------------------------------
# 5. outlines of degenerate zonotopes
# ---------------------------------------------------------------------------------------------

DEGENERATE = {
    "zero generator 2-D": (np.zeros(2), [[1.0, 0.0], [0.0, 0.0], [0.0, 0.5]]),
    "collinear 2-D": (np.array([1.0, 2.0]), [[1.0, 1.0], [2.0, 2.0], [-1.0, -1.0]]),
    "no generator 2-D": (np.zeros(2), np.zeros((0, 2))),
    "only zero generators 2-D": (np.zeros(2), np.zeros((2, 2))),
    "zero generator 3-D": (np.zeros(3), [[1.0, 0, 0], [0, 0, 0], [0, 1, 0], [0, 0, 1]]),
    "flat 3-D": (np.zeros(3), [[1.0, 0, 0], [0, 1, 0], [1, 1, 0]]),
    "flat 3-D seen edge-on": (np.zeros(3), [[0, 0, 1.0], [0, 1, 1]]),
    "collinear 3-D": (np.ones(3), [[1.0, 1, 1], [2, 2, 2]]),
    "only zero generators 3-D": (np.zeros(3), np.zeros((2, 3))),
    "no generator 3-D": (np.zeros(3), np.zeros((0, 3))),
}


@pytest.mark.parametrize("name", list(DEGENERATE))
def test_outlines_of_degenerate_zonotopes(name):
    """outline, projected_outline (dims 0, 1) and the 2-D / 3-D figures of degenerate
    zonotopes do not raise; every outline point lies in the set's bounding box
    c ± Σ|g_j| (to 1e-12)."""
    import matplotlib.pyplot as plt
    c, G = DEGENERATE[name]
    G = np.asarray(G, np.float64).reshape(-1, len(c))
    Z = sets.Zonotope(c, G)
    r = np.abs(G).sum(axis=0)
    P = set_figures.outline(Z)
    Q = set_figures.projected_outline(Z, (0, 1))
    assert np.all(np.abs(P - c) <= r + 1e-12) and np.all(np.abs(Q - c[:2]) <= r[:2] + 1e-12)
    samples = np.zeros((4, len(c)))
    try:
        set_figures.plot_set_2d(Z, samples, dims=(0, 1))
        if len(c) == 3:
            set_figures.plot_set_3d(Z, samples)
    finally:
        plt.close("all")
