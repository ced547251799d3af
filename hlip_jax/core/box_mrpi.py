"""The mRPI brackets of e⁺ = A e + w, w ∈ W_r, for many boxes W_r under one closed-loop matrix
A, and the membership of points in them, batched over the boxes.

Row r's box W_r = [lo_r, hi_r] (n ≤ 3 states) is widened to half-widths of at least
``min_halfwidth`` about its centre c_r, as :func:`hlip_jax.core.sets.mrpi` widens it, and its
bracket is that function's (Raković et al. 2005):

    inner F_s = c* + ⊕_{i<s} A^i diag(ρ) B_∞,   outer c* + (F_s − c*) / (1 − α),
    c* = (I − A)⁻¹ c,

with the same truncation order s and α = α(s) (:func:`hlip_jax.core.sets.choose_orders`,
vectorised over the rows: α(s) = max_j (|A^s| ρ)_j / ρ_j, M(s) = max_j Σ_{i<s} (|A^i| ρ)_j) and
the same exact facets: the normals N of the unit generators A^i e_j depend only on A, s and the
generators that count, and the half-widths are linear in ρ, h = H ρ
(:func:`hlip_jax.core.sets.box_sum_template`).  The rows that share a template have their points
tested in one jitted call on JAX's default device (an accelerator when there is one): the gauge

    g(x) = max_f |N_f (x − c*)| / h_f

puts x in F_s when g ≤ 1 + tol and in the outer set when g ≤ (1 + tol) / (1 − α).

:class:`BoxSets` fields, ``name: meaning (shape)``, R rows, n states:

    ok: the row has a bracket (finite box, an order s ≤ s_max found) (R,) bool
    s: terms of the truncated sum (R,) int (0 where not ok)
    alpha: α(s), 0 where the sum is exact (A^s W = {0}) (R,)
    centre: c* [state units] (R, n)
    radius: the widened half-widths ρ [state units] (R, n)
    offsets: h = H ρ, the inner set's facet half-widths, one array per row (F_r,) (None where
      not ok)
    volume: the outer set's volume (R,) (NaN where not ok)
    template: the row's template key (A bytes, n, s, prefix, kept generators), None where not ok
"""

from __future__ import annotations

import concurrent.futures
import functools
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import sets


#: threads that build a batch's facet templates at most
TEMPLATE_THREADS = 8


class BoxSets(NamedTuple):
    """The brackets of R boxes under one A (module doc)."""
    ok: np.ndarray
    s: np.ndarray
    alpha: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    offsets: list
    volume: np.ndarray
    template: list


def widen(lo: np.ndarray, hi: np.ndarray, min_halfwidth: float) -> tuple[np.ndarray, np.ndarray]:
    """(c, ρ) (R, n) of boxes [lo, hi] (R, n) with half-widths raised to ``min_halfwidth``, by
    the float operations of :func:`hlip_jax.core.sets.mrpi` (then ``box_to_zonotope``), so that
    each row's set is that function's bit for bit."""
    mid, r = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), min_halfwidth)
    lo, hi = mid - r, mid + r
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def orders(A: np.ndarray, radius: np.ndarray, eps: float, s_max: int, nil_tol: float):
    """(s, α, exact, sizes) of boxes of half-widths ``radius`` (R, n) > 0 under A (n, n):
    :func:`hlip_jax.core.sets.choose_orders` with the box's α(s) and M(s) (module doc); ``sizes``
    (R, S): term i's max-coordinate size max_j (|A^i| ρ)_j, the input of
    :func:`hlip_jax.core.sets.prefix_terms`.  s = 0 where no order ≤ ``s_max`` meets ε."""
    R, n = radius.shape
    acc, Ai, sizes = np.zeros((R, n)), np.eye(n), []

    def alpha_fn(As):
        return np.max(np.sum(np.abs(As[None] * radius[:, None, :]), axis=-1) / radius, axis=-1)

    def M_fn(s):
        nonlocal acc, Ai
        while len(sizes) < s:
            term = np.sum(np.abs(Ai[None] * radius[:, None, :]), axis=-1)     # (R, n)
            acc = acc + term
            sizes.append(np.max(term, axis=-1))
            Ai = A @ Ai
        return np.max(acc, axis=-1)

    s, a, exact = sets.choose_orders(A, alpha_fn, M_fn, eps, s_max, nil_tol, rows=R)
    M_fn(int(s.max(initial=0)))
    return s, a, exact, np.stack(sizes, axis=1) if sizes else np.zeros((R, 0))


