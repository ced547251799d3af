"""Per-tick diagnostics of one Cassie scenario of a results directory (``hlip-sweep ticks``).

The sweep keeps one record per walking step; explaining a fall needs the 1 kHz tick: output
errors, torques, contact set and forces, CLF-QP status, phase.  :func:`replay` re-simulates the
chosen scenario from the configs in the directory's manifest with the plant's tick log
(:class:`hlip_jax.plants.cassie.tick.TickLog`): by default within the chunk it ran in (the
same scenarios, padding, device split and array sizes, so the sweep's own run:
:func:`compare` checks the replay's step log against the stored one, bit for bit), or alone
(a batch of one: less memory, but float32 rounding changes with the batch, and a run at the
margin can then walk where its chunk fell).  It writes ``ticks/<index>.npz`` (the ticks that
ran, idle ones after each touchdown dropped, with the plant time ``time`` [s], the step index
``step`` and the measured output accelerations ``ydd_meas``), ``ticks/<index>.png`` and
``ticks/<index>.json`` (how it was replayed and whether that is the stored run), which the
report shows (``hlip-sweep run --ticks REGEX`` replays the chosen scenarios after the sweep);
:func:`runs` replays without writing anything (:mod:`hlip_jax.presentation.render` draws the robot from
the log's joint positions ``qpos``).  The chunk's device split is this machine's: on another
device count (the manifest names the sweep's devices) the replay may differ, and
:func:`compare` says so.

Model mismatch: every tick logs the output accelerations the CLF-QP's model predicts for the
torques it applied (``ydd_model``: rigid leaf springs, the tick's contact set) and the output
velocities ẏ; the measured acceleration over tick i is the forward difference
(ẏ_{i+1} − ẏ_i) / Δt (:func:`measured_accel`).  :func:`mismatch` averages both per phase for
the COM height: where they part, the robot does not move as the controller's model says, and
the output's PD feedback has to absorb the difference.
"""

from __future__ import annotations

import json
import pathlib
from typing import NamedTuple

import numpy as np

from hlip_jax import plants
from hlip_jax.core import steplog

#: output rows of hlip_jax.plants.cassie.outputs grouped for the figure
GROUPS = {"pelvis orientation [rad]": slice(0, 3), "COM height [m]": slice(3, 4),
          "foot position [m]": slice(6, 12), "sole slope [m]": slice(12, 14),
          "foot yaw [rad]": slice(14, 16)}


def flatten(ticks: dict, step_log: dict, plant: str) -> dict:
    """Tick arrays (K, n, ...) of plant ``plant`` → the ticks that ran (phase < done) in time
    order, with ``time`` (plant clock [s], the plant's control tick apart) and ``step``
    (walking step index)."""
    parts = plants.tools(plant)
    dt = parts.CONTROL_DT
    run = (np.asarray(ticks["phase"]) != parts.PHASE_DONE) & np.asarray(step_log["valid"])[:, None]
    K, n = run.shape
    t0 = np.asarray(step_log["t_plant"], np.float64)[:, None] + dt * np.arange(n)[None, :]
    out = {k: np.asarray(v)[run] for k, v in ticks.items()}
    out["time"] = t0[run]
    out["step"] = np.broadcast_to(np.arange(K)[:, None], (K, n))[run]
    return out


def measured_accel(flat: dict) -> np.ndarray:
    """Measured output accelerations (n, 16): the forward difference of ``ydot`` over the
    plant clock, (ẏ_{i+1} − ẏ_i) / (t_{i+1} − t_i), i.e. the mean acceleration over tick i
    (the tick that ``ydd_model[i]`` predicts); NaN at the last tick and where the next
    logged tick is not the next millisecond (a fall ends the log)."""
    yd = np.asarray(flat["ydot"], np.float64)
    t = np.asarray(flat["time"], np.float64)
    out = np.full(yd.shape, np.nan)
    dt = np.diff(t)
    ok = dt < 1.5 * np.median(dt) if dt.size else dt.astype(bool)
    out[:-1][ok] = (np.diff(yd, axis=0)[ok]) / dt[ok, None]
    return out


def mismatch(flat: dict, plant: str, row: int = 3) -> dict:
    """Per phase ("dsp", "ssp"): (mean measured, mean model-predicted) acceleration of output
    ``row`` (default the COM height) over the ticks of that phase [m/s² or rad/s²] of plant
    ``plant``'s tick log."""
    parts = plants.tools(plant)
    meas = flat["ydd_meas"][:, row]
    model = np.asarray(flat["ydd_model"])[:, row]
    out = {}
    for name, ph in (("dsp", parts.PHASE_DSP), ("ssp", parts.PHASE_SSP)):
        on = (np.asarray(flat["phase"]) == ph) & np.isfinite(meas)
        out[name] = (float(meas[on].mean()), float(model[on].mean())) if on.any() else (np.nan, np.nan)
    return out


