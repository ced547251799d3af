"""Tube tightening of the MPC by an error-invariant set: the paper's robust MPC.

The stepping law places u_R = u_H + K e with e = x_R − x_H, so per plane the error obeys

    e⁺ = A_cl e + d,    A_cl = A + B K,    d ∈ W

(d the S2S residual plus the placement error, :mod:`hlip_jax.core.invariant`).  If E is robust
positively invariant (A_cl E ⊕ W ⊆ E) and e_0 ∈ E — the planner plans from the H-LIP's own
state (``mpc.mode = "tube"``) and starts on the robot, e_0 = 0 — then e_k ∈ E at every step and

    steps:     u_R ∈ U                 ⇐  u_H ∈ U ⊖ K E
    keep-out:  n·(c_R − o) ≥ r         ⇐  n·(c_H − o) ≥ r + h_E(−n)

(h_E the support function; for a unit normal n of a half-plane outside the disc the robot's
COM then stays out of the disc, |c_R − o| ≥ n·(c_R − o) ≥ r).  The MPC's constraint rows
(:func:`hlip_jax.core.mpc.build_qp`) carry exactly these tightenings at the pre-impact instants where
the S2S model lives; between impacts nothing is claimed.  A placement error that the plant adds
after the law (``step_error``) is inside d for the invariance, but U ⊖ K E only tightens the
law's part of the step.

W is, per plane, either a box of symmetric half-widths w = (w_c, w_p, w_v) [m, m, m/s] (a box
measured from samples, ``w_lo``/``w_hi`` of coverage.csv, is enclosed by the symmetric box of
half-widths max(|lo|, |hi|)), or the symmetric convex hull conv(±s_j) of points s_j on
[c, p, v] (``mpc.w_shape = "hull"``, the points from a file, :func:`read_hull`): the smallest
convex symmetric set that holds every disturbance sample, with support h_W(d) = max_j |s_j·d|.
Either is in one of two frames:

* ``"heading"``: plane 1 sagittal, plane 2 lateral, the error rotated into the path heading
  (what the report and coverage.csv show when both planes share one gain);
* ``"world"``: plane 1 world x, plane 2 world y (the H-LIP plant's noise acts per world axis).

Because the loop starts on the H-LIP (e_0 = 0), the error after m steps lies in the reachable
set F_m = W ⊕ A_cl W ⊕ … ⊕ A_cl^{m−1} W (F_0 = {0}), which grows to the mRPI set F_∞.  The
tube uses F_m for the constraints of step m — exact, and it leaves the first steps from rest
untightened (a fixed F_∞ forces the nominal to start with the widest steps) — through two
numbers per plane i and step m,

    ec_i(m) = h_{F_m}(e_c) = Σ_{l<m} |(A_cl^l)ᵀ e_c| · w_i   [m]   (COM position error bound)
    eu_i(m) = h_{F_m}(K_i) = Σ_{l<m} |(A_cl^l)ᵀ K_i| · w_i   [m]   (stepping-law correction)

(support of a symmetric box: h_W(d) = |d|·w; of a hull, max_j |s_j·d| in place of |·|·w).  A
table holds m = 0..STEPS−2; its last row bounds every F_m and serves every later step: for a
box the support of the outer mRPI approximation (:func:`hlip_jax.core.sets.mrpi`), for a hull the
series summed until ‖A_clᴸ‖₂ ≤ 1e-12 plus a bound on its tail (:func:`hull_bounds`).  In the
heading frame the rows are rotated into the world by the heading of each planned step
(:func:`frame_weights`).
"""

from __future__ import annotations

import csv
import functools
import errno
import os
import stat
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from hlip_jax.core import invariant, sets

FRAMES = tuple(invariant.PLANES)    # "heading", "world": the frames of W and of the tube


#: rows of the per-step tube table (steps 0..STEPS−2 exact, then the mRPI bound)
STEPS = 48


class Tightening(NamedTuple):
    """Per-scenario tube data of the MPC (zeros: no tightening, E = {0})."""
    e_c: np.ndarray        # (STEPS, 2) ec per step and plane [m]
    e_u: np.ndarray        # (STEPS, 2) eu per step and plane [m]
    e_heading: np.ndarray  # 1.0: planes in the path-heading frame; 0.0: world x / y