def _generator_norms(A: np.ndarray, radius: np.ndarray, s: int) -> np.ndarray:
    """The norms (R, s·n) of the sums' generators ρ_j A^i e_j, rows in ``truncated_sum``'s
    order, of R boxes of half-widths ``radius`` (R, n) with s terms each: the unit generators
    (A^i e_j)ᵀ scaled by ρ_j, the products ``truncated_sum``'s diag(ρ) (A^i)ᵀ forms (exactly:
    the other terms of its sums are zeros)."""
    n, Ai, U = radius.shape[1], np.eye(radius.shape[1]), []
    for _ in range(s):
        U.append(Ai.T)
        Ai = A @ Ai
    G = np.concatenate(U)[None] * np.tile(radius, (1, s))[:, :, None]
    return np.linalg.norm(G, axis=2)


def _template_keys(A: np.ndarray, radius: np.ndarray, s: int, sizes: np.ndarray) -> list:
    """The template keys (:func:`hlip_jax.core.sets.box_sum_template`'s arguments) of R boxes
    (``radius`` (R, n), term sizes (R, S)) with s terms each."""
    n = radius.shape[1]
    keys = []
    for rho, gn, sz in zip(radius, _generator_norms(A, radius, s), sizes):
        n_prefix = sets.prefix_terms(sz, s) * n if n == 3 else 0
        keep, keep0 = sets.split_norms(gn, n_prefix)
        keys.append((A.tobytes(), n, s, n_prefix, keep.tobytes(), keep0.tobytes()))
    return keys


def templates(keys) -> dict:
    """{key: :func:`hlip_jax.core.sets.box_sum_template` (*key)} for a set of template keys,
    built in up to :data:`TEMPLATE_THREADS` threads (numpy's large array operations, most of a
    template's cost, release the interpreter lock; a 1024-scenario chunk has a few dozen)."""
    keys = list(keys)
    threads = min(TEMPLATE_THREADS, os.cpu_count() or 1, len(keys))
    if threads <= 1:
        return {k: sets.box_sum_template(*k) for k in keys}
    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        return dict(zip(keys, pool.map(lambda k: sets.box_sum_template(*k), keys)))


def box_sets(A_cl, lo, hi, min_halfwidth: float, eps: float = 1e-5, s_max: int = 500,
             nil_tol: float = 1e-10) -> BoxSets:
    """The brackets of the boxes [lo_r, hi_r] (R, n) under the Schur-stable ``A_cl`` (n, n)
    (module doc; the arguments are :func:`hlip_jax.core.sets.mrpi`'s)."""
    A = sets.as_float64(A_cl)
    lo, hi = np.atleast_2d(sets.as_float64(lo)), np.atleast_2d(sets.as_float64(hi))
    R, n = lo.shape
    c, rho = widen(lo, hi, min_halfwidth)
    ok = np.all(np.isfinite(c) & np.isfinite(rho) & (rho > 0), axis=1)
    s, alpha, exact = np.zeros(R, np.int64), np.zeros(R), np.zeros(R, bool)
    sizes = np.zeros((R, 0))
    if ok.any():
        s[ok], alpha[ok], exact[ok], sizes_ok = orders(A, rho[ok], eps, s_max, nil_tol)
        sizes = np.zeros((R, sizes_ok.shape[1]))
        sizes[ok] = sizes_ok
    ok &= s > 0
    centre = np.full((R, n), np.nan)
    offsets, template, volume = [None] * R, [None] * R, np.full(R, np.nan)
    for order in np.unique(s[ok]):
        rows = np.flatnonzero(ok & (s == order))
        for r, key in zip(rows, _template_keys(A, rho[rows], int(order), sizes[rows])):
            template[r] = key
    built = templates({template[r] for r in np.flatnonzero(ok)})
    for r in np.flatnonzero(ok):
        centre[r] = np.linalg.solve(np.eye(n) - A, c[r])
        _, H, _, T = built[template[r]]
        offsets[r] = H @ rho[r]
        rr = functools.reduce(np.multiply.outer, [rho[r]] * n)
        k = 1.0 if exact[r] else 1.0 / (1.0 - alpha[r])
        volume[r] = np.float64(2.0 ** n * np.sum(T * rr)) * k ** n
    return BoxSets(ok, s, alpha, centre, rho, offsets, volume, template)


