"""A block of ADMM iterations of many small dense QPs as one fused kernel (Pallas).

:mod:`hlip_jax.core.qp` runs each ADMM iteration of a batch as a handful of XLA operations (two
products with Ā, one with K⁻¹, the projection and the updates).  On a GPU each is a kernel
launch that reads every problem's Ā and K⁻¹ from memory again, and a tier of a few hundred
straggling problems pays those launches once per iteration for hundreds of iterations.  Here
one kernel runs a whole block: each program loads a tile of problems' K⁻¹ (n×n) and Ā (m×n)
once, runs ``iterations`` steps on values held on chip, and writes the iterates back.

The step is :func:`hlip_jax.core.qp._admm_step` with ``linsys = "inverse"`` (scaled variables,
per-row ρ, over-relaxation α, x-regularisation σ):

    x̃ = K⁻¹ (σx − q̄ + Āᵀ(ρ∘z − y)),  z̃ = Āx̃,
    x ← αx̃ + (1−α)x,  z_r = αz̃ + (1−α)z,  z ← Π_[l̄,ū](z_r + y/ρ),  y ← y + ρ∘(z_r − z),

and a step is taken only while the problem's iteration count is below ``max_iter`` (so a
partial last block stops there exactly, as in :func:`hlip_jax.core.qp._iterate`).  The last step's
differences δx, δy (the infeasibility certificates' inputs) are returned with the iterates.

Shapes are padded to powers of two (Triton's block shapes) and the batch to a whole number
of tiles.  Padded entries are inert: K⁻¹, Ā, q̄ are zero there, l̄ = ū = 0 and ρ = 1, so a
padded variable or row stays exactly 0 and adds exact zeros to every sum.  The products are
written as broadcast multiplies and sums (n, m ≤ 64 here: too small for matrix units), so
the rounding differs from XLA's matmuls by the order of the float32 sums.

On a GPU the kernel is compiled by Pallas's Triton backend; elsewhere it runs in Pallas's
interpreter (CPU tests check it against the XLA loop in float64).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jax.experimental import pallas as pl

_TILE_ELEMENTS = 2048  # problems per program × padded m × padded n (keeps Ā in registers)


class Iterates(NamedTuple):
    """A batch's ADMM iterates (scaled variables), leading axis B.

    x: primal iterate (B, n).  z: projected constraint values (B, m).  y: multipliers (B, m).
    dx, dy: the last step's differences x_k − x_{k−1} (B, n) and y_k − y_{k−1} (B, m).
    it: iterations run so far (B,) int32.
    """

    x: jax.Array
    z: jax.Array
    y: jax.Array
    dx: jax.Array
    dy: jax.Array
    it: jax.Array


class Problems(NamedTuple):
    """The scaled data a block needs, leading axis B.

    Kinv: (P̄ + σI + Āᵀ diag(ρ) Ā)⁻¹ (B, n, n).  A: Ā (B, m, n).  q: q̄ (B, n).
    l, u: l̄, ū (B, m), ±inf where unbounded.  rho: per-row step sizes ρ (B, m), > 0.
    """

    Kinv: jax.Array
    A: jax.Array
    q: jax.Array
    l: jax.Array
    u: jax.Array
    rho: jax.Array


def tile_size(n: int, m: int) -> int:
    """Problems per program: a power of two with tile × m̂ × n̂ ≤ 2048 (m̂, n̂ the padded
    sizes), at least 1."""
    per = pl.next_power_of_2(m) * pl.next_power_of_2(n)
    tile = 1
    while 2 * tile * per <= _TILE_ELEMENTS:
        tile *= 2
    return tile


def _step(prob, sigma: float, alpha: float, max_iter: int, carry):
    """One masked ADMM step on a tile (the module's formulas); ``prob`` holds loaded values."""
    Kinv, A, q, l, u, rho = prob
    x, z, y, dx, dy, it = carry
    rhs = sigma * x - q + jnp.sum(A * (rho * z - y)[:, :, None], axis=1)
    xt = jnp.sum(Kinv * rhs[:, None, :], axis=2)
    zt = jnp.sum(A * xt[:, None, :], axis=2)
    xn = alpha * xt + (1.0 - alpha) * x
    zr = alpha * zt + (1.0 - alpha) * z
    zn = jnp.minimum(jnp.maximum(zr + y / rho, l), u)
    yn = y + rho * (zr - zn)
    go = it < max_iter
    g = go[:, None]
    return (jnp.where(g, xn, x), jnp.where(g, zn, z), jnp.where(g, yn, y),
            jnp.where(g, xn - x, dx), jnp.where(g, yn - y, dy), it + go.astype(it.dtype))


def _kernel(*refs, sigma: float, alpha: float, iterations: int, max_iter: int):
    """Pallas kernel: refs are the six Problems tiles, the six Iterates tiles in, the six out."""
    prob = tuple(r[...] for r in refs[:6])
    carry = tuple(r[...] for r in refs[6:12])
    body = lambda _, c: _step(prob, sigma, alpha, max_iter, c)
    out = lax.fori_loop(0, iterations, body, carry)
    for ref, v in zip(refs[12:], out):
        ref[...] = v


def _pad(a, shape, value):
    """Pad ``a`` at the end of every axis to ``shape`` with ``value``."""
    return jnp.pad(a, [(0, t - s) for s, t in zip(a.shape, shape)], constant_values=value)


def _spec(shape, tile):
    """Block of ``tile`` problems (the leading axis) and whole trailing axes."""
    rest = len(shape) - 1
    return pl.BlockSpec((tile,) + tuple(shape[1:]), lambda i: (i,) + (0,) * rest)


def run_on_gpu() -> bool:
    """Whether Pallas compiles the kernel (Triton, on GPUs) rather than interpreting it."""
    return jax.default_backend() == "gpu"


@functools.partial(jax.jit, static_argnames=("sigma", "alpha", "iterations", "max_iter"))
def admm_block(prob: Problems, st: Iterates, *, sigma: float, alpha: float, iterations: int,
               max_iter: int) -> Iterates:
    """``iterations`` ADMM steps of every problem of the batch (each stopping at ``max_iter``
    iterations in all), as one kernel.  Returns the new :class:`Iterates`."""
    B, m, n = prob.A.shape
    N, M, T = pl.next_power_of_2(n), pl.next_power_of_2(m), tile_size(n, m)
    Bp = -(-B // T) * T
    pad_prob = Problems(_pad(prob.Kinv, (Bp, N, N), 0), _pad(prob.A, (Bp, M, N), 0),
                        _pad(prob.q, (Bp, N), 0), _pad(prob.l, (Bp, M), 0),
                        _pad(prob.u, (Bp, M), 0), _pad(prob.rho, (Bp, M), 1))
    pad_st = Iterates(_pad(st.x, (Bp, N), 0), _pad(st.z, (Bp, M), 0), _pad(st.y, (Bp, M), 0),
                      _pad(st.dx, (Bp, N), 0), _pad(st.dy, (Bp, M), 0),
                      _pad(st.it, (Bp,), max_iter))
    args = tuple(pad_prob) + tuple(pad_st)
    kernel = functools.partial(_kernel, sigma=sigma, alpha=alpha, iterations=iterations,
                               max_iter=max_iter)
    out = pl.pallas_call(
        kernel,
        out_shape=tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in pad_st),
        grid=(Bp // T,),
        in_specs=[_spec(a.shape, T) for a in args],
        out_specs=tuple(_spec(a.shape, T) for a in pad_st),
        interpret=not run_on_gpu(),
    )(*args)
    return Iterates(out[0][:B, :n], out[1][:B, :m], out[2][:B, :m], out[3][:B, :n],
                    out[4][:B, :m], out[5][:B])
