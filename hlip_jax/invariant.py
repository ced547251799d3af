"""Disturbance sets W and error-invariant sets E of the step-to-step (S2S) error dynamics.

With the stepping law ``u = u_HLIP + K (x_robot − x_HLIP)`` the S2S error e = x_robot − x_HLIP
obeys (per plane, sagittal and lateral)

    e⁺ = A_cl e + w,   A_cl = A + B K,   w ∈ W,

where ``w_k = x_{k+1} − A x_k − B u_k`` is measured from the robot's own pre-impact states and
executed step sizes.  A robot whose feet do not land exactly where the law asks adds the
foot-placement error δu_k = u_k − (u_HLIP,k + K e_k) (:func:`placement_errors`):

    e⁺ = A_cl e + w + B δu,

so the disturbance the error dynamics actually see is d = w + B δu = e⁺ − A_cl e;
:func:`analyse` bounds d when it is given the H-LIP steps (on a plant that places its feet
exactly, d = w).  The smallest set that every error trajectory started at 0 stays in is the
minimal robust positively invariant (mRPI) set

    F_∞ = ⊕_{i≥0} A_cl^i W.

Following Raković, Kerrigan, Kouramas & Mayne, "Invariant approximations of the minimal robust
positively invariant set", IEEE TAC 2005, with W containing the origin in its interior and

    α(s) = max_i h_W(A_cl^sᵀ f_i) / g_i          (W = {w : f_iᵀ w ≤ g_i}),
    F_s  = ⊕_{i<s} A_cl^i W,

F_s ⊆ F_∞ ⊆ F_s / (1 − α(s)), and the outer set is itself RPI.  s is the smallest integer with
α(s) < 1 and α/(1 − α) · max_j h_{F_s}(±e_j) ≤ ε, so the outer set lies within ε (in every
coordinate direction, state units [m] or [m/s]) of F_∞.  A W that is not centred at the origin,
W = c + W₀, is handled by the shift F_∞(W) = (I − A_cl)⁻¹ c + F_∞(W₀).

Set types (all NamedTuples, hence pytrees; ``support`` and ``contains`` are jitted and vectorised):

* :class:`Box` — axis box [lo, hi].
* :class:`Zonotope` — c + G ᵀβ, β ∈ [−1, 1]^m; exact H-representation (2-D: normals ⊥ each
  generator; 3-D: cross products of generator pairs).  Box W gives zonotope F_s.
* :class:`Hull` — convex hull of points (V- and H-representation, facets from scipy's Qhull).
* :class:`TemplatePolytope` — {x : D x ≤ b} for a fixed direction set D; used as an **outer
  approximation** of F_s/(1−α) when W is a general hull.
* :class:`MRPI` — the bracket (inner F_s, outer F_s/(1−α)) with s, α, ε; its ``support``,
  ``contains`` and ``volume`` are those of the outer set.

Construction (the s/α choice, facet enumeration) runs eagerly in float64 numpy on concrete
values; the per-point functions run in JAX.
"""

from __future__ import annotations

import itertools
from functools import partial
from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax import steplog

# ---------------------------------------------------------------------------------------------
# set types
# ---------------------------------------------------------------------------------------------

_CHUNK = 65536  # points per block in membership tests (bounds the (points × facets) temporary)


