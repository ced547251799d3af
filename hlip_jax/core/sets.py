"""Convex sets for error-invariant-set analysis, and the mRPI set of a linear error system.

Following Raković, Kerrigan, Kouramas & Mayne, "Invariant approximations of the minimal robust
positively invariant set", IEEE TAC 2005: for e⁺ = A_cl e + w, w ∈ W (W containing the origin
in its interior),

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
values (:func:`as_float64`); the per-point functions run in JAX.  Constructors with the
H-representation filled in: :func:`zonotope`, :func:`convex_hull`; vertices of a set:
:func:`vertices`, of any bounded {x : N x ≤ b}: :func:`halfspace_vertices`.  The error system these sets serve is described in
:mod:`hlip_jax.core.invariant`; figures of them are in :mod:`hlip_jax.presentation.set_figures`.
"""

from __future__ import annotations

import functools
import itertools
from functools import partial
from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np


# ---------------------------------------------------------------------------------------------
# set types
# ---------------------------------------------------------------------------------------------

_CHUNK = 65536  # points per block in membership tests (bounds the (points × facets) temporary)


def as_float64(x) -> np.ndarray:
    """``x`` (numbers, nested lists, numpy or JAX arrays) as a float64 numpy array on the host,
    the precision every construction of this module runs in (module doc); the values and their
    units are unchanged."""
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
        return _box_support(_for_kernels(self), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        """Bool per point (shape (...,) for points (..., n)); ``tol`` relative to the widths."""
        return _box_contains(_for_kernels(self), jnp.asarray(points), tol)

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

    ``known_volume``, optional: the volume where the construction knows it in closed form (a
    truncated sum of a box, :func:`truncated_sum`); else :meth:`volume` sums the generators'
    determinants.
    """
    center: Any
    generators: Any
    normals: Any = None
    offsets: Any = None
    prefix_offsets: Any = None
    known_volume: Any = None

    @property
    def dim(self) -> int:
        return int(np.shape(self.center)[-1])

    def support(self, directions):
        """h(d) = dᵀc + Σ_k |g_kᵀ d|."""
        return _zono_support(_for_kernels(self), jnp.asarray(directions))

    def contains(self, points, tol: float = 1e-9):
        """Bool per point through the exact facets; ``tol`` relative to the set's size."""
        z = _for_kernels(self if self.normals is not None else zonotope_hrep(self))
        x = points if isinstance(points, jax.Array) else np.asarray(points)
        if any(isinstance(a, jax.core.Tracer) for a in jax.tree_util.tree_leaves(z)):
            x = jnp.asarray(x)                 # a traced set: the points join the trace
        if (z.prefix_offsets is not None and not isinstance(x, jax.core.Tracer)
                and not isinstance(z.normals, jax.core.Tracer) and x.size >= 8192 * x.shape[-1]):
            return _zono_contains_two_pass(z, x, tol)
        N, h = _pad_facets(z.normals, z.offsets, 1.0)
        return _padded_call(lambda p: _zono_contains(z.center, N, h, p, tol), x)

    def volume(self):
        """2ⁿ Σ_{|S|=n} |det G_S| over all n-subsets S of the generators (exact)."""
        return _zono_volume(self) if self.known_volume is None else self.known_volume


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
        return convex_hull(self.vertices)

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
        return _points_volume(as_float64(self.vertices))


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
        return _points_volume(as_float64(self.vertices))


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


def _facets(S):
    """(normals (F, n), offsets (F,), centre (n,), symmetric) of a polytope with an
    H-representation {x : N x ≤ b}, or {x : |N (x − c)| ≤ h} when ``symmetric``."""
    S = S.outer if isinstance(S, MRPI) else S
    if isinstance(S, Box):
        lo, hi = as_float64(S.lo), as_float64(S.hi)
        return np.eye(lo.size), 0.5 * (hi - lo), 0.5 * (lo + hi), True
    if isinstance(S, Zonotope):
        z = S if S.normals is not None else zonotope_hrep(S)
        return as_float64(z.normals), as_float64(z.offsets), as_float64(z.center), True
    if isinstance(S, Hull):
        h = S.canonical()
        V = as_float64(h.vertices)
        return as_float64(h.normals), as_float64(h.offsets), V.mean(axis=0), False
    if isinstance(S, TemplatePolytope):
        return as_float64(S.normals), as_float64(S.offsets), as_float64(S.center), False
    raise TypeError(f"S: Box, Zonotope, Hull, TemplatePolytope or MRPI expected, got "
                    f"{type(S).__name__}")


def center(S) -> np.ndarray:
    """The centre c about which :func:`gauge` and :class:`Scaled` measure and scale S (n,):
    a box's or zonotope's centre, a hull's vertex mean, a template polytope's centre."""
    return _facets(S)[2]


def gauge(S, points) -> np.ndarray:
    """The scale of each point relative to the polytope S about S's centre c:

        g(x) = min {s ≥ 0 : x ∈ c + s (S − c)} = max_f N_f (x − c) / (b_f − N_f c)

    (for a zonotope max_f |N_f (x − c)| / h_f), so x ∈ S ⇔ g(x) ≤ 1.  points (..., n);
    returns (...,) float64 (an MRPI bracket is measured against its outer set).  c must lie in
    S's interior, which every set of this module has by construction."""
    N, b, c, sym = _facets(S)
    x = as_float64(points) - c
    flat = x.reshape(-1, x.shape[-1])
    scale = 1.0 / np.maximum(b if sym else b - N @ c, np.finfo(float).tiny)   # (F,)
    rows = max(1, _GAUGE_BLOCK // max(1, N.shape[0]))     # bounds the (points × facets) block
    out = np.empty(flat.shape[0])
    for i in range(0, flat.shape[0], rows):
        r = flat[i:i + rows] @ N.T
        out[i:i + rows] = np.max((np.abs(r) if sym else r) * scale, axis=-1)
    return out.reshape(x.shape[:-1])


def gauge_within(S, points, level: float) -> np.ndarray:
    """g_S(x) ≤ ``level`` per point (bool, shape (...,)), the same decision as
    ``gauge(S, points) <= level``.  For a zonotope (or an MRPI bracket's) with prefix facets
    (:class:`Zonotope`: the complete facets of its leading terms Z₀, with Z₀'s half-widths)
    most points are decided on those F₀ facets alone: outside where one of them already gives a
    gauge above ``level`` (a subset of facets bounds the maximum from below), inside where
    x ∈ c + level (Z₀ − c) ⊆ c + level (Z − c); only the rest take every facet."""
    z = S.outer if isinstance(S, MRPI) else S
    x = as_float64(points)
    if not (isinstance(z, Zonotope) and z.prefix_offsets is not None and z.normals is not None):
        return gauge(S, x) <= level
    flat = x.reshape(-1, x.shape[-1])
    F0 = len(z.prefix_offsets)
    N0, c = as_float64(z.normals)[:F0], as_float64(z.center)
    tiny = np.finfo(float).tiny
    y = np.abs((flat - c) @ N0.T)                                     # (P, F₀)
    lower = np.max(y / np.maximum(as_float64(z.offsets)[:F0], tiny), axis=-1)
    in_z0 = np.max(y / np.maximum(as_float64(z.prefix_offsets), tiny), axis=-1) <= level
    out = in_z0 & (lower <= level)
    rest = np.flatnonzero((lower <= level) & ~in_z0)
    if rest.size:
        out[rest] = gauge(z, flat[rest]) <= level
    return out.reshape(x.shape[:-1])


#: (points × facets) entries per block of :func:`gauge` (8 MB of float64)
_GAUGE_BLOCK = 1 << 20


class Scaled(NamedTuple):
    """The set c + s (S − c): ``base`` S (a polytope of this module, or an MRPI bracket whose
    outer set is used) scaled by ``s`` ≥ 0 about its centre c (the calibrated sets of
    :mod:`hlip_jax.analysis.estimators`)."""
    base: Any
    s: float

    @property
    def dim(self) -> int:
        return self.base.dim

    def support(self, directions):
        """h(d) = dᵀc + s (h_S(d) − dᵀc)."""
        D = as_float64(directions)
        dc = D @ center(self.base)
        return dc + self.s * (as_float64(self.base.support(D)) - dc)

    def contains(self, points, tol: float = 1e-9):
        """g_S(x) ≤ s (1 + tol) per point (:func:`gauge`, :func:`gauge_within`)."""
        return gauge_within(self.base, points, self.s * (1.0 + tol))

    def volume(self):
        return float(self.base.volume()) * self.s ** self.dim


def _for_kernels(t):
    """Leaves ready for the jitted kernels: JAX arrays (and tracers) as they are, anything else
    as numpy.  A host array goes to the kernel as an argument; converting it with
    ``jnp.asarray`` first would run an eager op that compiles once per new shape, and set
    sizes change from scenario to scenario (the analysis of one 312-robot chunk spent
    minutes compiling such ops)."""
    return jax.tree_util.tree_map(lambda a: a if isinstance(a, jax.Array) else np.asarray(a), t)


def bucket(k: int) -> int:
    """Next power of two ≥ max(k, 16): padded sizes so that sets and sample batches of
    similar size share one compiled kernel."""
    return 1 << max(4, int(k - 1).bit_length())


def _pad_facets(N, b, fill):
    """Pad facet rows to a bucket size with inert rows (0ᵀx ≤ fill, fill ≥ 0)."""
    F = N.shape[0]
    pad = bucket(F) - F
    if pad == 0:
        return N, b
    xp = jnp if isinstance(N, jax.Array) or isinstance(b, jax.Array) else np
    N, b = xp.asarray(N), xp.asarray(b)     # JAX arrays take JAX's float width (no float64 ask)
    return (xp.concatenate([N, xp.zeros((pad, N.shape[1]), N.dtype)]),
            xp.concatenate([b, xp.full((pad,), fill, b.dtype)]))


def _padded_call(fn, x):
    """fn on points padded (flattened) to a bucket size; result reshaped to x.shape[:-1]."""
    batch = x.shape[:-1]
    flat = x.reshape(-1, x.shape[-1])
    k = flat.shape[0]
    if k == 0:
        return jnp.zeros(batch, bool)
    if isinstance(flat, jax.Array):            # traced or on a device: stay there
        return fn(jnp.pad(flat, ((0, bucket(k) - k), (0, 0))))[:k].reshape(batch)
    return np.asarray(fn(np.pad(flat, ((0, bucket(k) - k), (0, 0)))))[:k].reshape(batch)


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
def _zono_contains(center, normals, offsets, x, tol, chunk: int = _CHUNK):
    """max_f |N_f (x − c)| / h_f ≤ 1 + tol per point (symmetric facet pairs tested at once).
    Only the facets enter (padded to a bucket size), not the generators, whose number
    changes from set to set: one compile serves sets of similar facet counts."""
    Ns = normals / jnp.maximum(offsets, jnp.finfo(normals.dtype).tiny)[:, None]
    return _blocked(lambda blk: jnp.max(jnp.abs((blk - center) @ Ns.T), axis=-1) <= 1.0 + tol,
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
        inside[und] = np.asarray(_padded_call(lambda p: _zono_contains(z.center, N, h, p, tol),
                                              jnp.asarray(flat[und])))
    return jnp.asarray(inside.reshape(x.shape[:-1]))


def _padded_int(fn, x):
    flat = x.reshape(-1, x.shape[-1])
    k = flat.shape[0]
    return np.asarray(fn(jnp.pad(flat, ((0, bucket(k) - k), (0, 0)))))[:k].reshape(x.shape[:-1])


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
    G = as_float64(z.generators)
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


def significant_generators(G: np.ndarray) -> np.ndarray:
    """Mask (m,) of the generators that count for the facets: norm above 1e-14 × the largest
    (a term A^i W that has decayed to round-off adds no facet direction)."""
    return significant_norms(np.linalg.norm(G, axis=1))


def significant_norms(gn: np.ndarray) -> np.ndarray:
    """:func:`significant_generators` from the generators' norms ``gn`` (m,)."""
    if not gn.shape[0] or not gn.max() > 0:
        return np.zeros(gn.shape[0], bool)
    return gn > 1e-14 * gn.max()


def zonotope_normals(generators, parallel_rtol: float = 1e-12) -> np.ndarray:
    """Facet normal candidates (unit rows, each direction once; use ± both) of a zonotope.

    1-D: {1}.  2-D: the perpendicular of every generator.  3-D: g_i × g_j for every
    non-parallel pair (|g_i × g_j| > parallel_rtol |g_i||g_j|).  Degenerate (rank-deficient)
    generator sets are completed by an orthonormal basis of the missing directions, treated as
    extra generators for normal finding only, so flat sets get both their in-plane facets and
    the pair of bounding planes.  Generators below :func:`significant_generators` are left out.
    """
    G = as_float64(generators)
    return _normals_of(G[significant_generators(G)], G.shape[1], parallel_rtol)


def _normals_of(G: np.ndarray, n: int, parallel_rtol: float = 1e-12) -> np.ndarray:
    """:func:`zonotope_normals` of generators already filtered (rows of G, (m, n))."""
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
    c = as_float64(z.center)
    G = as_float64(z.generators).reshape(-1, c.shape[0])
    N, n0 = _facet_normals(G, n_prefix, *significant_split(G, n_prefix))
    h, h0 = _facet_widths(N, G, n0, n_prefix)
    return Zonotope(c, G, N, h, h0)


def significant_split(G: np.ndarray, n_prefix: int) -> tuple[np.ndarray, np.ndarray]:
    """(keep, keep0): :func:`significant_generators` of G, and of its first ``n_prefix``
    generators taken alone (empty without a prefix: 0 < n_prefix < m does not hold)."""
    return split_norms(np.linalg.norm(G, axis=1), n_prefix)


def split_norms(gn: np.ndarray, n_prefix: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`significant_split` from the generators' norms ``gn`` (m,)."""
    keep = significant_norms(gn)
    return keep, significant_norms(gn[:n_prefix]) if 0 < n_prefix < len(gn) else keep[:0]


def _facet_normals(G: np.ndarray, n_prefix: int, keep: np.ndarray,
                   keep0: np.ndarray) -> tuple[np.ndarray, int]:
    """(N, n0): the facet normals of the zonotope of the generators G[keep], the complete facet
    set of its first ``n_prefix`` generators (those of them in ``keep0``) first (n0 rows; 0
    without a prefix, ``keep0`` empty); the masks come from :func:`significant_split`."""
    n = G.shape[1]
    N, n0 = _normals_of(G[keep], n), 0
    if len(keep0):
        N0 = _normals_of(G[:n_prefix][keep0], n)
        N, n0 = _unique_directions(np.concatenate([N0, N])), len(N0)  # keeps N0 first, in order
    return N, n0


_WIDTH_ROWS = 2048   # facet rows per block of |N Gᵀ| (2048 × 400 generators: 6.5 MB)


def _facet_widths(N: np.ndarray, G: np.ndarray, n0: int, n_prefix: int):
    """(h, h0): h_f = Σ_k |N_f · g_k| for every facet row, and for the first ``n0`` rows the
    same over the first ``n_prefix`` generators (None where n0 = 0).  |N Gᵀ| is formed
    ``_WIDTH_ROWS`` rows at a time: a 3-state mRPI set has ~10⁵ facets × ~400 generators, and
    the whole temporary (hundreds of MB) made the sums memory-bound.  Each row's sum is the
    same numpy reduction over the same contiguous row, so the result is the same bit for bit."""
    h = np.empty(len(N), np.result_type(N, G))
    h0 = np.empty(n0, h.dtype) if n0 else None
    for i in range(0, len(N), _WIDTH_ROWS):
        P = np.abs(_small_matmul_t(N[i:i + _WIDTH_ROWS], G))
        h[i:i + len(P)] = P.sum(axis=1)
        if i < n0:
            h0[i:min(n0, i + len(P))] = P[:n0 - i, :n_prefix].sum(axis=1)
    return h, h0


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
    N, h, c = as_float64(z.normals), as_float64(z.offsets), as_float64(z.center)
    N2 = np.concatenate([N, -N])
    return N2, N2 @ c + np.concatenate([h, h])


def zonotope(center, generators, n_prefix: int = 0) -> Zonotope:
    """Zonotope c + Gᵀβ, |β| ≤ 1, with facets; center (n,), generators (m, n);
    ``n_prefix``: see :func:`zonotope_hrep`."""
    c = as_float64(center)
    if c.ndim != 1 or not 1 <= c.shape[0] <= 3:
        raise ValueError(f"zonotope center: shape (n,) with n in 1..3 expected, got {c.shape}")
    G = as_float64(generators).reshape(-1, c.shape[0])
    return zonotope_hrep(Zonotope(c, G), n_prefix)


def box_to_zonotope(b: Box) -> Zonotope:
    lo, hi = as_float64(b.lo), as_float64(b.hi)
    return zonotope(0.5 * (lo + hi), np.diag(0.5 * (hi - lo)))


def convex_hull(points) -> Hull:
    """The convex hull conv{p_j} of ``points`` (k, n), in the points' own units (here the state
    [c, p, v] in m, m, m/s), with its H-representation filled in (the same as
    ``Hull(points).canonical()``):

        conv{p_j} = {x : N x ≤ b},  N (F, n) unit outward facet normals, b (F,) offsets,

    vertices = the extreme points among the p_j (scipy Qhull, eager, float64); duplicate facets
    (equal (N_f, b_f) to 1e-10) appear once.  In 1-D the hull is the interval [min p, max p]
    with N = [[1], [−1]], b = [max p, −min p].  ValueError when there is no point or the points
    do not span the space (flat in n-D, or fewer than n + 1)."""
    from scipy.spatial import ConvexHull, QhullError

    P = as_float64(points)
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


def halfspace_vertices(normals, offsets, interior) -> np.ndarray:
    """Vertices (k, n) of the bounded polytope {x : N x ≤ b}, N = ``normals`` (F, n),
    b = ``offsets`` (F,), in the units of x (state units: m, m, m/s for [c, p, v]).

    ``interior`` (n,) is a point strictly inside (N x < b), e.g. a zonotope's centre.  In 1-D
    the polytope is the interval [max_{N_f < 0} b_f / N_f, min_{N_f > 0} b_f / N_f]; in more
    dimensions the vertices are the intersections of the facets (scipy's HalfspaceIntersection,
    eager, float64; non-finite intersections dropped; with joggled input where Qhull's exact
    merging fails)."""
    N, b = as_float64(normals), as_float64(offsets)
    if N.shape[1] == 1:
        up = b[N[:, 0] > 0] / N[N[:, 0] > 0, 0]
        dn = b[N[:, 0] < 0] / N[N[:, 0] < 0, 0]
        return np.array([[dn.max()], [up.min()]])
    from scipy.spatial import HalfspaceIntersection, QhullError

    H = np.concatenate([N, -b[:, None]], axis=1)
    try:
        V = HalfspaceIntersection(H, as_float64(interior)).intersections
    except QhullError:
        # thousands of nearly parallel facets (a slow mode of A + BK) can defeat Qhull's
        # merging ("wide merge error"); joggled input always triangulates, each vertex then off
        # by about 1e-11 of the set's size
        V = HalfspaceIntersection(H, as_float64(interior), qhull_options="QJ").intersections
    return V[np.all(np.isfinite(V), axis=1)]


def vertices(S) -> np.ndarray:
    """Vertices (k, n) of a Box, Zonotope, Hull, TemplatePolytope, MRPI (outer set) or Scaled."""
    if isinstance(S, Scaled):
        c = center(S.base)
        return c + S.s * (vertices(S.base) - c)
    if isinstance(S, MRPI):
        S = S.outer
    if isinstance(S, Box):
        lo, hi = as_float64(S.lo), as_float64(S.hi)
        return np.array([np.where(m, hi, lo) for m in itertools.product([0, 1], repeat=len(lo))])
    if isinstance(S, Hull):
        return as_float64(S.canonical().vertices)
    if isinstance(S, TemplatePolytope):
        return as_float64(S.vertices)
    if isinstance(S, Zonotope):
        N, b = zonotope_halfspaces(S)
        return halfspace_vertices(N, b, as_float64(S.center))
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


def schur_stable(A_cl, margin: float = 1e-9) -> bool:
    """Whether every eigenvalue of ``A_cl`` lies inside the circle of radius 1 − ``margin``
    (the error system then has a bounded invariant set)."""
    return bool(np.all(np.abs(np.linalg.eigvals(as_float64(A_cl))) < 1 - margin))


def _check_acl(A_cl, n: int) -> np.ndarray:
    A = as_float64(A_cl)
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
        c, G = as_float64(W.center), as_float64(W.generators)
        A = as_float64(A_cl).reshape(len(c), len(c))
        Ai, cs, gs = np.eye(len(c)), np.zeros_like(c), []
        for _ in range(s):
            cs = cs + Ai @ c
            gs.append(G @ Ai.T)
            Ai = A @ Ai
        cs = cs if center is None else as_float64(center)
        if _is_box(G):
            return _box_sum(A, np.diag(G).copy(), cs, np.concatenate(gs), s, n_prefix_terms)
        return zonotope(cs, np.concatenate(gs), n_prefix=n_prefix_terms * G.shape[0])
    if isinstance(W, Hull):
        V = as_float64(W.canonical().vertices)
        A = as_float64(A_cl).reshape(V.shape[1], V.shape[1])
        return convex_hull(_minkowski_power_sum(A, V, s))
    raise TypeError(f"W: Box, Zonotope or Hull expected, got {type(W).__name__}")


def _is_box(G: np.ndarray) -> bool:
    """Whether generators G (m, n) are those of an axis-aligned box: diag(r), r > 0."""
    return (G.ndim == 2 and G.shape[0] == G.shape[1] and 1 <= G.shape[0] <= 3
            and np.all(np.diag(G) > 0) and not np.any(G - np.diag(np.diag(G))))


def _box_sum(A: np.ndarray, r: np.ndarray, c: np.ndarray, G: np.ndarray, s: int,
             n_prefix_terms: int) -> Zonotope:
    """F_s = c + ⊕_{i<s} A^i diag(r) B_∞ with its exact facets, G its generators (s·n, n).

    Its generators are r_j A^i e_j: positive multiples of the unit generators u_{ij} = A^i e_j,
    so the facet normals are those of the u_{ij} (the same for every box) and each half-width
    is linear in r, h_f = Σ_j r_j Σ_i |N_f · A^i e_j| = (H r)_f.  N and H are formed once per
    (A, s, prefix, generators left out) (:func:`box_sum_template`); a sweep's scenarios share
    A + BK, so the per-scenario cost is H r instead of |N Gᵀ| (equal up to the order of the sums)."""
    n = len(r)
    n_prefix = n_prefix_terms * n
    keep, keep0 = significant_split(G, n_prefix)
    N, H, H0, T = box_sum_template(A.tobytes(), n, s, n_prefix, keep.tobytes(), keep0.tobytes())
    rr = functools.reduce(np.multiply.outer, [r] * n)          # r_a r_b … over label tuples
    return Zonotope(c, G, N, H @ r, None if H0 is None else H0 @ r,
                    np.float64(2.0 ** n * np.sum(T * rr)))


#: where :func:`box_sum_template` keeps its templates between processes (an object with
#: ``load(key) -> dict | None`` and ``save(key, dict)``, e.g.
#: :class:`hlip_jax.runtime.array_cache.ArrayCache`); None: in this process only
_TEMPLATE_STORE: list = [None]


def keep_templates_in(store) -> None:
    """Keep the facet templates of :func:`box_sum_template` in ``store`` (None: this process
    only), so that a later run of the same closed loop finds them instead of building them
    (about 0.1-0.3 s each for a 3-state sum of tens of terms)."""
    _TEMPLATE_STORE[0] = store


@functools.lru_cache(maxsize=64)
def box_sum_template(A_bytes: bytes, n: int, s: int, n_prefix: int, keep: bytes, keep0: bytes):
    """(N, H, H0, T) of :func:`_box_sum` (facet normals, half-widths per unit r, the prefix's,
    determinant sums) for A (its bytes, n × n), s terms, a prefix of ``n_prefix`` generators
    and the masks of the generators that count (:func:`significant_split`, bytes of bool);
    read from the template store where it holds them (:func:`keep_templates_in`)."""
    store = _TEMPLATE_STORE[0]
    key = template_key(A_bytes, n, s, n_prefix, keep, keep0)
    found = None if store is None else store.load(key)
    if found is not None and _template_fits(found, n):
        N, H, T = found["N"], found["H"], found["T"]
        H0 = found.get("H0")
    else:
        N, H, H0, T = _build_box_sum_template(A_bytes, n, s, n_prefix, keep, keep0)
        if store is not None:
            store.save(key, dict(N=N, H=H, T=T, **({} if H0 is None else {"H0": H0})))
    for a in (N, H, T) + ((H0,) if H0 is not None else ()):
        a.setflags(write=False)
    return N, H, H0, T


def template_key(A_bytes: bytes, n: int, s: int, n_prefix: int, keep: bytes, keep0: bytes) -> bytes:
    """The bytes that name a template in the store (:func:`box_sum_template`'s arguments)."""
    return b"|".join([A_bytes, f"{n}|{s}|{n_prefix}".encode(), keep, keep0])


def _template_fits(arrays: dict, n: int) -> bool:
    """Whether stored arrays have a template's names, dtypes and shapes for n states."""
    N, H, T = (arrays.get(k) for k in ("N", "H", "T"))
    H0 = arrays.get("H0")
    return (N is not None and H is not None and T is not None and N.ndim == 2
            and N.shape[1] == n and H.shape == N.shape and T.shape == (n,) * n
            and all(a.dtype == np.float64 for a in (N, H, T))
            and (H0 is None or (H0.dtype == np.float64 and H0.ndim == 2 and H0.shape[1] == n
                                and H0.shape[0] <= N.shape[0]))
            and set(arrays) <= {"N", "H", "T", "H0"})


def _build_box_sum_template(A_bytes: bytes, n: int, s: int, n_prefix: int, keep: bytes,
                            keep0: bytes):
    A = np.frombuffer(A_bytes, np.float64).reshape(n, n)
    U, Ai = [], np.eye(n)
    for _ in range(s):
        U.append(Ai.T)                       # rows: (A^i e_j)ᵀ, in truncated_sum's order
        Ai = A @ Ai
    U = np.concatenate(U)
    N, n0 = _facet_normals(U, n_prefix, np.frombuffer(keep, bool), np.frombuffer(keep0, bool))
    P = np.abs(N @ U.T)                       # (F, s·n): |N_f · u_ij|
    H = P.reshape(len(N), s, n).sum(axis=1)
    H0 = P[:n0, :n_prefix].reshape(n0, -1, n).sum(axis=1) if n0 else None
    return N, H, H0, _determinant_sums(U, np.tile(np.arange(n), s), n)


def box_sum_cache_info():
    """Hits and misses of the per-(A, s) facet templates of :func:`truncated_sum`'s box path."""
    return box_sum_template.cache_info()


def _determinant_sums(U: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """T (n,)*n: T[a, b, …] = Σ |det[u_i, u_j, …]| over the n-subsets i < j < … of the rows of
    U (m, n) whose labels are a, b, … in that order.  The zonotope of generators r_{l_i} u_i
    then has volume 2ⁿ Σ T[a, b, …] r_a r_b … (the determinant is multilinear and r > 0):
    :func:`_zono_volume`'s sum, grouped by label once per U."""
    T = np.zeros((n,) * n)
    m = len(U)
    if m < n:
        return T
    if n == 1:
        np.add.at(T, labels, np.abs(U[:, 0]))
    elif n == 2:
        i, j = np.triu_indices(m, k=1)
        np.add.at(T, (labels[i], labels[j]), np.abs(U[i, 0] * U[j, 1] - U[i, 1] * U[j, 0]))
    else:
        L = np.eye(n)[labels]                                     # (m, n) one-hot labels
        for i in range(m - 2):
            C = np.cross(U[i], U[i + 1:])                         # g_i × g_j, j > i
            D = np.triu(np.abs(C @ U[i + 1:].T), 1)               # |(g_i × g_j) · g_k|, k > j
            T[labels[i]] += L[i + 1:].T @ D @ L[i + 1:]
    return T


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
        lo, hi = as_float64(W.lo), as_float64(W.hi)
        if lo.ndim != 1 or lo.shape != hi.shape:
            raise ValueError(f"W (Box): lo, hi of equal shape (n,) expected, got {lo.shape}, {hi.shape}")
        if min_halfwidth is not None:
            mh = np.broadcast_to(as_float64(min_halfwidth), lo.shape)
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


def choose_orders(A: np.ndarray, alpha_fn, M_fn, eps, s_max, nilpotent_tol, rows: int = 1):
    """The truncation order of each of ``rows`` sums (Raković et al. 2005): the smallest s with
    α(s) ≤ ``nilpotent_tol`` (A^s W = {0}: exact, α taken as 0) or α(s) < 1 and
    α/(1−α)·M(s) ≤ ε.  ``alpha_fn(A^s)`` and ``M_fn(s)`` give α(s) and M(s) per row (rows,).
    Returns (s (rows,) int, α (rows,) float, exact (rows,) bool), s = 0 for a row with no such
    s ≤ ``s_max`` (:func:`one_order` raises instead)."""
    n = A.shape[0]
    As = np.eye(n)
    s_out, a_out = np.zeros(rows, np.int64), np.zeros(rows)
    exact, open_ = np.zeros(rows, bool), np.ones(rows, bool)
    for s in range(1, s_max + 1):
        As = A @ As  # A^s
        a = np.asarray(alpha_fn(As), np.float64).reshape(rows)
        nil = open_ & (a <= nilpotent_tol)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            ok = open_ & ~nil & (a < 1.0) & (a / (1.0 - a) * M_fn(s) <= eps)
        s_out[nil | ok], a_out[ok], exact[nil] = s, a[ok], True
        open_ &= ~(nil | ok)
        if not open_.any():
            break
    return s_out, a_out, exact


def one_order(A: np.ndarray, alpha_fn, M_fn, eps, s_max, nilpotent_tol) -> tuple[int, float, bool]:
    """:func:`choose_orders` of one sum as (s, α, exact); ValueError when no s ≤ ``s_max``
    meets ε."""
    s, a, exact = (v[0].item() for v in choose_orders(A, alpha_fn, M_fn, eps, s_max, nilpotent_tol))
    if s == 0:
        raise ValueError(f"mrpi: no s ≤ s_max={s_max} meets eps={eps}; raise s_max or eps")
    return s, a, exact


def _prefix_terms(A: np.ndarray, G: np.ndarray, s: int, tail: float = 0.1) -> int:
    """:func:`prefix_terms` of the sum F_s of the zonotope of generators G (m, n)."""
    sizes, Ai = [], np.eye(A.shape[0])
    for _ in range(s if s >= 6 else 0):
        sizes.append(np.max(np.sum(np.abs(G @ Ai.T), axis=0)))
        Ai = A @ Ai
    return prefix_terms(np.asarray(sizes), s, tail)


def prefix_terms(sizes: np.ndarray, s: int, tail: float = 0.1) -> int:
    """Number of leading terms A^i W whose sum carries all but ``tail`` of the size of F_s,
    ``sizes`` (s,) the terms' max-coordinate sizes max_j h_{A^i W}(e_j); 0 (no two-pass
    membership) when the sum is short anyway (s < 6) or the prefix would be over half of it."""
    if s < 6:
        return 0
    sizes = np.asarray(sizes, np.float64)[:s]
    rest = np.cumsum(sizes[::-1])[::-1] / np.sum(sizes)  # rest[i] = share of terms ≥ i
    s0 = int(np.argmax(rest <= tail))
    return s0 if 0 < s0 <= s // 2 else 0


def _mrpi_zonotope(A_cl, W: Zonotope, eps, s_max, nil_tol) -> MRPI:
    c = as_float64(W.center)
    G = as_float64(W.generators).reshape(-1, c.shape[0])
    n = c.shape[0]
    A = _check_acl(A_cl, n)
    # facets of W₀ = W − c: f_iᵀ w ≤ g_i, g_i = Σ_k |f_iᵀ g_k| > 0
    Wz = zonotope(np.zeros(n), G)
    F, g = as_float64(Wz.normals), as_float64(Wz.offsets)
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

    s, a, exact = one_order(A, alpha_fn, M_fn, eps, s_max, nil_tol)
    centre = np.linalg.solve(np.eye(n) - A, c)
    inner = truncated_sum(A, Zonotope(centre, G), s, center=centre,
                          n_prefix_terms=_prefix_terms(A, G, s) if n == 3 else 0)
    if exact:
        outer = inner
    else:  # scaling about the centre keeps the facet normals
        k = 1.0 / (1.0 - a)
        scaled = lambda v: None if v is None else as_float64(v) * k
        outer = Zonotope(inner.center, scaled(inner.generators), inner.normals,
                         scaled(inner.offsets), scaled(inner.prefix_offsets),
                         None if inner.known_volume is None else inner.known_volume * k ** n)
    return MRPI(inner, outer, int(s), float(a), float(eps), bool(exact))


def _mrpi_hull(A_cl, W: Hull, eps, s_max, directions, nil_tol) -> MRPI:
    Wc = W.canonical()
    V = as_float64(Wc.vertices)
    n = V.shape[1]
    A = _check_acl(A_cl, n)
    c = V.mean(axis=0)
    V0 = V - c
    F, g = as_float64(Wc.normals), as_float64(Wc.offsets) - as_float64(Wc.normals) @ c
    if not np.all(g > 0):
        raise ValueError("W (Hull): the vertex mean must lie strictly inside (full-dimensional W)")

    def h_W0(D):
        return np.max(D @ V0.T, axis=-1)

    def alpha_fn(As):
        return float(np.max(h_W0(F @ As) / g))

    axes = np.concatenate([np.eye(n), -np.eye(n)])
    D = as_float64(default_directions(n) if directions is None else directions)
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

    s, a, exact = one_order(A, alpha_fn, M_fn, eps, s_max, nil_tol)
    M_fn(s)
    centre = np.linalg.solve(np.eye(n) - A, c)
    inner_pts = _minkowski_power_sum(A, V0, s) + centre
    inner = convex_hull(inner_pts)
    b = state["hD"] / (1.0 - a) + D @ centre
    Vt = halfspace_vertices(D, b, centre)
    outer = TemplatePolytope(jnp.asarray(D), jnp.asarray(b), jnp.asarray(Vt), jnp.asarray(centre))
    return MRPI(inner, outer, int(s), float(a), float(eps), bool(exact))