NONE = Tightening(e_c=np.zeros((STEPS, 2)), e_u=np.zeros((STEPS, 2)), e_heading=np.float64(1.0))


def plane_bounds(A_cl, K, w, steps: int = STEPS) -> np.ndarray:
    """(steps, 2) [ec(m), eu(m)] of one plane for m = 0..steps−2 (support of F_m) and, in the
    last row, of the outer mRPI set of W = [−w, w].

    Args:
      A_cl: (3, 3) closed-loop S2S matrix A + B K on [c, p, v], Schur stable.
      K: (3,) stepping gain.
      w: (3,) half-widths of W, ≥ 0 [m, m, m/s].
    """
    A_cl, K, w = (np.asarray(a, np.float64) for a in (A_cl, K, w))
    out = np.zeros((steps, 2))
    if not np.any(w > 0):
        return out
    D = np.stack([np.eye(3)[0], K])               # directions e_c and K
    Dm = D                                        # rows (A_cl^{m−1})ᵀ d, from m = 1
    for m in range(1, steps - 1):
        out[m] = out[m - 1] + np.abs(Dm) @ w
        Dm = Dm @ A_cl
    E = sets.mrpi(A_cl, sets.Box(-w, w), min_halfwidth=1e-9)
    out[-1] = np.maximum(np.asarray(E.support(D), np.float64), out[-2])
    return out


def _tail_bound(D, radius: float, L: int, a: float, M: float) -> np.ndarray:
    """Upper bound of Σ_{l ≥ L} h_W((A_clˡ)ᵀ d) for the rows d of ``D``, W in the ball of
    ``radius``: with a = ‖A_clᴸ‖₂ < 1 and M = max_{i<L} ‖A_clⁱ‖₂, every ‖A_clˡ‖₂ ≤ M a^⌊l/L⌋,
    so the tail is at most radius ‖d‖ L M a / (1 − a)."""
    return radius * np.linalg.norm(D, axis=1) * L * M * a / (1.0 - a)


def hull_bounds(A_cl, K, points, steps: int = STEPS, a_max: float = 1e-12,
                l_max: int = 100000) -> np.ndarray:
    """:func:`plane_bounds` for W = conv(±points) (points (N, 3) on [c, p, v]): rows m =
    0..steps−2 the support of F_m in e_c and K, the last row an upper bound of F_∞'s: the
    series to the first L with ‖A_clᴸ‖₂ ≤ ``a_max``, plus :func:`_tail_bound`."""
    A_cl, K, S = (np.asarray(a, np.float64) for a in (A_cl, K, points))
    D = np.stack([np.eye(3)[0], K])
    h = lambda G: np.abs(S @ G.T).max(axis=0)
    out, total, G, L = np.zeros((steps, 2)), np.zeros(2), D.copy(), 0
    power, M = np.eye(3), 0.0                     # A_clᴸ and max_{i<L} ‖A_clⁱ‖₂
    a = 1.0
    while L < l_max and (L < steps - 2 or a > a_max):
        total = total + h(G)
        M = max(M, a)
        L += 1
        G, power = G @ A_cl, power @ A_cl
        a = np.linalg.norm(power, 2)
        if L <= steps - 2:
            out[L] = total
    if L >= l_max:
        raise ValueError("A + B K is not Schur stable on [c, p, v]: no bounded invariant set")
    out[-1] = total + _tail_bound(D, float(np.linalg.norm(S, axis=1).max()), L, a, M)
    return out


@functools.lru_cache(maxsize=1024)
def _cached(A_cl: tuple, K: tuple, w: tuple) -> np.ndarray:
    return plane_bounds(np.array(A_cl).reshape(3, 3), np.array(K), np.array(w))