def compute_tolerance(tol: float) -> float:
    """``tol`` raised to 50 machine epsilons of the dtype the kernels compute in (float32 unless
    JAX's x64 mode is on): a point on a set's boundary by construction must count as inside
    whatever precision decides it."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64)
    return max(float(tol), 50.0 * float(np.finfo(dtype).eps))


#: (rows × points × facets) entries per block of :func:`_gauges` (a block is one row's facets
#: where those alone are more)
GAUGE_BLOCK = 1 << 22
#: rows per call of :func:`gauges` at most (bounds the host's padded (rows × facets) offsets:
#: 512 × 32,768 float64 = 128 MiB), so a chunk of thousands of scenarios costs several calls
ROWS_PER_CALL = 512


@functools.partial(jax.jit, static_argnames=("rows", "points"))
def _gauges(N, h, y, rows: int, points: int):
    """g (R, K) = max_f |N_f y_rk| / h_rf for facets N (F, n), half-widths h (R, F) and
    points y = x − c* (R, K, n) relative to their row's centre; ``rows`` rows and ``points``
    points at a time (a block of rows × points × F entries).

    y is formed by the caller in float64: in float32 (x − c*) keeps only ~eps₃₂ |c*| of the
    difference, which for a set of half-width h ≪ |c*| is an error of eps₃₂ |c*| / h in g
    (a 1 mm box 1 m off the origin: 6e-5, ten times the tolerance)."""
    R, K, n = y.shape

    def block(args):
        hb, yb = args                                    # (r, F), (K / points, r, points, n)
        Ns = N[None] / jnp.maximum(hb, jnp.finfo(hb.dtype).tiny)[..., None]    # (r, F, n)
        part = lambda yc: jnp.max(jnp.abs(jnp.einsum("rkn,rfn->rkf", yc, Ns)), axis=-1)
        return jax.lax.map(part, yb)                     # (K / points, r, points)

    yb = y.reshape(R // rows, rows, K // points, points, n).transpose(0, 2, 1, 3, 4)
    g = jax.lax.map(block, (h.reshape((R // rows, rows) + h.shape[1:]), yb))
    return g.transpose(0, 2, 1, 3).reshape(R, K)


def _power_of_two(k: int) -> int:
    """The largest power of two ≤ max(k, 1)."""
    return 1 << (int(max(k, 1)).bit_length() - 1)


def gauges(bs: BoxSets, rows: np.ndarray, points: list) -> list:
    """The gauge of each of ``points[i]`` (k_i, n) in the inner set of row ``rows[i]`` (all
    rows ok and of one template), in one jitted call: a list of (k_i,) arrays.  A point with a
    NaN or infinite coordinate, or one whose gauge is not finite in the kernel's precision,
    gets g = ∞ (outside every set, as ``sets.gauge(...) <= 1`` decides it): XLA's fused
    maximum over the facets can drop NaN products (a NaN point came out as g = −∞, inside)."""
    N = sets.box_sum_template(*bs.template[rows[0]])[0]
    F, n = N.shape
    Fb, Kb = sets.bucket(F), sets.bucket(max(1, max(len(p) for p in points)))
    Rb = sets.bucket(len(rows))
    # rows and points per block, powers of two (dividing Rb and Kb): blk·pts·Fb ≤ GAUGE_BLOCK,
    # or pts·Fb ≤ GAUGE_BLOCK with blk = 1 where one row's points exceed it, or Fb alone
    blk = _power_of_two(min(Rb, GAUGE_BLOCK // (Kb * Fb)))
    pts = _power_of_two(min(Kb, GAUGE_BLOCK // (blk * Fb)))
    y, h, Np = np.zeros((Rb, Kb, n)), np.ones((Rb, Fb)), np.zeros((Fb, n))
    for i, (r, p) in enumerate(zip(rows, points)):      # padding: inert facets, zero points
        y[i, :len(p)], h[i, :F] = sets.as_float64(p) - bs.centre[r], bs.offsets[r]
    Np[:F] = N
    finite = np.isfinite(y).all(axis=-1)
    g = np.asarray(_gauges(Np, h, np.where(finite[..., None], y, 0.0), rows=blk, points=pts),
                   np.float64)
    g = np.where(finite & np.isfinite(g), g, np.inf)
    return [g[i, :len(p)] for i, p in enumerate(points)]


class Covered(NamedTuple):
    """Per row: the fraction of its points in the inner and in the outer set, and their count
    (NaN fractions for a row without points or without a bracket)."""
    inner: np.ndarray
    outer: np.ndarray
    n: np.ndarray


def coverage(bs: BoxSets, points: list, tol: float = 1e-9) -> Covered:
    """:class:`Covered` of ``points[r]`` (k_r, n) in row r's bracket, every template's rows in
    one call (:func:`gauges`) of at most :data:`ROWS_PER_CALL` rows; ``tol`` relative, floored
    by :func:`compute_tolerance`."""
    R = len(points)
    tol = compute_tolerance(tol)
    inner, outer = np.full(R, np.nan), np.full(R, np.nan)
    count = np.array([len(p) for p in points], np.int64)
    groups: dict = {}
    for r in np.flatnonzero(bs.ok & (count > 0)):
        groups.setdefault(bs.template[r], []).append(r)
    parts = [rows[i:i + ROWS_PER_CALL] for rows in groups.values()
             for i in range(0, len(rows), ROWS_PER_CALL)]
    for rows in parts:
        for r, g in zip(rows, gauges(bs, np.asarray(rows), [points[r] for r in rows])):
            k = 1.0 if bs.alpha[r] == 0 else 1.0 / (1.0 - bs.alpha[r])
            inner[r] = np.mean(g <= 1.0 + tol)
            outer[r] = np.mean(g <= (1.0 + tol) * k)
    return Covered(inner, outer, count)