def _f64(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


class Box(NamedTuple):
    """Axis-aligned box {x : lo ≤ x ≤ hi}; ``lo``, ``hi`` shape (n,) in state units."""
    lo: Any
    hi: Any

    @property
    def dim(self) -> int:
        return int(np.shape(self.lo)[-1])

    def support(self, directions):
        """h(d) = max_{x∈Box} dᵀx = dᵀc + |d|ᵀr (c centre, r half-widths); d shape (..., n)."""
        return _box_support(_as_jnp(self), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        """Bool per point (shape (...,) for points (..., n)); ``tol`` relative to the widths."""
        return _box_contains(_as_jnp(self), jnp.asarray(points), tol)

    def volume(self):
        """Π (hi − lo)."""
        return jnp.prod(jnp.asarray(self.hi) - jnp.asarray(self.lo))


class Zonotope(NamedTuple):
    """Zonotope {c + Σ_k β_k g_k : |β_k| ≤ 1}; ``center`` (n,), ``generators`` (m, n).

    A zonotope is centrally symmetric, so its exact H-representation is stored once per ±
    facet pair: ``normals`` (F, n, unit rows) and ``offsets`` (F,) = Σ_k |normals g_k| give
    {x : |normals (x − c)| ≤ offsets}.  Build it with :func:`zonotope` (or
    :func:`zonotope_hrep`).

    ``prefix_offsets`` (F₀,), optional: the first F₀ normals are the complete facet set of the
    sub-zonotope Z₀ of the leading generators (for F_s: the first terms A^i W, which carry most
    of the size), with Z₀'s half-widths.  Membership of many points then runs in two exact
    passes: F₀ facets decide most points (outside Z if a facet of Z is violated, inside if in
    Z₀ ⊆ Z); only the band Z ∖ Z₀ gets the full facet test.
    """
    center: Any
    generators: Any
    normals: Any = None
    offsets: Any = None
    prefix_offsets: Any = None

    @property
    def dim(self) -> int:
        return int(np.shape(self.center)[-1])

    def support(self, directions):
        """h(d) = dᵀc + Σ_k |g_kᵀ d|."""
        return _zono_support(_as_jnp(self), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        """Bool per point through the exact facets; ``tol`` relative to the set's size."""
        z = _as_jnp(self if self.normals is not None else zonotope_hrep(self))
        x = jnp.asarray(points)
        if (z.prefix_offsets is not None and not isinstance(x, jax.core.Tracer)
                and not isinstance(z.normals, jax.core.Tracer) and x.size >= 8192 * x.shape[-1]):
            return _zono_contains_two_pass(z, x, tol)
        N, h = _pad_facets(z.normals, z.offsets, 1.0)
        zp = z._replace(normals=N, offsets=h, prefix_offsets=None)
        return _padded_call(lambda p: _zono_contains(zp, p, tol), x)

    def volume(self):
        """2ⁿ Σ_{|S|=n} |det G_S| over all n-subsets S of the generators (exact)."""
        return _zono_volume(self)


class Hull(NamedTuple):
    """Convex hull of ``vertices`` (k, n).  ``Hull(points)`` accepts any point cloud; the
    H-representation (``normals`` (F, n) unit rows, ``offsets`` (F,)) is filled by
    :meth:`canonical` (scipy Qhull, eager) and used by ``contains``."""
    vertices: Any
    normals: Any = None
    offsets: Any = None

    @property
    def dim(self) -> int:
        return int(np.shape(self.vertices)[-1])

    def canonical(self) -> "Hull":
        """Hull with only its extreme points as vertices and its facets filled in."""
        if self.normals is not None:
            return self
        return _hull_from_points(_f64(self.vertices))

    def support(self, directions):
        """h(d) = max_k v_kᵀ d."""
        return _hull_support(jnp.asarray(self.vertices), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        h = self.canonical()
        c = jnp.mean(jnp.asarray(h.vertices), axis=0)
        N, b = _pad_facets(jnp.asarray(h.normals), jnp.asarray(h.offsets), 0.0)
        return _padded_call(lambda x: _hpoly_contains(N, b, c, x, tol), jnp.asarray(points))

    def volume(self):
        """Lebesgue measure (scipy Qhull, eager; length in 1-D)."""
        return _points_volume(_f64(self.vertices))


class TemplatePolytope(NamedTuple):
    """{x : D x ≤ b} for a fixed template direction set D (``normals`` (F, n), unit rows).

    Produced by :func:`mrpi` for a general (hull) W as an OUTER approximation of
    F_s/(1−α): b = h_{F_s}(D)/(1−α) is exact in the template directions only.  ``vertices``
    (computed eagerly by halfspace intersection) give the support in other directions.
    """
    normals: Any
    offsets: Any
    vertices: Any
    center: Any

    is_outer_approximation = True

    @property
    def dim(self) -> int:
        return int(np.shape(self.normals)[-1])

    def support(self, directions):
        return _hull_support(jnp.asarray(self.vertices), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        N, b = _pad_facets(jnp.asarray(self.normals), jnp.asarray(self.offsets), 0.0)
        c = jnp.asarray(self.center)
        return _padded_call(lambda x: _hpoly_contains(N, b, c, x, tol), jnp.asarray(points))

    def volume(self):
        return _points_volume(_f64(self.vertices))


class MRPI(NamedTuple):
    """Bracket of the mRPI set F_∞ of e⁺ = A_cl e + w:  inner ⊆ F_∞ ⊆ outer.

    inner: c* + F_s(W₀) (exact Minkowski sum; Zonotope for box W, Hull for hull W).
    outer: c* + F_s(W₀)/(1−α) (Zonotope, RPI) or its TemplatePolytope outer approximation.
    s: number of terms; alpha: α(s) (0 for nilpotent A_cl: then inner = outer = F_∞);
    eps: the tolerance ε used; exact: True when α = 0 (finite sum, no approximation).
    ``support``, ``contains`` and ``volume`` act on ``outer``.
    """
    inner: Any
    outer: Any
    s: int
    alpha: float
    eps: float
    exact: bool

    @property
    def dim(self) -> int:
        return self.outer.dim

    def support(self, directions):
        return self.outer.support(directions)

    def contains(self, points, tol: float = 1e-9):
        return self.outer.contains(points, tol)

    def volume(self):
        return self.outer.volume()


def _as_jnp(t):
    return jax.tree_util.tree_map(jnp.asarray, t)


def _bucket(k: int) -> int:
    """Next power of two ≥ max(k, 16): padded sizes so that sets and sample batches of
    similar size share one compiled kernel."""
    return 1 << max(4, int(k - 1).bit_length())


def _pad_facets(N, b, fill):
    """Pad facet rows to a bucket size with inert rows (0ᵀx ≤ fill, fill ≥ 0)."""
    F = N.shape[0]
    pad = _bucket(F) - F
    if pad == 0:
        return N, b
    return (jnp.concatenate([N, jnp.zeros((pad, N.shape[1]), N.dtype)]),
            jnp.concatenate([b, jnp.full((pad,), fill, b.dtype)]))


def _padded_call(fn, x):
    """fn on points padded (flattened) to a bucket size; result reshaped to x.shape[:-1]."""
    batch = x.shape[:-1]
    flat = x.reshape(-1, x.shape[-1])
    k = flat.shape[0]
    if k == 0:
        return jnp.zeros(batch, bool)
    out = fn(jnp.pad(flat, ((0, _bucket(k) - k), (0, 0))))
    return out[:k].reshape(batch)


# ---------------------------------------------------------------------------------------------
# jitted per-point kernels
# ---------------------------------------------------------------------------------------------

@jax.jit
def _box_support(b: Box, d):
    c = 0.5 * (b.lo + b.hi)
    r = 0.5 * (b.hi - b.lo)
    return d @ c + jnp.abs(d) @ r


@jax.jit
def _box_contains(b: Box, x, tol):
    slack = tol * jnp.maximum(jnp.max(b.hi - b.lo), jnp.finfo(x.dtype).tiny)
    return jnp.all((x >= b.lo - slack) & (x <= b.hi + slack), axis=-1)


@jax.jit
def _zono_support(z: Zonotope, d):
    return d @ z.center + jnp.sum(jnp.abs(d @ z.generators.T), axis=-1)


@jax.jit
def _hull_support(v, d):
    return jnp.max(d @ v.T, axis=-1)


@partial(jax.jit, static_argnames=("chunk",))
def _hpoly_contains(normals, offsets, center, x, tol, chunk: int = _CHUNK):
    """all(N x ≤ b + tol·size) per point, size = max_f (b_f − N_f c) (set's radius).

    Points are processed in blocks of ``chunk`` so the (points × facets) temporary stays small.
    """
    size = jnp.maximum(jnp.max(offsets - normals @ center), jnp.finfo(normals.dtype).tiny)
    slack = tol * size
    return _blocked(lambda blk: jnp.max(blk @ normals.T - offsets, axis=-1) <= slack,
                    x, chunk, normals.shape[0])


@partial(jax.jit, static_argnames=("chunk",))
def _zono_contains(z: Zonotope, x, tol, chunk: int = _CHUNK):
    """max_f |N_f (x − c)| / h_f ≤ 1 + tol per point (symmetric facet pairs tested at once)."""
    Ns = z.normals / jnp.maximum(z.offsets, jnp.finfo(z.normals.dtype).tiny)[:, None]
    return _blocked(lambda blk: jnp.max(jnp.abs((blk - z.center) @ Ns.T), axis=-1) <= 1.0 + tol,
                    x, chunk, Ns.shape[0])


@partial(jax.jit, static_argnames=("chunk",))
def _zono_prefilter(center, N0, h_full0, h0, x, tol, chunk: int = _CHUNK):
    """0: outside (a facet of Z violated), 1: inside Z₀ ⊆ Z, 2: undecided."""
    Nf = N0 / h_full0[:, None]
    Nb = N0 / h0[:, None]

    def one(blk):
        y = blk - center
        out = jnp.max(jnp.abs(y @ Nf.T), axis=-1) > 1.0 + tol
        inn = jnp.max(jnp.abs(y @ Nb.T), axis=-1) <= 1.0
        return jnp.where(out, 0, jnp.where(inn, 1, 2)).astype(jnp.int8)

    return _blocked(one, x, chunk, N0.shape[0])


def _zono_contains_two_pass(z: Zonotope, x, tol):
    """Exact membership via the prefix facets first, the full facet set on the rest (eager)."""
    F0 = z.prefix_offsets.shape[0]
    tiny = jnp.finfo(z.normals.dtype).tiny
    h0 = jnp.maximum(z.prefix_offsets, tiny)
    N0 = z.normals[:F0]
    N0p, h0p = _pad_facets(N0, h0, 1.0)
    _, hf0p = _pad_facets(N0, jnp.maximum(z.offsets[:F0], tiny), 1.0)
    state = _padded_int(lambda p: _zono_prefilter(z.center, N0p, hf0p, h0p, p, tol), x)
    flat = np.asarray(x).reshape(-1, x.shape[-1])
    inside = state.reshape(-1) == 1
    und = np.nonzero(state.reshape(-1) == 2)[0]
    if und.size:
        N, h = _pad_facets(z.normals, z.offsets, 1.0)
        zp = z._replace(normals=N, offsets=h, prefix_offsets=None)
        inside[und] = np.asarray(_padded_call(lambda p: _zono_contains(zp, p, tol),
                                              jnp.asarray(flat[und])))
    return jnp.asarray(inside.reshape(x.shape[:-1]))


def _padded_int(fn, x):
    flat = x.reshape(-1, x.shape[-1])
    k = flat.shape[0]
    return np.asarray(fn(jnp.pad(flat, ((0, _bucket(k) - k), (0, 0)))))[:k].reshape(x.shape[:-1])


def _blocked(fn, x, chunk, n_facets):
    """Apply ``fn`` (points (P, n) → (P,)) over the points in blocks, keeping the (points ×
    facets) temporary near 2²² entries."""
    n = x.shape[-1]
    batch = x.shape[:-1]
    flat = x.reshape(-1, n)
    npts = flat.shape[0]
    chunk = int(max(256, min(chunk, (1 << 22) // max(n_facets, 1))))
    if npts <= chunk:
        return fn(flat).reshape(batch)
    nblk = -(-npts // chunk)
    pad = nblk * chunk - npts
    blocks = jnp.pad(flat, ((0, pad), (0, 0))).reshape(nblk, chunk, n)
    return jax.lax.map(fn, blocks).reshape(-1)[:npts].reshape(batch)


def _zono_volume(z: Zonotope):
    """2ⁿ Σ_{i<j<…} |det[g_i, g_j, …]| without listing the subsets: n = 1 is Σ|g|; n = 2 sums
    |g_i × g_j| over i < j; n = 3 sums |(g_i × g_j) · g_k| over i < j < k row by row (O(m³)
    flops but O(m²) memory: 480 generators take ~0.2 s).  Larger n: the subset list.  Eager
    (float64 numpy), like every caller."""
    G = _f64(z.generators)
    m, n = G.shape
    if m < n:
        return np.float64(0.0)
    if n == 1:
        total = np.abs(G[:, 0]).sum()
    elif n == 2:
        D = np.abs(np.outer(G[:, 0], G[:, 1]) - np.outer(G[:, 1], G[:, 0]))
        total = np.triu(D, 1).sum()
    elif n == 3:
        total = 0.0
        for i in range(m - 2):
            C = np.cross(G[i], G[i + 1:])                      # (m−i−1, 3): g_i × g_j, j > i
            D = np.abs(C @ G[i + 1:].T)                         # |(g_i × g_j) · g_k|
            total += np.triu(D, 1).sum()                        # k > j
    else:
        idx = np.array(list(itertools.combinations(range(m), n)), dtype=np.int32)
        total = np.abs(np.linalg.det(G[idx])).sum()
    return np.float64((2.0 ** n) * total)


# ---------------------------------------------------------------------------------------------
# H-representations (eager, float64)
# ---------------------------------------------------------------------------------------------

def _null_basis(G: np.ndarray, n: int, rtol: float = 1e-10) -> np.ndarray:
    """Orthonormal basis (rows) of the complement of span(G rows)."""
    if G.shape[0] == 0:
        return np.eye(n)
    _, sv, vt = np.linalg.svd(G, full_matrices=G.shape[0] < n)  # vt: (n, n) either way
    rank = int(np.sum(sv > rtol * max(sv.max(), 1e-300)))
    return vt[rank:]


def _unique_directions(N: np.ndarray, decimals: int = 10) -> np.ndarray:
    """Unit rows of N with duplicates (up to sign) removed; zero rows dropped."""
    norm = np.linalg.norm(N, axis=1)
    keep = norm > 0
    N = N[keep] / norm[keep, None]
    if N.shape[0] == 0:
        return N
    # sign canonicalisation: first component with |.| > 1e-9 positive
    first = np.argmax(np.abs(N) > 1e-9, axis=1)
    sgn = np.sign(N[np.arange(len(N)), first])
    N = N * sgn[:, None]
    key = np.ascontiguousarray(np.round(N, decimals) + 0.0)  # + 0.0 folds −0 into 0
    key = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, idx = np.unique(key, return_index=True)
    return N[np.sort(idx)]


def zonotope_normals(generators, parallel_rtol: float = 1e-12) -> np.ndarray:
    """Facet normal candidates (unit rows, each direction once; use ± both) of a zonotope.

    1-D: {1}.  2-D: the perpendicular of every generator.  3-D: g_i × g_j for every
    non-parallel pair (|g_i × g_j| > parallel_rtol |g_i||g_j|).  Degenerate (rank-deficient)
    generator sets are completed by an orthonormal basis of the missing directions, treated as
    extra generators for normal finding only, so flat sets get both their in-plane facets and
    the pair of bounding planes.
    """
    G = _f64(generators)
    n = G.shape[1]
    gn = np.linalg.norm(G, axis=1)
    if G.shape[0]:
        G = G[gn > 1e-14 * gn.max()] if gn.max() > 0 else G[:0]
    cand = np.concatenate([G, _null_basis(G, n)], axis=0)
    if n == 1:
        return np.ones((1, 1))
    if n == 2:
        return _unique_directions(np.stack([-cand[:, 1], cand[:, 0]], axis=1))
    if n == 3:
        i, j = np.triu_indices(len(cand), k=1)
        cr = np.cross(cand[i], cand[j])
        ni = np.linalg.norm(cand[i], axis=1) * np.linalg.norm(cand[j], axis=1)
        ok = np.linalg.norm(cr, axis=1) > parallel_rtol * ni
        return _unique_directions(cr[ok])
    raise ValueError(f"zonotope H-representation: dimension n={n} not supported (allowed 1..3)")


def zonotope_hrep(z: Zonotope, n_prefix: int = 0) -> Zonotope:
    """The zonotope with its exact H-representation filled in: one normal N_f per ± facet
    pair, half-width h_f = Σ_k |N_f g_k| (support of the centred set).

    n_prefix > 0: put the complete facet set of the sub-zonotope of the first ``n_prefix``
    generators first and record its half-widths in ``prefix_offsets`` (two-pass membership).
    Extra normals never change the set: every row is a supporting halfspace of Z.
    """
    c = _f64(z.center)
    G = _f64(z.generators).reshape(-1, c.shape[0])
    N = zonotope_normals(G)
    h0 = None
    if 0 < n_prefix < G.shape[0]:
        N0 = zonotope_normals(G[:n_prefix])
        N = _unique_directions(np.concatenate([N0, N]))  # keeps N0 first, in order
    P = np.abs(_small_matmul_t(N, G))  # |N_f · g_k|, (F, m)
    h = P.sum(axis=1)
    if 0 < n_prefix < G.shape[0]:
        h0 = jnp.asarray(P[:len(N0), :n_prefix].sum(axis=1))
    return Zonotope(jnp.asarray(c), jnp.asarray(G), jnp.asarray(N), jnp.asarray(h), h0)


def _small_matmul_t(N: np.ndarray, G: np.ndarray) -> np.ndarray:
    """N Gᵀ for a tiny inner dimension (n ≤ 3) as broadcast products: no BLAS threads, which
    on a busy machine cost more than the arithmetic."""
    out = N[:, 0:1] * G[:, 0]
    for j in range(1, N.shape[1]):
        out += N[:, j:j + 1] * G[:, j]
    return out


def zonotope_halfspaces(z: Zonotope):
    """Full H-representation (N (2F, n), b (2F,)) with {x : N x ≤ b} (both signs)."""
    z = z if z.normals is not None else zonotope_hrep(z)
    N, h, c = _f64(z.normals), _f64(z.offsets), _f64(z.center)
    N2 = np.concatenate([N, -N])
    return N2, N2 @ c + np.concatenate([h, h])


def zonotope(center, generators, n_prefix: int = 0) -> Zonotope:
    """Zonotope c + Gᵀβ, |β| ≤ 1, with facets; center (n,), generators (m, n);
    ``n_prefix``: see :func:`zonotope_hrep`."""
    c = _f64(center)
    if c.ndim != 1 or not 1 <= c.shape[0] <= 3:
        raise ValueError(f"zonotope center: shape (n,) with n in 1..3 expected, got {c.shape}")
    G = _f64(generators).reshape(-1, c.shape[0])
    return zonotope_hrep(Zonotope(c, G), n_prefix)


def box_to_zonotope(b: Box) -> Zonotope:
    lo, hi = _f64(b.lo), _f64(b.hi)
    return zonotope(0.5 * (lo + hi), np.diag(0.5 * (hi - lo)))


def _hull_from_points(P: np.ndarray) -> Hull:
    from scipy.spatial import ConvexHull, QhullError

    if P.ndim != 2 or P.shape[0] == 0:
        raise ValueError(f"Hull points: shape (k, n) with k ≥ 1 expected, got {P.shape}")
    n = P.shape[1]
    if n == 1:
        lo, hi = P.min(), P.max()
        return Hull(jnp.asarray(np.array([[lo], [hi]])), jnp.asarray(np.array([[1.0], [-1.0]])),
                    jnp.asarray(np.array([hi, -lo])))
    try:
        h = ConvexHull(P)
    except QhullError as exc:
        raise ValueError(
            f"Hull points: the {P.shape[0]} points in {n}-D do not span a full-dimensional "
            "convex hull (flat or too few); use a Box W instead") from exc
    V = P[h.vertices]
    eq = h.equations  # a x + d ≤ 0 inside, |a| = 1
    N, b = eq[:, :-1], -eq[:, -1]
    key = np.round(np.concatenate([N, b[:, None]], axis=1), 10)
    _, idx = np.unique(key, axis=0, return_index=True)
    idx = np.sort(idx)
    return Hull(jnp.asarray(V), jnp.asarray(N[idx]), jnp.asarray(b[idx]))


def _points_volume(P: np.ndarray) -> float:
    from scipy.spatial import ConvexHull, QhullError

    if P.shape[1] == 1:
        return float(P.max() - P.min())
    try:
        return float(ConvexHull(P).volume)
    except QhullError:
        return 0.0


def _hpoly_vertices(N: np.ndarray, b: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """Vertices of {x : N x ≤ b} (bounded, ``interior`` strictly inside)."""
    if N.shape[1] == 1:
        up = b[N[:, 0] > 0] / N[N[:, 0] > 0, 0]
        dn = b[N[:, 0] < 0] / N[N[:, 0] < 0, 0]
        return np.array([[dn.max()], [up.min()]])
    from scipy.spatial import HalfspaceIntersection

    hs = HalfspaceIntersection(np.concatenate([N, -b[:, None]], axis=1), interior)
    V = hs.intersections
    return V[np.all(np.isfinite(V), axis=1)]


def vertices(S) -> np.ndarray:
    """Vertices (k, n) of a Box, Zonotope, Hull, TemplatePolytope or MRPI (outer set)."""
    if isinstance(S, MRPI):
        S = S.outer
    if isinstance(S, Box):
        lo, hi = _f64(S.lo), _f64(S.hi)
        return np.array([np.where(m, hi, lo) for m in itertools.product([0, 1], repeat=len(lo))])
    if isinstance(S, Hull):
        return _f64(S.canonical().vertices)
    if isinstance(S, TemplatePolytope):
        return _f64(S.vertices)
    if isinstance(S, Zonotope):
        N, b = zonotope_halfspaces(S)
        return _hpoly_vertices(N, b, _f64(S.center))
    raise TypeError(f"vertices: unsupported set type {type(S).__name__}")


# ---------------------------------------------------------------------------------------------
# mRPI (Raković et al. 2005)
# ---------------------------------------------------------------------------------------------

def default_directions(n: int, count: Optional[int] = None) -> np.ndarray:
    """Template directions: ± axes plus ``count`` near-uniform unit vectors (circle / Fibonacci
    sphere).  Defaults: 64 in 2-D, 256 in 3-D."""
    axes = np.concatenate([np.eye(n), -np.eye(n)])
    if n == 1:
        return axes
    if n == 2:
        k = 64 if count is None else count
        t = 2 * np.pi * (np.arange(k) + 0.5) / k
        D = np.stack([np.cos(t), np.sin(t)], axis=1)
    elif n == 3:
        k = 256 if count is None else count
        i = np.arange(k) + 0.5
        z = 1 - 2 * i / k
        phi = np.pi * (1 + 5 ** 0.5) * i
        rho = np.sqrt(1 - z * z)
        D = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    else:
        raise ValueError(f"default_directions: n={n} not supported (allowed 1..3)")
    return np.concatenate([axes, D])


def _check_acl(A_cl, n: int) -> np.ndarray:
    A = _f64(A_cl)
    if A.ndim == 0 and n == 1:
        A = A.reshape(1, 1)
    if A.shape != (n, n):
        raise ValueError(f"A_cl: shape ({n}, {n}) expected to match W (n={n}), got {A.shape}")
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    if not rho < 1.0:
        raise ValueError(f"A_cl: must be Schur stable (spectral radius < 1), got {rho:.6g}")
    return A


def truncated_sum(A_cl, W, s: int, center=None, n_prefix_terms: int = 0):
    """F_s = ⊕_{i<s} A_cl^i W (exact): a Zonotope for a Box/Zonotope W, a Hull for a Hull W.
    ``center`` (zonotope only) overrides the centre Σ_{i<s} A_cl^i c_W; ``n_prefix_terms``
    > 0 records the facets of F_{n_prefix_terms} for two-pass membership (see Zonotope)."""
    if s < 1:
        raise ValueError(f"s: must be ≥ 1, got {s}")
    if isinstance(W, Box):
        W = box_to_zonotope(W)
    if isinstance(W, Zonotope):
        c, G = _f64(W.center), _f64(W.generators)
        A = _f64(A_cl).reshape(len(c), len(c))
        Ai, cs, gs = np.eye(len(c)), np.zeros_like(c), []
        for _ in range(s):
            cs = cs + Ai @ c
            gs.append(G @ Ai.T)
            Ai = A @ Ai
        return zonotope(cs if center is None else center, np.concatenate(gs),
                        n_prefix=n_prefix_terms * G.shape[0])
    if isinstance(W, Hull):
        V = _f64(W.canonical().vertices)
        A = _f64(A_cl).reshape(V.shape[1], V.shape[1])
        return _hull_from_points(_minkowski_power_sum(A, V, s))
    raise TypeError(f"W: Box, Zonotope or Hull expected, got {type(W).__name__}")


def _minkowski_power_sum(A: np.ndarray, V: np.ndarray, s: int) -> np.ndarray:
    """Extreme points of ⊕_{i<s} A^i conv(V), pruned by a convex hull after every addition."""
    from scipy.spatial import ConvexHull

    acc = V.copy()
    Ai = np.eye(A.shape[0])
    for _ in range(1, s):
        Ai = A @ Ai
        P = (acc[:, None, :] + (V @ Ai.T)[None, :, :]).reshape(-1, V.shape[1])
        if V.shape[1] == 1:
            acc = np.array([[P.min()], [P.max()]])
        else:
            acc = P[ConvexHull(P).vertices]
    return acc


def mrpi(A_cl, W, eps: float = 1e-5, s_max: int = 500, directions=None,
         nilpotent_tol: float = 1e-10, min_halfwidth=None) -> MRPI:
    """Minimal robust positively invariant set of e⁺ = A_cl e + w, w ∈ W (Raković et al. 2005).

    Args:
      A_cl: closed-loop matrix (n, n), Schur stable (n = 1..3).
      W: :class:`Box` (or :class:`Zonotope`) → exact zonotope bracket;
         :class:`Hull` → inner exact Hull F_s, outer :class:`TemplatePolytope` (outer approx.).
      eps: ε [state units]: stop at the first s with α(s) < 1 and
        α/(1−α) · max_j h_{F_s}(±e_j) ≤ ε.
      s_max: give up (ValueError) beyond this many terms.
      directions: template directions (F, n) for a Hull W; default :func:`default_directions`.
      nilpotent_tol: α(s) ≤ this is taken as A_cl^s W = {0} (finite, exact sum, α = 0).
      min_halfwidth: Box W only; scalar or (n,) [state units]: half-widths below it are
        widened to it (about the box centre).  The procedure needs W₀ with an interior, so a
        box that is flat in some axis (e.g. a state that the disturbance never reaches) is
        rejected unless this is given; the result then over-approximates by that margin.

    W off the origin is shifted: W = c + W₀, E = (I − A_cl)⁻¹ c + E(W₀); c is the box centre
    (or the vertex mean of a hull), so W₀ has the origin in its interior (required).

    Cost: a box W takes ~1 ms for a deadbeat A_cl and a few ms for tens of terms (3-D facet
    pairs grow as (3s)²/2).  A hull W builds its inner set F_s by s successive Minkowski sums
    pruned with Qhull: instant in 2-D or for deadbeat gains, seconds in 3-D with tens of terms.
    """
    if not eps > 0:
        raise ValueError(f"eps: must be > 0, got {eps}")
    if isinstance(W, Box):
        lo, hi = _f64(W.lo), _f64(W.hi)
        if lo.ndim != 1 or lo.shape != hi.shape:
            raise ValueError(f"W (Box): lo, hi of equal shape (n,) expected, got {lo.shape}, {hi.shape}")
        if min_halfwidth is not None:
            mh = np.broadcast_to(_f64(min_halfwidth), lo.shape)
            if not np.all(mh >= 0):
                raise ValueError(f"min_halfwidth: must be ≥ 0, got {min_halfwidth}")
            mid, r = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), mh)
            lo, hi = mid - r, mid + r
            W = Box(lo, hi)
        if not np.all(hi > lo):
            raise ValueError("W (Box): hi > lo required in every axis (the origin-centred W₀ needs "
                             f"a non-empty interior), got widths {hi - lo}; pass min_halfwidth to "
                             "widen flat axes")
        W = box_to_zonotope(W)
    if isinstance(W, Zonotope):
        return _mrpi_zonotope(A_cl, W, eps, s_max, nilpotent_tol)
    if isinstance(W, Hull):
        return _mrpi_hull(A_cl, W, eps, s_max, directions, nilpotent_tol)
    raise TypeError(f"W: Box, Zonotope or Hull expected, got {type(W).__name__}")


def _choose_s(A: np.ndarray, alpha_fn, M_fn, eps, s_max, nilpotent_tol):
    """Smallest s with α(s) < 1 and α/(1−α)·M(s) ≤ ε; returns (s, α, exact)."""
    n = A.shape[0]
    As = np.eye(n)
    for s in range(1, s_max + 1):
        As = A @ As  # A^s
        a = alpha_fn(As)
        if a <= nilpotent_tol:
            return s, 0.0, True
        if a < 1.0 and a / (1.0 - a) * M_fn(s) <= eps:
            return s, float(a), False
    raise ValueError(f"mrpi: no s ≤ s_max={s_max} meets eps={eps}; raise s_max or eps")


def _prefix_terms(A: np.ndarray, G: np.ndarray, s: int, tail: float = 0.1) -> int:
    """Number of leading terms A^i W whose sum carries all but ``tail`` of the size of F_s
    (max-coordinate measure); 0 (no two-pass membership) when the sum is short anyway."""
    if s < 6:
        return 0
    sizes, Ai = [], np.eye(A.shape[0])
    for _ in range(s):
        sizes.append(np.max(np.sum(np.abs(G @ Ai.T), axis=0)))
        Ai = A @ Ai
    rest = np.cumsum(sizes[::-1])[::-1] / np.sum(sizes)  # rest[i] = share of terms ≥ i
    s0 = int(np.argmax(rest <= tail))
    return s0 if 0 < s0 <= s // 2 else 0


def _mrpi_zonotope(A_cl, W: Zonotope, eps, s_max, nil_tol) -> MRPI:
    c = _f64(W.center)
    G = _f64(W.generators).reshape(-1, c.shape[0])
    n = c.shape[0]
    A = _check_acl(A_cl, n)
    # facets of W₀ = W − c: f_iᵀ w ≤ g_i, g_i = Σ_k |f_iᵀ g_k| > 0
    Wz = zonotope(np.zeros(n), G)
    F, g = _f64(Wz.normals), _f64(Wz.offsets)
    if not np.all(g > 0):
        raise ValueError("W: must be full-dimensional (origin-centred W₀ needs an interior)")

    def h_W0(D):  # support of W₀ in rows of D
        return np.sum(np.abs(D @ G.T), axis=-1)

    def alpha_fn(As):
        return float(np.max(h_W0(F @ As) / g))

    # M(s) = max_j h_{F_s}(±e_j) = max_j Σ_{i<s} Σ_k |(A^i g_k)_j|  (F_s symmetric)
    state = {"k": 0, "Ai": np.eye(n), "acc": np.zeros(n)}

    def M_fn(s):
        while state["k"] < s:
            state["acc"] += np.sum(np.abs(G @ state["Ai"].T), axis=0)
            state["Ai"] = A @ state["Ai"]
            state["k"] += 1
        return float(np.max(state["acc"]))

    s, a, exact = _choose_s(A, alpha_fn, M_fn, eps, s_max, nil_tol)
    centre = np.linalg.solve(np.eye(n) - A, c)
    inner = truncated_sum(A, Zonotope(centre, G), s, center=centre,
                          n_prefix_terms=_prefix_terms(A, G, s) if n == 3 else 0)
    if exact:
        outer = inner
    else:  # scaling about the centre keeps the facet normals
        k = 1.0 / (1.0 - a)
        scaled = lambda v: None if v is None else jnp.asarray(_f64(v) * k)
        outer = Zonotope(inner.center, scaled(inner.generators), inner.normals,
                         scaled(inner.offsets), scaled(inner.prefix_offsets))
    return MRPI(inner, outer, int(s), float(a), float(eps), bool(exact))


def _mrpi_hull(A_cl, W: Hull, eps, s_max, directions, nil_tol) -> MRPI:
    Wc = W.canonical()
    V = _f64(Wc.vertices)
    n = V.shape[1]
    A = _check_acl(A_cl, n)
    c = V.mean(axis=0)
    V0 = V - c
    F, g = _f64(Wc.normals), _f64(Wc.offsets) - _f64(Wc.normals) @ c
    if not np.all(g > 0):
        raise ValueError("W (Hull): the vertex mean must lie strictly inside (full-dimensional W)")

    def h_W0(D):
        return np.max(D @ V0.T, axis=-1)

    def alpha_fn(As):
        return float(np.max(h_W0(F @ As) / g))

    axes = np.concatenate([np.eye(n), -np.eye(n)])
    D = _f64(default_directions(n) if directions is None else directions)
    if D.ndim != 2 or D.shape[1] != n:
        raise ValueError(f"directions: shape (F, {n}) expected, got {D.shape}")
    D = D / np.linalg.norm(D, axis=1, keepdims=True)
    state = {"k": 0, "Ai": np.eye(n), "hax": np.zeros(len(axes)), "hD": np.zeros(len(D))}

    def M_fn(s):
        while state["k"] < s:
            Ai = state["Ai"]
            state["hax"] += h_W0(axes @ Ai)
            state["hD"] += h_W0(D @ Ai)
            state["Ai"] = A @ Ai
            state["k"] += 1
        return float(np.max(state["hax"]))

    s, a, exact = _choose_s(A, alpha_fn, M_fn, eps, s_max, nil_tol)
    M_fn(s)
    centre = np.linalg.solve(np.eye(n) - A, c)
    inner_pts = _minkowski_power_sum(A, V0, s) + centre
    inner = _hull_from_points(inner_pts)
    b = state["hD"] / (1.0 - a) + D @ centre
    Vt = _hpoly_vertices(D, b, centre)
    outer = TemplatePolytope(jnp.asarray(D), jnp.asarray(b), jnp.asarray(Vt), jnp.asarray(centre))
    return MRPI(inner, outer, int(s), float(a), float(eps), bool(exact))


# ---------------------------------------------------------------------------------------------
# disturbances and W estimators
# ---------------------------------------------------------------------------------------------

class Disturbances(NamedTuple):
    """w samples per plane: ``w`` (..., n_steps−1, 2, n), ``mask`` (..., n_steps−1) bool.
    w[..., k, plane, :] = x_{k+1} − A x_k − B u_k (n = 3 for [c, p, v], 2 for [p, v])."""
    w: jax.Array
    mask: jax.Array


def _plane_mats(A, B, n_state=None):
    A = jnp.asarray(A)
    B = jnp.asarray(B)
    if A.ndim == 2:
        A = jnp.broadcast_to(A, (2,) + A.shape)
    if B.ndim == 1:
        B = jnp.broadcast_to(B, (2,) + B.shape)
    n = A.shape[-1]
    if A.shape != (2, n, n) or n not in (2, 3):
        raise ValueError(f"A: shape (n, n) or (2, n, n) with n in (2, 3) expected, got {A.shape}")
    if B.shape != (2, n):
        raise ValueError(f"B: shape ({n},) or (2, {n}) expected to match A, got {B.shape}")
    return A, B


def _states(x, n):
    """Select [c, p, v] (n = 3) or [p, v] (n = 2, drop c) from (..., 3) states."""
    if x.shape[-1] != 3:
        raise ValueError(f"x_robot / e: last axis must be the per-plane state [c, p, v] (size 3), "
                         f"got {x.shape[-1]}")
    return x if n == 3 else x[..., 1:]


def step_mask(valid, transient: int = 0):
    """Valid-and-settled mask (..., n_steps): step k counts if k ≥ transient and every step
    0..k is valid (so everything after the first failure is dropped)."""
    valid = jnp.asarray(valid, bool)
    alive = jnp.cumprod(valid.astype(jnp.int32), axis=-1).astype(bool)
    k = jnp.arange(valid.shape[-1])
    return alive & (k >= transient)


@jax.jit
def _disturbances(x, u, valid, A, B, transient):
    n = A.shape[-1]
    xs = _states(x, n)  # (..., T, 2, n)
    pred = jnp.einsum("pij,...pj->...pi", A, xs[..., :-1, :, :]) + B * u[..., :-1, :, None]
    w = xs[..., 1:, :, :] - pred
    m = step_mask(valid, transient)
    mask = m[..., :-1] & m[..., 1:]
    return Disturbances(w, mask)


def disturbances(x_robot, u_exec, valid, A, B, transient: int = 0) -> Disturbances:
    """Per-plane S2S disturbances w_k = x_{k+1} − A x_k − B u_k from a log.

    Args:
      x_robot: (..., n_steps, 2, 3) pre-impact states [c [m], p [m], v [m/s]] per plane
        (plane 0 sagittal, 1 lateral).
      u_exec: (..., n_steps, 2) executed step sizes [m].
      valid: (..., n_steps) bool, step data valid.
      A, B: (n, n), (n,) or per plane (2, n, n), (2, n); n = 3 uses [c, p, v], n = 2 drops c.
      transient: steps k < transient are excluded (w_k needs steps k and k+1 counted).
    Returns :class:`Disturbances` (w (..., n_steps−1, 2, n), mask (..., n_steps−1)).
    """
    x = jnp.asarray(x_robot)
    u = jnp.asarray(u_exec, x.dtype)
    v = jnp.asarray(valid, bool)
    if x.ndim < 3 or x.shape[-2:] != (2, 3):
        raise ValueError(f"x_robot: shape (..., n_steps, 2, 3) expected, got {x.shape}")
    if u.shape != x.shape[:-1]:
        raise ValueError(f"u_exec: shape {x.shape[:-1]} expected (..., n_steps, 2), got {u.shape}")
    if v.shape != x.shape[:-2]:
        raise ValueError(f"valid: shape {x.shape[:-2]} expected (..., n_steps), got {v.shape}")
    if x.shape[-3] < 2:
        raise ValueError(f"x_robot: n_steps ≥ 2 needed, got {x.shape[-3]}")
    if int(transient) < 0:
        raise ValueError(f"transient: must be ≥ 0, got {transient}")
    Ap, Bp = _plane_mats(A, B)
    return _disturbances(x, u, v, Ap.astype(x.dtype), Bp.astype(x.dtype), int(transient))


def placement_errors(u_exec, u_hlip, e, K):
    """Foot-placement errors δu_k = u_k − (u_HLIP,k + K e_k) [m] per plane: how far the executed
    step (robot foot to foot at SSP⁻_k) lies from the step the stepping law asks for at the
    same pre-impact error e_k.  0 on the H-LIP plant without step noise.

    Args:
      u_exec, u_hlip: (..., n_steps, 2) executed and H-LIP step sizes [m].
      e: (..., n_steps, 2, 3) errors x_robot − x_HLIP per plane [c, p, v].
      K: stepping gain (n,) or per plane (2, n); n = 2 acts on [p, v].
    Returns (..., n_steps, 2)."""
    e = _f64(e)
    K = _f64(K)
    n = K.shape[-1]
    Kp = np.broadcast_to(K, (2, n))
    return _f64(u_exec) - _f64(u_hlip) - np.einsum("pj,...pj->...p", Kp, _states(e, n))


def to_heading(v, heading):
    """Per-plane vectors v (..., 2, n) [world x, y] → (sagittal, lateral) of the frame turned by
    ``heading`` θ (...) [rad]: v'_0 = cos θ v_x + sin θ v_y, v'_1 = −sin θ v_x + cos θ v_y."""
    return steplog.to_heading_frame(_f64(v), _f64(heading))


def heading_frame(e, d, heading, A_cl):
    """Errors and error-system disturbances of a log, rotated from the world planes (x, y) into
    the path's heading frame (sagittal along θ_k, lateral to its left).

    Per state component j (c, p, v alike: each is a horizontal vector split over the planes),
    e'_k = R(θ_k) e_k with R(θ) = [[cos θ, sin θ], [−sin θ, cos θ]] acting on the plane axis.
    When the closed loop is the same in both planes, A_cl commutes with R and the world
    recursion e_{k+1} = A_cl e_k + d_k becomes

        e'_{k+1} = A_cl e'_k + d'_k,   d'_k = R(θ_{k+1}) d_k + A_cl (R(θ_{k+1}) − R(θ_k)) e_k:

    the disturbance as the walking robot sees it plus the term the turning frame adds (zero on
    a straight path).  d' = e'_{k+1} − A_cl e'_k exactly, so the mRPI analysis of (A_cl, W') in
    the heading frame is the same theory as in the world frame; what changes is which
    disturbances are pooled: a bias along the walking direction (an over-step, a lag) keeps
    its sign when the path turns round, instead of flipping between +x and −x.

    Args:
      e: (..., n_steps, 2, n) world-frame errors [m, m/s].
      d: (..., n_steps − 1, 2, n) world-frame disturbances with e_{k+1} = A_cl e_k + d_k.
      heading: (..., n_steps) path heading θ_k [rad] at each pre-impact instant.
      A_cl: (n, n), or (2, n, n) with both planes equal (a different gain per plane does not
        commute with the rotation; ValueError).
    Returns (e', d') with the shapes of e and d; plane 0 sagittal, 1 lateral."""
    e = _f64(e)
    d = _f64(d)
    th = _f64(heading)
    Acl = _f64(A_cl)
    if Acl.ndim == 3:
        if Acl.shape[0] != 2 or not np.allclose(Acl[0], Acl[1], rtol=1e-12, atol=1e-12):
            raise ValueError("A_cl: the heading frame needs the same closed loop in both planes "
                             "(gain.lateral = 'same'); got different per-plane A + BK")
        Acl = Acl[0]
    n = Acl.shape[-1]
    if e.ndim < 3 or e.shape[-2:] != (2, n):
        raise ValueError(f"e: shape (..., n_steps, 2, {n}) expected, got {e.shape}")
    if d.shape != e.shape[:-3] + (e.shape[-3] - 1, 2, n):
        raise ValueError(f"d: shape {e.shape[:-3] + (e.shape[-3] - 1, 2, n)} expected, got {d.shape}")
    if th.shape != e.shape[:-2]:
        raise ValueError(f"heading: shape {e.shape[:-2]} expected (..., n_steps), got {th.shape}")
    e_rot = to_heading(e, th)
    # A_cl (R(θ_{k+1}) − R(θ_k)) e_k: the frame's turn between the two pre-impact instants
    turn = (to_heading(e[..., :-1, :, :], th[..., 1:]) - e_rot[..., :-1, :, :]) @ Acl.T
    return e_rot, to_heading(d, th[..., 1:]) + turn


def estimate_w(samples, mask=None, method: str = "box", quantile: float = 0.99):
    """Disturbance set W from samples (N, n) of one plane (rows with ``mask`` False dropped).

    method: "box" (per-axis min/max), "quantile" (per-axis [Q(1−q), Q(q)], q = ``quantile``
    in (0.5, 1]; q = 1 is the min/max box), or "hull" (convex hull, scipy Qhull).
    """
    P = _f64(samples).reshape(-1, np.shape(samples)[-1])
    if mask is not None:
        P = P[np.asarray(mask, bool).reshape(-1)]
    if P.shape[0] == 0:
        raise ValueError("estimate_w: no valid samples (mask selects none)")
    if method == "box":
        return Box(jnp.asarray(P.min(axis=0)), jnp.asarray(P.max(axis=0)))
    if method == "quantile":
        if not 0.5 < quantile <= 1.0:
            raise ValueError(f"quantile: must be in (0.5, 1], got {quantile}")
        lo = np.quantile(P, 1.0 - quantile, axis=0)
        hi = np.quantile(P, quantile, axis=0)
        return Box(jnp.asarray(lo), jnp.asarray(hi))
    if method == "hull":
        return _hull_from_points(P)
    raise ValueError(f"method: one of 'box', 'quantile', 'hull' expected, got {method!r}")


# ---------------------------------------------------------------------------------------------
# coverage and whole-log analysis
# ---------------------------------------------------------------------------------------------

class Coverage(NamedTuple):
    """Fraction of samples inside the inner set (F_s) and inside the outer set (F_s/(1−α));
    the true mRPI coverage lies in [inner, outer].  n: number of samples counted."""
    inner: float
    outer: float
    n: int


def coverage(E, e_samples, mask=None, tol: float | None = None) -> Coverage:
    """Coverage bracket of error samples e (..., n) (rows with ``mask`` False ignored).

    ``tol`` (relative to the set's size) defaults to 1e-9, raised to 50 machine epsilons of
    the samples' dtype: errors logged in float32 carry ~1e-7 relative rounding, and a sample
    that lies on E's boundary by construction (W estimated from the same data) must count
    as inside."""
    e = np.asarray(e_samples)
    if tol is None:
        eps = np.finfo(e.dtype).eps if np.issubdtype(e.dtype, np.floating) else 0.0
        tol = max(1e-9, 50.0 * float(eps))
    m = np.ones(e.shape[:-1], bool) if mask is None else np.asarray(mask, bool)
    if m.shape != e.shape[:-1]:
        raise ValueError(f"mask: shape {e.shape[:-1]} expected, got {m.shape}")
    cnt = int(m.sum())
    if cnt == 0:
        return Coverage(float("nan"), float("nan"), 0)
    inner_set = E.inner if isinstance(E, MRPI) else E
    outer_set = E.outer if isinstance(E, MRPI) else E
    pts = e[m]  # only the counted samples are tested
    fi = float(np.sum(np.asarray(inner_set.contains(pts, tol)))) / cnt
    fo = fi if outer_set is inner_set else float(np.sum(np.asarray(outer_set.contains(pts, tol)))) / cnt
    return Coverage(fi, fo, cnt)


class PlaneAnalysis(NamedTuple):
    """Per-plane result of :func:`analyse`.  W, E from all scenarios; coverage in-sample;
    W_train, E_train from the training split and heldout = coverage on the held-out split."""
    W: Any
    E: MRPI
    s: int
    alpha: float
    volume: float
    coverage: Coverage
    W_train: Any
    E_train: Optional[MRPI]
    heldout: Optional[Coverage]
    n_w: int


class Analysis(NamedTuple):
    """``planes`` = (sagittal, lateral) :class:`PlaneAnalysis`; ``combined`` = joint coverage
    (a step counts when both planes' errors are inside), in-sample and held-out;
    ``train``/``test``: scenario indices of the split (leading axis)."""
    planes: tuple
    combined: Coverage
    combined_heldout: Optional[Coverage]
    train: np.ndarray
    test: np.ndarray


def _joint(E_pair, e, mask, tol):
    """Joint coverage bracket of both planes; e (..., 2, n), mask (...)."""
    m = np.asarray(mask, bool)
    cnt = int(m.sum())
    if cnt == 0:
        return Coverage(float("nan"), float("nan"), 0)
    pts = e[m]  # (cnt, 2, n)
    ins_i = np.ones(cnt, bool)
    ins_o = np.ones(cnt, bool)
    for p, E in enumerate(E_pair):
        ins_i &= np.asarray(E.inner.contains(pts[:, p, :], tol))
        ins_o &= np.asarray(E.outer.contains(pts[:, p, :], tol))
    return Coverage(float(ins_i.sum()) / cnt, float(ins_o.sum()) / cnt, cnt)


def analyse(x_robot, u_exec, valid, e, A, B, K, W_estimator: str = "box",
            quantile: float = 0.99, transient: int = 0, holdout_fraction: float = 0.0,
            seed: int = 0, eps: float = 1e-5, directions=None, tol: float = 1e-9,
            min_halfwidth=None, u_hlip=None, heading=None) -> Analysis:
    """Per-plane W / E / coverage of a whole log.

    Args:
      x_robot (..., n_steps, 2, 3), u_exec (..., n_steps, 2), valid (..., n_steps): the log
        (see :func:`disturbances`); e (..., n_steps, 2, 3): errors x_robot − x_HLIP, counted
        with the same mask as the states (:func:`step_mask`).
      A, B: S2S matrices, shared or per plane; their size selects [c, p, v] or [p, v].
      K: stepping gain (n,) or per plane (2, n); A_cl = A + B K.
      u_hlip: (..., n_steps, 2) H-LIP steps, or None.  Given, W bounds the error system's
        disturbance d = w + B δu (:func:`placement_errors`), which the errors obey exactly
        (e⁺ = A_cl e + d); None bounds the robot's S2S disturbance w alone.
      W_estimator, quantile: see :func:`estimate_w`.
      holdout_fraction: in [0, 1); the leading axis (scenarios) is split with
        ``numpy.random.default_rng(seed)``: W is re-estimated on the training scenarios and
        coverage measured on the held-out ones.  0 skips the held-out part.
      eps, directions, min_halfwidth: passed to :func:`mrpi`.
      heading: (..., n_steps) path heading θ_k [rad], or None.  Given, the planes are the
        heading frame's sagittal and lateral ones (:func:`heading_frame`; needs the same gain
        in both planes); None keeps the world's x and y.
    """
    x = _f64(x_robot)
    if x.ndim < 4:
        raise ValueError(f"x_robot: shape (n_scenarios, ..., n_steps, 2, 3) expected, got {x.shape}")
    e = _f64(e)
    if e.shape != x.shape:
        raise ValueError(f"e: shape {x.shape} (same as x_robot) expected, got {e.shape}")
    if not 0.0 <= holdout_fraction < 1.0:
        raise ValueError(f"holdout_fraction: must be in [0, 1), got {holdout_fraction}")
    Ap, Bp = _plane_mats(A, B)
    Ap, Bp = np.asarray(Ap, np.float64), np.asarray(Bp, np.float64)
    n = Ap.shape[-1]
    Kp = np.broadcast_to(_f64(K), (2, n)) if _f64(K).shape in ((n,), (2, n)) else None
    if Kp is None:
        raise ValueError(f"K: shape ({n},) or (2, {n}) expected, got {np.shape(K)}")
    Acl = Ap + Bp[:, :, None] * Kp[:, None, :]

    d = disturbances(x, u_exec, valid, Ap, Bp, transient)
    w, wmask = np.asarray(d.w, np.float64), np.asarray(d.mask)
    if u_hlip is not None:
        du = placement_errors(u_exec, u_hlip, e, Kp)                  # (..., n_steps, 2)
        w = w + Bp * du[..., :-1, :, None]
    es = _states(e, n)
    if heading is not None:
        es, w = heading_frame(es, w, heading, Acl)
    alive = np.cumprod(np.asarray(valid, bool), axis=-1).astype(bool)
    emask = alive & (np.arange(alive.shape[-1]) >= transient)  # = step_mask, in numpy

    n_scen = x.shape[0]
    n_test = int(round(holdout_fraction * n_scen))
    if holdout_fraction > 0:
        n_test = min(max(n_test, 1), n_scen - 1)
        if n_test < 1:
            raise ValueError(f"holdout_fraction: needs ≥ 2 scenarios on the leading axis, got {n_scen}")
    perm = np.random.default_rng(seed).permutation(n_scen)
    test = np.sort(perm[:n_test])
    train = np.sort(perm[n_test:])

    planes, Es, Es_tr = [], [], []
    for p in range(2):
        W = estimate_w(w[..., p, :], wmask, W_estimator, quantile)
        E = mrpi(Acl[p], W, eps=eps, directions=directions, min_halfwidth=min_halfwidth)
        cov = coverage(E, es[..., p, :], emask, tol)
        W_tr = E_tr = held = None
        if n_test:
            W_tr = estimate_w(w[train][..., p, :], wmask[train], W_estimator, quantile)
            E_tr = mrpi(Acl[p], W_tr, eps=eps, directions=directions,
                        min_halfwidth=min_halfwidth)
            held = coverage(E_tr, es[test][..., p, :], emask[test], tol)
        Es.append(E)
        Es_tr.append(E_tr)
        planes.append(PlaneAnalysis(W, E, E.s, E.alpha, float(E.volume()), cov, W_tr, E_tr,
                                    held, int(wmask.sum())))
    comb = _joint(Es, es, emask, tol)
    comb_h = _joint(Es_tr, es[test], emask[test], tol) if n_test else None
    return Analysis(tuple(planes), comb, comb_h, train, test)


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------

STATE_LABELS = {3: ("c [m]", "p [m]", "v [m/s]"), 2: ("p [m]", "v [m/s]")}


def _split_inside(E, samples, tol=1e-9):
    P = _f64(samples).reshape(-1, E.dim)
    inside = np.asarray(E.contains(P, tol))
    return P, inside


def plot_set_3d(E, samples=None, ax=None, face_color="tab:blue", inside_color="tab:green",
                outside_color="tab:red", alpha: float = 0.15, labels=None):
    """E (3-D) as transparent polytope faces with samples (k, 3): inside / outside coloured."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import ConvexHull

    if ax is None:
        ax = plt.figure().add_subplot(projection="3d")
    V = vertices(E)
    hull = ConvexHull(V)
    faces = [V[t] for t in hull.simplices]
    ax.add_collection3d(Poly3DCollection(faces, facecolor=face_color, alpha=alpha,
                                         edgecolor="none"))
    pts = V
    if samples is not None:
        P, inside = _split_inside(E, samples)
        ax.scatter(*P[inside].T, s=3, c=inside_color, label=f"inside ({inside.mean():.1%})")
        if (~inside).any():
            ax.scatter(*P[~inside].T, s=6, c=outside_color, label=f"outside ({(~inside).sum()})")
        pts = np.concatenate([V, P])
        ax.legend(loc="upper left", fontsize="small")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    for set_lim, a, b in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lo, hi):
        set_lim(a - 0.05 * (b - a + 1e-12), b + 0.05 * (b - a + 1e-12))
    lab = labels or STATE_LABELS[3]
    ax.set_xlabel(lab[0]), ax.set_ylabel(lab[1]), ax.set_zlabel(lab[2])
    return ax


def plot_set_2d(E, samples=None, dims=(0, 1), ax=None, face_color="tab:blue",
                inside_color="tab:green", outside_color="tab:red", alpha: float = 0.2,
                labels=None):
    """Projection of E onto coordinates ``dims`` (polygon) with projected samples, coloured by
    membership in the full-dimensional E."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.spatial import ConvexHull

    if ax is None:
        ax = plt.figure().add_subplot()
    V = vertices(E)[:, list(dims)]
    poly = V[ConvexHull(V).vertices]
    ax.fill(*poly.T, color=face_color, alpha=alpha, lw=1)
    if samples is not None:
        P, inside = _split_inside(E, samples)
        P = P[:, list(dims)]
        ax.scatter(*P[inside].T, s=3, c=inside_color)
        ax.scatter(*P[~inside].T, s=6, c=outside_color)
    lab = labels or STATE_LABELS[E.dim]
    ax.set_xlabel(lab[dims[0]]), ax.set_ylabel(lab[dims[1]])
    return ax


def plot_planes(E_pair, e_pair, title: str = ""):
    """Paper-style figure: one panel per plane (sagittal, lateral) with E and the errors e_k
    (3-D for [c, p, v], 2-D for [p, v]).  Returns the matplotlib Figure."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 5))
    for p, (E, e, name) in enumerate(zip(E_pair, e_pair, ("sagittal", "lateral"))):
        if E.dim == 3:
            ax = fig.add_subplot(1, 2, p + 1, projection="3d")
            plot_set_3d(E, e, ax=ax)
        else:
            ax = fig.add_subplot(1, 2, p + 1)
            plot_set_2d(E, e, ax=ax)
        ax.set_title(f"{name}: E and e_k")
    if title:
        fig.suptitle(title)
    return fig
