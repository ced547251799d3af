"""Figures of invariant sets with error samples (matplotlib, Agg): E as transparent faces in
3-D or as a filled projection in 2-D, samples inside green and outside red."""

from __future__ import annotations

import numpy as np

from hlip_jax.core.sets import MRPI, Scaled, Zonotope, as_float64, default_directions, vertices


STATE_LABELS = {3: ("c [m]", "p [m]", "v [m/s]"), 2: ("p [m]", "v [m/s]")}
#: directions whose support points outline a 3-D zonotope (a Fibonacci sphere and the axes)
OUTLINE_DIRECTIONS = 2048


def _zonotope_parts(E):
    """(c, G, k) when E is the zonotope c + k Gᵀβ, |β| ≤ 1 (a zonotope, an MRPI bracket's outer
    zonotope, or one of those scaled about its centre), else None."""
    if isinstance(E, Scaled):
        inner = _zonotope_parts(E.base)
        return None if inner is None else (inner[0], inner[1], inner[2] * float(E.s))
    if isinstance(E, MRPI):
        E = E.outer
    if isinstance(E, Zonotope):
        return as_float64(E.center), as_float64(E.generators).reshape(-1, len(E.center)), 1.0
    return None


def _support_points(c, G, k, D) -> np.ndarray:
    """argmax_{x ∈ E} dᵀx for each row d of D: c + k Σ_j sign(dᵀg_j) g_j (a vertex of E
    where d is inside its normal cone)."""
    return c + k * (np.sign(D @ G.T) @ G)


def projected_outline(E, dims) -> np.ndarray:
    """Points whose convex hull is the projection of E onto the coordinates ``dims`` (2): for
    a zonotope exactly its vertices, the support points of the projected generators g'_j at
    directions strictly between consecutive generator normals (no facet enumeration of the
    full-dimensional set); else the projected vertices of E."""
    parts = _zonotope_parts(E)
    if parts is None:
        return vertices(E)[:, list(dims)]
    c, G, k = parts
    g = G[:, list(dims)]
    gn = np.linalg.norm(g, axis=1)
    g = g[gn > 1e-14 * max(gn.max(initial=0.0), 1e-300)]     # (a zonotope may have none)
    if len(g) == 0:
        return c[list(dims)][None]
    th = np.sort(np.mod(np.arctan2(g[:, 1], g[:, 0])[:, None] + np.array([0.5, 1.5]) * np.pi,
                        2 * np.pi).ravel())
    mid = 0.5 * (th + np.r_[th[1:], th[0] + 2 * np.pi])
    D = np.stack([np.cos(mid), np.sin(mid)], axis=1)
    return _support_points(c[list(dims)], g, k, D)


def outline(E) -> np.ndarray:
    """Points whose convex hull is drawn for E: for a 3-D zonotope its support points in
    :data:`OUTLINE_DIRECTIONS` directions (vertices of E, so the drawn hull lies inside E and
    touches it in each of those directions; a zonotope of hundreds of generators has tens of
    thousands of vertices, which Qhull would take seconds to find and matplotlib to draw), in
    2-D the exact vertices (:func:`projected_outline`), else :func:`vertices`."""
    parts = _zonotope_parts(E)
    if parts is None or E.dim != 3:
        return projected_outline(E, (0, 1)) if E.dim == 2 else vertices(E)
    c, G, k = parts
    return _support_points(c, G, k, default_directions(3, OUTLINE_DIRECTIONS))


def _split_inside(E, samples, tol=1e-9):
    P = as_float64(samples).reshape(-1, E.dim)
    inside = np.asarray(E.contains(P, tol))
    return P, inside


def _hull(V):
    """scipy's ConvexHull of the points V, with joggled input where Qhull's exact merging fails
    on nearly coplanar points (a picture, so a 1e-11 relative joggle is invisible)."""
    from scipy.spatial import ConvexHull, QhullError
    try:
        return ConvexHull(V)
    except QhullError:
        return ConvexHull(V, qhull_options="QJ")


def _polygon(V) -> np.ndarray:
    """The corners of the convex hull of the 2-D points V in order, or V itself where there
    are fewer than three (a set whose projection is one point: Qhull needs a simplex)."""
    return V[_hull(V).vertices] if len(V) >= 3 else V


def plot_set_3d(E, samples=None, ax=None, face_color="tab:blue", inside_color="tab:green",
                outside_color="tab:red", alpha: float = 0.15, labels=None):
    """E (3-D) as transparent polytope faces with samples (k, 3): inside / outside coloured."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if ax is None:
        ax = plt.figure().add_subplot(projection="3d")
    V = outline(E)
    hull = _hull(V)
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

    if ax is None:
        ax = plt.figure().add_subplot()
    V = projected_outline(E, dims)
    poly = _polygon(V)
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