def _smooth(x: np.ndarray, n: int = 10) -> np.ndarray:
    """Moving average over n ticks (NaN-aware: NaN ticks count as absent)."""
    ok = np.isfinite(x)
    k = np.ones(n)
    num = np.convolve(np.where(ok, x, 0.0), k, "same")
    den = np.convolve(ok.astype(float), k, "same")
    return np.where(den > 0, num / np.maximum(den, 1), np.nan)


def figure(flat: dict, title: str, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = flat["time"]
    fig, ax = plt.subplots(6, 1, figsize=(9, 13), sharex=True)
    ax[0].plot(t, flat["com"][:, 2], label="COM z")
    ax[0].plot(t, flat["pelvis"][:, 2], label="pelvis z")
    ax[0].set_ylabel("[m]")
    ax[0].legend(loc="upper right")
    for name, rows in GROUPS.items():
        ax[1].plot(t, np.linalg.norm(flat["y_err"][:, rows], axis=1), label=name)
    ax[1].set_yscale("symlog", linthresh=1e-3)
    ax[1].set_ylabel("|output error|")
    ax[1].legend(loc="upper right", fontsize=7)
    ax[2].plot(t, flat["tau"], lw=0.7)
    ax[2].set_ylabel("motor torque [N m]")
    ax[3].plot(t, flat["grf"][:, :, 2], lw=0.7)
    ax[3].set_ylabel("normal force per site [N]")
    ax[4].plot(t, flat["phase"], label="phase (0 DSP, 1 SSP)")
    ax[4].plot(t, flat["status"], ".", ms=2, label="CLF-QP status")
    ax[4].plot(t, flat["contact"].sum(axis=1), label="sites in contact")
    ax[4].legend(loc="upper right", fontsize=7)
    ax[5].plot(t, _smooth(flat["ydd_meas"][:, 3]), label="measured")
    ax[5].plot(t, _smooth(np.asarray(flat["ydd_model"])[:, 3]), label="CLF-QP model")
    ax[5].set_ylabel("COM height accel.\n[m/s², 10 ms mean]")
    ax[5].legend(loc="upper right", fontsize=7)
    ax[5].set_xlabel("plant time [s]")
    ax[0].set_title(title)
    fig.tight_layout()
    from hlip_jax.sweepio import store
    store.save_figure_atomic(fig, path, 100)
    plt.close(fig)


class Agreement(NamedTuple):
    """How a replay's step log compares with the one the sweep stored (:func:`compare`)."""
    identical: bool      # every step's robot state, validity, status and fall step equal bit for bit
    first_step: int      # first step whose robot state or validity differs (−1: none)
    largest: float       # largest |Δ| of the robot state [m, m, m/s] over the steps both ran


class Replay(NamedTuple):
    npz: pathlib.Path          # the tick log (:func:`flatten`, with ``ydd_meas``)
    png: pathlib.Path          # its figure (:func:`figure`)
    within: str                # "chunk": the sweep's own batch; "alone": a batch of one
    agreement: Agreement       # the replay's step log against the stored one


def compare(stored: dict, replayed: dict) -> Agreement:
    """``stored``: one scenario's step log as the sweep keeps it (arrays (K, ...)); ``replayed``:
    the replay's (K', ...).  Compares the robot state x_R at SSP⁻ (NaN where a step did not
    run) step by step over the shorter K, and the outcome."""
    K = min(len(stored["valid"]), len(replayed["valid"]))
    xs = np.asarray(stored["x_robot"][:K], np.float64)
    xr = np.asarray(replayed["x_robot"][:K], np.float64)
    vs, vr = np.asarray(stored["valid"][:K], bool), np.asarray(replayed["valid"][:K], bool)
    both = vs & vr
    diff = np.where(both[:, None, None], np.abs(xs - xr), 0.0)
    bad = (diff.reshape(K, -1).max(axis=1) > 0) | (vs != vr)
    first = int(np.flatnonzero(bad)[0]) if bad.any() else -1
    same_end = (int(stored["status"]) == int(replayed["status"])
                and int(stored["fail_step"]) == int(replayed["fail_step"]))
    return Agreement(identical=first < 0 and same_end, first_step=first,
                     largest=float(diff.max(initial=0.0)))


def verdict(a: Agreement) -> str:
    """:func:`compare`'s result in words."""
    if a.identical:
        return "the stored run, bit for bit"
    return (f"differs from the stored run from step {a.first_step} on "
            f"(largest robot-state difference {a.largest:.3g})")


def stored_logs(out_dir, indices) -> dict:
    """{index: that scenario's stored step log (arrays (K, ...))}, the chunks read once."""
    from hlip_jax.sweepio import store
    log = store.load_log(out_dir, indices)
    return {int(i): {k: v[j] for k, v in log.items()} for j, i in enumerate(log["index"])}


def _write(out_dir, index: int, cfg, step_log: dict, ticks, within: str,
           stored: dict) -> Replay:
    """Write scenario ``index``'s (config ``cfg``) tick log, its figure and ``ticks/<index>.json`` (the
    scenario's name, how it was replayed and :func:`compare`'s verdict on the replay against
    ``stored``, the sweep's step log of it) into ``out_dir``."""
    from hlip_jax.sweepio import store

    agreement = compare(stored, step_log)
    name, plant = cfg.name, cfg.plant
    flat = flatten(ticks._asdict(), step_log, plant)
    folder = pathlib.Path(out_dir) / "ticks"
    folder.mkdir(exist_ok=True)
    npz, png = folder / f"{index}.npz", folder / f"{index}.png"
    flat["ydd_meas"] = measured_accel(flat)
    store.save_npz_atomic(npz, flat)
    status = steplog.STATUS_NAMES.get(int(step_log["status"]), "?")
    figure(flat, f"#{index} {name} ({status})", png)
    store.write_atomic(folder / f"{index}.json", json.dumps(
        {"name": name, "within": within, **agreement._asdict()}, indent=1))
    return Replay(npz, png, within, agreement)


def _manifest_configs(out_dir, indices) -> tuple[dict, list]:
    from hlip_jax.sweepio import store, sweep
    man = store.read_manifest(out_dir)
    configs = [sweep.config_from_dict(d) for d in man["configs"]]
    for index in indices:
        if not 0 <= index < len(configs):
            raise ValueError(f"scenario: index {index} is out of range; "
                             f"allowed: 0..{len(configs) - 1}")
    return man, configs


def runs(out_dir, indices, *, alone: bool = False):
    """Re-simulate scenarios ``indices`` of the results in ``out_dir`` with their tick logs and
    yield, scenario by scenario, (index, its :class:`hlip_jax.simulation.config.ScenarioConfig`, the
    replay's step log (arrays (K, ...)), its tick log (:class:`hlip_jax.plants.cassie.tick.TickLog`
    of arrays (K, ticks per step, ...)), "chunk" or "alone"); nothing is written.  Each runs
    within the chunk it ran in (one run per chunk, however many of its scenarios are asked
    for; the chunk's scenarios, padding and device split: the sweep's own run; every robot of
    a replayed chunk logs its ticks, so a chunk needs that memory once), or, with ``alone``,
    as a batch of one.  ValueError for an index out of range (raised here, before any run)."""
    man, configs = _manifest_configs(out_dir, indices)
    return _simulated(man, configs, indices, alone)


def _simulated(man: dict, configs: list, indices, alone: bool):
    """:func:`runs`' generator."""
    from hlip_jax.simulation import arrays, execution
    from hlip_jax.sweepio import runner
    if alone:
        for i in indices:
            yield (i, configs[i], *execution.simulate_ticks(configs, i), "alone")
        return
    batch, shapes = int(man["batch"]), arrays.shapes_of(configs)
    for chunk in sorted({i // batch for i in indices}):
        mine = sorted({i for i in indices if i // batch == chunk})
        out = execution.simulate_chunk_ticks(runner.chunk_configs(configs, batch, chunk),
                                           [i % batch for i in mine], shapes=shapes)
        for i, (step_log, ticks) in zip(mine, out):
            yield i, configs[i], step_log, ticks, "chunk"


def replay_many(out_dir, indices) -> list[Replay]:
    """Re-simulate scenarios ``indices`` of the results in ``out_dir`` with their tick logs,
    each within the chunk it ran in (:func:`runs`), and write their logs and figures
    (:func:`_write`).  Returns one :class:`Replay` per index, in order."""
    replays = runs(out_dir, indices)
    stored, done = stored_logs(out_dir, indices), {}
    for i, cfg, step_log, ticks, within in replays:
        done[i] = _write(out_dir, i, cfg, step_log, ticks, within, stored[i])
    return [done[i] for i in indices]


def replay(out_dir, index: int, *, alone: bool = False) -> Replay:
    """Re-simulate scenario ``index`` of the results in ``out_dir`` with its tick log, within
    the chunk it ran in (:func:`replay_many`) or, with ``alone``, as a batch of one (less
    memory; float32 runs at the margin may end otherwise), and write its log and figure."""
    if not alone:
        return replay_many(out_dir, [index])[0]
    replays = runs(out_dir, [index], alone=True)
    stored = stored_logs(out_dir, [index])
    i, cfg, step_log, ticks, within = next(replays)
    return _write(out_dir, i, cfg, step_log, ticks, within, stored[i])