def tightening(A, B, gain, w, frame: str, hull=None) -> Tightening:
    """The MPC's :class:`Tightening` for a W box ``w`` (2, 3) in ``frame`` (:data:`FRAMES`),
    or, given ``hull`` (two (N_i, 3) point arrays, planes 1 and 2), for W = conv(±points).

    Args:
      A, B: (3, 3), (3,) S2S model on [c, p, v]; gain: (2, 3) K per world plane.
    Raises ValueError when a plane's A + B K is not Schur stable (no bounded E; e.g. a gain
    without the c term leaves the COM position error unbounded) or when the heading frame is
    asked for with different gains in the two planes (the error's rotation into the heading
    commutes with A_cl only when both planes share it)."""
    if frame not in FRAMES:
        raise ValueError(f"frame: {frame!r} is not one of {FRAMES}")
    A, B, gain, w = (np.asarray(a, np.float64) for a in (A, B, gain, w))
    if frame == "heading" and not np.allclose(gain[0], gain[1]):
        raise ValueError("a W box in the heading frame needs the same stepping gain in both "
                         "planes (gain.lateral = 'same')")
    ec, eu = np.zeros((STEPS, 2)), np.zeros((STEPS, 2))
    for i in range(2):
        A_cl = A + np.outer(B, gain[i])
        if not sets.schur_stable(A_cl):
            raise ValueError("A + B K is not Schur stable on [c, p, v]: the COM position error "
                             "has no bounded invariant set (use gain.with_position = true)")
        if hull is None:
            b = _cached(tuple(A_cl.ravel()), tuple(gain[i]), tuple(w[i]))
        else:
            b = hull_bounds(A_cl, gain[i], hull[i])
        ec[:, i], eu[:, i] = b[:, 0], b[:, 1]
    return Tightening(e_c=ec, e_u=eu, e_heading=np.float64(frame == "heading"))


def check_limits(t: Tightening, length_min, length_max, width_min, width_max) -> None:
    """ValueError when U ⊖ K E is empty for some heading: the step rows shrink by the support
    of K E along and across the heading (≤ √(eu_1² + eu_2²) in the world frame)."""
    eu = t.e_u.max(axis=0)
    worst = (float(np.hypot(*eu)),) * 2 if t.e_heading == 0 else tuple(map(float, eu))
    for name, lo, hi, m in (("step_length", length_min, length_max, worst[0]),
                            ("step_width", width_min, width_max, worst[1])):
        if hi - lo < 2 * m:
            raise ValueError(f"mpc.{name}_min/max: [{lo:g}, {hi:g}] m leaves no room for the "
                             f"stepping law's correction K E (±{m:.3g} m): U ⊖ K E is empty; "
                             f"allowed: mpc.{name}_max - mpc.{name}_min >= {2 * m:.3g} m, or a "
                             "smaller W")


HULL_COLUMNS = ("plane", "c", "p", "v")


@functools.lru_cache(maxsize=64)
def _read_hull(path: str, stamp: tuple) -> tuple:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or tuple(c.strip() for c in rows[0]) != HULL_COLUMNS:
        raise ValueError(f"{path}: expected the header {','.join(HULL_COLUMNS)}")
    planes = ([], [])
    for k, r in enumerate(rows[1:], start=2):
        try:
            plane, *vals = (float(v) for v in r)
        except ValueError:
            raise ValueError(f"{path}, line {k}: expected four numbers") from None
        if plane not in (1.0, 2.0) or len(vals) != 3 or not np.all(np.isfinite(vals)):
            raise ValueError(f"{path}, line {k}: expected plane 1 or 2 and three finite numbers "
                             "c [m], p [m], v [m/s]")
        planes[int(plane) - 1].append(vals)
    if not (planes[0] and planes[1]):
        raise ValueError(f"{path}: every plane (1 and 2) needs at least one point")
    return tuple(np.array(p, np.float64) for p in planes)


#: the largest hull W file read [bytes]: a hull's vertices take a few kB; a device or a
#: runaway file is refused before it is read
HULL_FILE_MAX_BYTES = 10_000_000


def read_hull(path) -> tuple:
    """The points of a hull W from a CSV file with the columns plane (1 or 2), c [m], p [m],
    v [m/s] (what ``hlip-sweep whull`` writes), as two (N_i, 3) arrays.  ValueError naming the
    file and line when it is missing or malformed."""
    path = os.fspath(path)
    if "\0" in path:
        raise ValueError(f"{path!r}: holds a NUL character; allowed: the path of a CSV file")
    try:
        st = os.stat(path)
    except OSError as err:      # a name too long is no "not found"
        shown = path if len(path) <= 200 else f"{path[:200]}... ({len(path)} characters)"
        why = "file not found" if err.errno == errno.ENOENT else f"unusable ({err.strerror})"
        raise ValueError(f"{shown}: {why}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: not a regular file (a hull W file is a CSV file)")
    if st.st_size > HULL_FILE_MAX_BYTES:
        raise ValueError(f"{path}: {st.st_size} bytes; allowed: at most {HULL_FILE_MAX_BYTES} "
                         "(a hull W holds its vertices, a few hundred lines)")
    return _read_hull(path, (st.st_mtime_ns, st.st_size))


