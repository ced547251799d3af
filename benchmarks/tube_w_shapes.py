"""How much a W that is not a box would shrink the Cassie tube: the box of a results
directory's S2S disturbance samples against their symmetric convex hull.

For each analysis plane the non-push disturbance samples d of every run (the error system
e⁺ = A_cl e + d of :mod:`hlip_jax.core.invariant`, in the frame coverage.csv uses) are pooled, and
the outer mRPI set E of e⁺ = A_cl e + d, d ∈ W, is measured along the two directions the tube
tightens by (:mod:`hlip_jax.core.robust`): the COM position e_c (the keep-out margin) and the
stepping gain K (U ⊖ K E).  Its support is the series

    h_E(g) = Σ_{l ≥ 0} h_W((A_clˡ)ᵀ g),

bounded from above as the tube bounds it (:func:`hlip_jax.core.robust.hull_bounds`, its last row),
for the symmetric box of half-widths w_j = max |d_j| (what ``hlip-sweep wbox`` gives the tube;
the hull of its corners, h_W(g) = Σ_j |g_j| w_j) and for the symmetric hull conv(±d_s),
h_W(g) = max_s |d_s · g|: the smallest convex symmetric set that holds every sample, so no
convex symmetric W model of these samples can give less.

    python benchmarks/tube_w_shapes.py results/tube_w [results/tube_reach --only "tube"]

``--only`` keeps the scenarios whose name contains the text.  Runs must share one A_cl per
plane (one gain and one H-LIP); the pushes' steps are left out, as the tube does not bound them.
"""

import argparse

import numpy as np

from hlip_jax.simulation import arrays
from hlip_jax.core import robust
from hlip_jax.sweepio import store, sweep


def pooled(out_dir: str, only: str | None):
    """(A_cl (2, 3, 3), samples per plane [(N, 3), (N, 3)], K (2, 3), runs) of a results
    directory's scenarios whose name contains ``only`` (all when None)."""
    configs = [sweep.config_from_dict(c) for c in store.read_manifest(out_dir)["configs"]]
    chosen = [i for i, c in enumerate(configs) if only is None or only in c.name]
    if not chosen:
        raise SystemExit("no runs selected")
    models = set()
    for i in chosen:
        A, B = (np.asarray(a, np.float64) for a in arrays._cached_s2s(configs[i].hlip))
        K = arrays.stepping_gain(configs[i])
        models.add(np.round(np.concatenate([A.ravel(), B, K.ravel()]), 12).tobytes())
    if len(models) > 1:
        raise SystemExit("the runs have different S2S models or gains; choose one (--only)")
    _, samples, runs = store.disturbance_samples(out_dir, chosen)
    A_cl = np.stack([A + np.outer(B, K[i]) for i in range(2)])
    return A_cl, samples, K, runs


def shape_bounds(A_cl, K, samples) -> dict:
    """{W: (E along c [m], K E [m])} of the symmetric box and the symmetric hull of
    ``samples`` (N, 3) for one plane (A_cl (3, 3), K (3,))."""
    w = np.abs(samples).max(axis=0)
    corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) * w
    return {name: tuple(robust.hull_bounds(A_cl, K, points)[-1])
            for name, points in (("box", corners), ("symmetric hull", samples))}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dirs", nargs="+", help="results directories")
    p.add_argument("--only", default=None, help="keep scenarios whose name contains this text")
    a = p.parse_args()
    print("| results | plane | runs | samples | W | E along c [m] | K E [m] |")
    print("|---|---|---:|---:|---|---:|---:|")
    for d in a.dirs:
        A_cl, samples, K, runs = pooled(d, a.only)
        for i, S in enumerate(samples):
            for name, (ec, eu) in shape_bounds(A_cl[i], K[i], S).items():
                print(f"| {d} | {i + 1} | {runs} | {len(S)} | {name} | {ec:.3f} | {eu:.3f} |")


if __name__ == "__main__":
    main()
