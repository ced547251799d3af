"""The condensation's two solves for the constraint forces (``impl.condense``): the null
space of G = J M⁻¹ Jᵀ is the plantar four-bars' plane normals, the deflated solve is the
minimum-norm solution (against numpy's SVD pseudo-inverse), both solves are the same model in
float64, and only the deflated one keeps float32 close to float64."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from hlip_jax.plants.cassie import control, dynamics, model

CONTACT_SETS = [(1, 1, 1, 1), (1, 1, 0, 0), (0, 0, 1, 1), (1, 0, 0, 0), (0, 0, 0, 0)]


@pytest.fixture(scope="module")
def cassie():
    return control.load()


@pytest.fixture(scope="module")
def terms_fn(cassie):
    return jax.jit(lambda d: model.robot_terms(cassie, d))


def _closed_state_terms(cassie, terms_fn, seed):
    """Terms at the stand keyframe (chains closed) with random joint velocities (J̇q̇ ≠ 0)."""
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    d.qvel[:] = np.random.default_rng(seed).uniform(-0.5, 0.5, m.nv)
    mujoco.mj_forward(m, d)
    return terms_fn(mjx.put_data(m, d))


def _G(terms, J, active):
    return np.asarray(J) @ np.linalg.solve(np.asarray(terms.M), np.asarray(J).T) \
        + np.diag(1.0 - np.asarray(active))


@pytest.mark.parametrize("contact", CONTACT_SETS)
def test_plantar_normals_span_the_null_space_of_G(cassie, terms_fn, contact, float64):
    """N is orthonormal, Jᵀ N = 0 and G N = 0; G's two smallest eigenvalues (numpy) are below
    1e-12 of its largest and the third above 1e-5 of it, so the null space is N's alone.  Jᵀ N
    and G N are held to 1e-8 of |J| and |G| (the keyframe closes the chains to ~1e-9 m)."""
    terms = _closed_state_terms(cassie, terms_fn, 0)
    J, _, active, _ = dynamics.constraint_stack(terms, jnp.array(contact, float),
                                                dynamics.spring_dofs(cassie))
    N = np.asarray(dynamics.plantar_normals(J))
    J = np.asarray(J)
    np.testing.assert_allclose(N.T @ N, np.eye(2), atol=1e-12)
    assert np.abs(J.T @ N).max() < 1e-8 * np.abs(J).max()
    G = _G(terms, J, active)
    assert np.abs(G @ N).max() < 1e-8 * np.abs(G).max()
    s = np.linalg.eigvalsh(G)
    assert abs(s[0]) < 1e-12 * s[-1] and abs(s[1]) < 1e-12 * s[-1] and s[2] > 1e-5 * s[-1]


@pytest.mark.parametrize("contact", CONTACT_SETS)
def test_deflated_forces_are_the_minimum_norm_solution(cassie, terms_fn, contact, float64):
    """min_norm_forces = G⁺ r against numpy's SVD pseudo-inverse (cut 1e-10 of the largest
    singular value), within 1e-7 of |λ|: the chains' ~1e-9 closure tilts the null vectors by
    that much and the two routes drop slightly different lines."""
    terms = _closed_state_terms(cassie, terms_fn, 1)
    J, jd, active, _ = dynamics.constraint_stack(terms, jnp.array(contact, float),
                                                 dynamics.spring_dofs(cassie))
    G = _G(terms, J, active)
    r = np.random.default_rng(2).normal(size=(G.shape[0], 3)) * 100.0
    r[:, 0] -= np.asarray(jd)
    lam = np.asarray(dynamics.min_norm_forces(jnp.asarray(G), dynamics.plantar_normals(J),
                                              jnp.asarray(r)))
    ref = np.linalg.pinv(G, rcond=1e-10) @ r
    np.testing.assert_allclose(lam, ref, atol=1e-7 * np.abs(ref).max())


def _condensed(cassie, terms, contact, solve, dtype):
    cast = lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a
    c = dynamics.condense(jax.tree.map(cast, terms), np.asarray(cassie.actuation, dtype),
                          jnp.array(contact, dtype), dynamics.spring_dofs(cassie), solve=solve)
    tau = np.random.default_rng(1).uniform(-1, 1, cassie.index.nu) * cassie.ctrl_range[:, 1]
    return {a: np.asarray(getattr(c, a), float) @ tau + np.asarray(getattr(c, b), float)
            for a, b in (("qdd_tau", "qdd0"), ("lam_tau", "lam0"))}


@pytest.mark.parametrize("contact", CONTACT_SETS)
def test_both_solves_are_one_model_in_float64(cassie, terms_fn, contact, float64):
    """In float64 the eigen cut drops G's null eigenvalues (round-off of ~1e-16 of the
    largest), so both solves compute G⁺ r: q̈ and λ for a torque inside the motor limits agree
    within 1e-7 of their largest entries (the route difference of the test above)."""
    terms = _closed_state_terms(cassie, terms_fn, 2)
    eig, dfl = (_condensed(cassie, terms, contact, s, jnp.float64) for s in dynamics.SOLVES)
    for k in eig:
        np.testing.assert_allclose(dfl[k], eig[k], atol=1e-7 * np.abs(eig[k]).max(), err_msg=k)


@pytest.mark.parametrize("contact", CONTACT_SETS)
def test_deflated_solve_keeps_float32_close_to_float64(cassie, terms_fn, contact, float64):
    """The deflated float32 condensation (what a sweep with it runs) against float64 at the
    same state: q̈ and λ within 1e-4 of their largest entries (measured ≤ 3.2e-5: float32
    round-off through one Cholesky factorisation of the deflated, well-conditioned matrix).
    How far the eigen solve's float32 λ is off depends on the processor's round-off (5-100
    times the largest true force on one machine, 1e-4 to 2e-3 of it on another), so it is not
    asserted."""
    terms = _closed_state_terms(cassie, terms_fn, 3)
    ref = _condensed(cassie, terms, contact, "eigen", jnp.float64)
    f32 = _condensed(cassie, terms, contact, "deflated", jnp.float32)
    for k in ref:
        np.testing.assert_allclose(f32[k], ref[k], atol=1e-4 * np.abs(ref[k]).max(), err_msg=k)


def test_unknown_solve_is_refused(cassie, terms_fn):
    terms = _closed_state_terms(cassie, terms_fn, 0)
    with pytest.raises(ValueError, match="solve: 'svd'; allowed"):
        dynamics.condense(terms, cassie.actuation, jnp.ones(4), solve="svd")


def test_the_setting_reaches_the_tick():
    from hlip_jax.simulation.config import ImplConfig, ScenarioConfig
    from hlip_jax.plants.cassie import plant
    for solve in dynamics.SOLVES:
        cfg = ScenarioConfig(plant="cassie", impl=ImplConfig(condense=solve))
        assert plant.settings(cfg).condense == solve
