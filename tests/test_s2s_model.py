"""The identified S2S model (hlip_jax.core.s2s_model): the fit against a map of known coefficients,
the lift to [c, p, v] against the H-LIP's closed form, the file's checks, and
``s2s.model = "identified"`` end to end on the exact H-LIP plant (its own map identified from
its own runs gives back the H-LIP's runs), with ``hlip-sweep identify``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hlip_jax.simulation import arrays, config as C
from hlip_jax.presentation import cli
from hlip_jax.core import hlip, s2s_model
from hlip_jax.sweepio import runner, store, sweep

A2 = np.array([[1.3, 0.2], [2.4, 1.2]])
B2 = np.array([-1.25, -2.0])
OFFSET = np.array([[[-0.01, 0.004], [0.002, -0.006]], [[0.003, 0.012], [-0.002, -0.011]]])


def _log(S=6, K=30, seed=0):
    """A step log whose robot obeys [p, v]⁺ = A2 [p, v] + B2 u + OFFSET[plane, stance] exactly,
    in the heading frame (heading 0), with random steps u."""
    rng = np.random.default_rng(seed)
    x = np.zeros((S, K, 2, 3))
    u = rng.uniform(-0.3, 0.3, (S, K, 2))
    stance = np.tile(np.arange(K) % 2, (S, 1))
    x[:, 0, :, 1:] = rng.uniform(-0.1, 0.1, (S, 2, 2))
    for k in range(K - 1):
        for j in range(2):
            x[:, k + 1, j, 1:] = (x[:, k, j, 1:] @ A2.T + u[:, k, j, None] * B2
                                  + OFFSET[j, stance[:, k]])
    return {"valid": np.ones((S, K), bool), "x_robot": x, "u_robot": u,
            "ref_heading": np.zeros((S, K)), "stance": stance}


def test_fit_recovers_a_known_map_and_its_constants():
    """Noise-free data of a known map: Â, B̂ and ĉ back to 1e-9; on other data the residuals
    are round-off (1e-12 of the states' size)."""
    log = _log()
    m = s2s_model.fit(log, range(6), (0.8, 0.3, 0.1))
    assert m.rank == 7 and m.n == 6 * (30 - 1 - 4)
    np.testing.assert_allclose(m.A, A2, atol=1e-9)
    np.testing.assert_allclose(m.B, B2, atol=1e-9)
    np.testing.assert_allclose(m.offset, OFFSET, atol=1e-9)
    other = _log(seed=1)
    scale = np.abs(other["x_robot"]).max()
    assert np.abs(s2s_model.residuals(other, range(6), m)).max() < 1e-12 * scale
    with pytest.raises(ValueError, match="at least 7"):
        s2s_model.fit(_log(S=1, K=8), [0], (0.8, 0.3, 0.1))


def test_lift_of_the_hlip_map_is_the_hlip_three_state_map():
    """lifted(A2, B2 of the H-LIP) = hlip.s2s_matrices(with_position=True) to 1e-12."""
    A3, B3 = (np.asarray(a, np.float64) for a in hlip.s2s_matrices(0.864, 0.175, 0.03))
    m = s2s_model.Model(A3[1:, 1:], B3[1:], np.zeros((2, 2, 2)), np.zeros(2), 10, 7,
                        (0.864, 0.175, 0.03))
    L3, M3 = s2s_model.lifted(m)
    np.testing.assert_allclose(L3, A3, atol=1e-6)     # s2s_matrices runs in the suite's dtype
    np.testing.assert_allclose(M3, B3, atol=1e-6)


def test_model_file_round_trip_and_damaged_files(tmp_path):
    m = s2s_model.fit(_log(), range(6), (0.8, 0.3, 0.1))
    back = s2s_model.read(s2s_model.write(tmp_path / "m.npz", m))
    for a, b in zip(m, back):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a model file"):
        s2s_model.read(bad)
    with pytest.raises(ValueError, match="not a readable file"):
        s2s_model.read(tmp_path / "missing.npz")
    np.savez(tmp_path / "shape.npz", **dict(m._asdict(), A=np.zeros(3)))
    with pytest.raises(ValueError, match=r"A: shape \(3,\); allowed: an array of shape \(2, 2\)"):
        s2s_model.read(tmp_path / "shape.npz")
    np.savez(tmp_path / "nan.npz", **dict(m._asdict(), B=np.array([np.nan, 1.0])))
    with pytest.raises(ValueError, match="B: non-finite"):
        s2s_model.read(tmp_path / "nan.npz")


SWEEP = """
name = "ident"
[base]
plant = "hlip"
duration = 12.0
[base.hlip]
z0 = 0.8
t_ssp = 0.3
t_dsp = 0.1
[base.disturbance]
noise_p = 0.005
noise_v = 0.02
step_error = 0.05
[[paths]]
shape = "circle"
radius = 1.5
[grid.product]
seed = [1, 2, 3, 4, 5, 6, 7, 8]
"""


@pytest.fixture(scope="module")
def hlip_runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("ident")
    out = d / "r"
    runner.run_sweep(sweep.parse_sweep(SWEEP), out, progress=False)
    return d, out


def test_identify_writes_the_hlip_plants_own_map(hlip_runs, capsys):
    """The exact H-LIP plant with uniform S2S noise and step-placement errors (the excitation):
    ``hlip-sweep identify`` on seeds 1-7 (about 180 pairs) gives back the H-LIP's Â, B̂ within
    0.05 (noise-limited), the held-out seed is reported, and the file is refused a second time
    (nothing is overwritten)."""
    d, out = hlip_runs
    f = d / "model.npz"
    assert cli.main(["identify", str(out), "-o", str(f), "--scenarios", "seed=[1-7]$",
                     "--test", "seed=8$"]) == 0
    text = capsys.readouterr().out
    assert "held out: 1 scenarios" in text and "s2s.model" in text
    m = s2s_model.read(f)
    A3, B3 = (np.asarray(a, np.float64) for a in hlip.s2s_matrices(0.8, 0.3, 0.1))
    np.testing.assert_allclose(m.A, A3[1:, 1:], atol=0.05)
    np.testing.assert_allclose(m.B, B3[1:], atol=0.05)
    assert m.cadence == (0.8, 0.3, 0.1)
    assert cli.main(["identify", str(out), "-o", str(f)]) == 2
    assert "nothing is overwritten" in capsys.readouterr().err


def test_identified_hlip_map_reproduces_the_hlip_runs(hlip_runs, tmp_path):
    """s2s.model = "identified" with a file holding the H-LIP's own map: the MPC plans with the
    same (A, B), the gain (Ackermann on the map) equals the closed form, so the runs match the
    H-LIP model's (1e-6 m on the robot's states, float64)."""
    _, out = hlip_runs
    A3, B3 = (np.asarray(a, np.float64) for a in hlip.s2s_matrices(0.8, 0.3, 0.1))
    f = s2s_model.write(tmp_path / "hlip.npz", s2s_model.Model(
        A3[1:, 1:], B3[1:], np.zeros((2, 2, 2)), np.zeros(2), 100, 7, (0.8, 0.3, 0.1)))
    text = SWEEP.replace("[base.disturbance]", f'[base.s2s]\nmodel = "identified"\n'
                         f'file = "{f}"\n[base.disturbance]')
    out2 = tmp_path / "r2"
    runner.run_sweep(sweep.parse_sweep(text), out2, progress=False)
    a, b = store.load_log(out), store.load_log(out2)
    np.testing.assert_allclose(b["A"], a["A"], atol=1e-12)
    np.testing.assert_allclose(b["K_gain"], a["K_gain"], atol=1e-9)
    np.testing.assert_allclose(b["x_robot"], a["x_robot"], atol=1e-6)


def test_sweep_checks_the_model_file(tmp_path):
    """s2s.file only with the identified model; a model of another cadence is named; a
    relative path is read from the sweep file's directory."""
    m = s2s_model.Model(A2, B2, OFFSET, np.zeros(2), 10, 7, (0.8, 0.3, 0.1))
    s2s_model.write(tmp_path / "m.npz", m)
    head = SWEEP.replace("[base.disturbance]", "[base.s2s]\n{}\n[base.disturbance]")
    with pytest.raises(sweep.SweepError, match="s2s.file: .* is read with s2s.model = "
                                               "'identified' only"):
        sweep.parse_sweep(head.format(f'file = "{tmp_path / "m.npz"}"'))
    wrong = s2s_model.write(tmp_path / "w.npz", m._replace(cadence=(0.8, 0.35, 0.1)))
    with pytest.raises(sweep.SweepError, match=r"s2s.file: fitted at \(z0, t_ssp, t_dsp\) = "
                                               r"\(0.8, 0.35, 0.1\)"):
        sweep.parse_sweep(head.format(f'model = "identified"\nfile = "{wrong}"'))
    p = tmp_path / "s.toml"
    p.write_text(head.format('model = "identified"\nfile = "m.npz"'))
    assert sweep.load_sweep(p).scenarios[0].s2s.file == str(tmp_path / "m.npz")


def test_gain_on_an_identified_map_is_designed_on_it(tmp_path):
    """LQR and deadbeat gains on an identified map: A + BK's eigenvalues are those the design
    promises on that map (deadbeat: all 0 within 1e-2, since a nilpotent matrix's eigenvalues
    move as the n-th root of round-off; LQR: inside the unit circle)."""
    f = s2s_model.write(tmp_path / "m.npz",
                        s2s_model.Model(A2, B2, OFFSET, np.zeros(2), 10, 7, (0.8, 0.3, 0.1)))
    base = C.ScenarioConfig(s2s=C.S2SConfig(model="identified", file=str(f)))
    A3, B3 = arrays.s2s_of(base)
    for g in (C.GainConfig(type="deadbeat"), C.GainConfig(type="lqr"),
              C.GainConfig(type="deadbeat", with_position=False)):
        K = arrays.stepping_gain(dataclasses.replace(base, gain=g))[0]
        n = 3 if g.with_position else 2
        A, B, k = A3[3 - n:, 3 - n:], B3[3 - n:], K[3 - n:]
        eig = np.abs(np.linalg.eigvals(A + np.outer(B, k)))
        assert (eig.max() < 1e-2 if g.type == "deadbeat" else eig.max() < 1.0), (g, eig)