def symmetric_hull_vertices(samples) -> np.ndarray:
    """The vertices of conv(±samples) (N, 3) that lie in one half-space of each opposite pair
    (the hull is symmetric, so these and their negatives span it): the few points a hull W file
    needs to hold the support of every sample.  Samples spanning fewer than three dimensions
    are returned as they are (their support is the same)."""
    from scipy.spatial import ConvexHull, QhullError
    S = np.asarray(samples, np.float64)
    both = np.concatenate([S, -S])
    try:
        idx = ConvexHull(both).vertices
    except (QhullError, ValueError):
        return S
    V = both[idx]
    key = np.round(V, 12)
    keep = [i for i, v in enumerate(key)
            if not any(np.array_equal(-v, key[j]) for j in range(i))]
    return V[keep]


def frame_weights(dx, dy, heading, frame_heading):
    """|components| of the world direction (dx, dy) in the tightening's frame: rotated by
    −heading when ``frame_heading`` is 1 (sagittal, lateral), unrotated when 0 (world x, y).
    Support of the box E_c = [−ec_1, ec_1] × [−ec_2, ec_2] in that direction is
    Σ_i weight_i · ec_i.  Works elementwise on arrays (jax or numpy)."""
    phi = heading * frame_heading
    c, s = jnp.cos(phi), jnp.sin(phi)
    return jnp.abs(c * dx + s * dy), jnp.abs(-s * dx + c * dy)


class NoWError(ValueError):
    """coverage.csv holds no W for a group (no disturbance samples on its training side)."""


def w_from_coverage(rows, method: str = "box", groups=None):
    """The W box a tube needs, from the rows of a results directory's coverage.csv.

    Per plane, the symmetric half-widths w = max(|w_lo|, |w_hi|) [m, m, m/s] of every chosen
    group's W (``groups``: names; None = all), enclosing them all.  Returns (frame, w (2, 3),
    the groups used).  ValueError (naming what is allowed) when ``method`` has no rows, a group
    is unknown, the rows mix frames, a plane is missing, or W is on [p, v] (the tube needs the
    COM position: a gain with ``with_position``)."""
    rows = [r for r in rows if r["w_method"] == method and r["level"] == "run"]
    if not rows:
        raise ValueError(f"method {method!r}: no coverage.csv rows of it")
    known = sorted({str(r["group"]) for r in rows})
    chosen = known if groups is None else list(groups)
    unknown = [g for g in chosen if g not in known]
    if unknown:
        raise ValueError(f"group {unknown[0]!r} is not in coverage.csv; allowed: {', '.join(known)}")
    rows = [r for r in rows if str(r["group"]) in chosen]
    frames = {f for f, names in invariant.PLANES.items() for r in rows if r["plane"] in names}
    if len(frames) != 1:
        raise ValueError(f"the chosen groups' planes are in frames {sorted(frames)}; choose groups "
                         "of one frame (--group)")
    frame = frames.pop()
    w = np.full((2, 3), -np.inf)
    for r in rows:
        if not isinstance(r["state"], str):     # no W at all (NaN cells): the row's note says why
            raise NoWError(f"group {r['group']!r} has no W ({r.get('note') or 'no samples'})")
        if r["state"] != "[c, p, v]":
            raise ValueError(f"group {r['group']!r}: W is on {r['state']}; the tube needs "
                             "[c, p, v] (gain.with_position = true)")
        lo, hi = (np.array(str(r[k]).split(), float) for k in ("w_lo", "w_hi"))
        if lo.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(f"group {r['group']!r}, plane {r['plane']}: no finite W (too few samples)")
        i = invariant.PLANES[frame].index(r["plane"])
        w[i] = np.maximum(w[i], np.maximum(np.abs(lo), np.abs(hi)))
    if not np.all(np.isfinite(w)):
        raise ValueError(f"a plane of {invariant.PLANES[frame]} has no rows")
    return frame, w, chosen
