"""Closed-loop Cassie throughput (``hlip-sweep bench``): the MPC on the H-LIP driving the MJX
Cassie plant through the stepping law and the CLF-QP, one compiled, vmapped call over a batch
of straight-line scenarios (0, 0.2, 0.4, 0.6 m/s, the default gait), against physics-only MJX
(zero torque, same model, same batch, same number of ticks) in the same process: MJX-JAX
always, and MJX's Warp implementation too when Warp physics is among the benchmarked ones
(the engine such a sweep runs), each with its own ratio.

Per batch size, device count, CLF-QP loop (``impl.qp_loop``: the ADMM blocks in a while
loop that stops when the batch has converged, or in a loop of static trip count that runs the
whole budget; the same torques either way) and physics implementation (``impl.physics``:
MJX-JAX or MJX's Warp): compile + first run [s], timed run [s], simulated
robot-seconds per wall-second, physics steps per second in the loop (2 per 1 kHz control tick,
only the ticks that simulate), the physics-only rate on one device and the ratio, the fraction
of robots still walking at the end, and the accelerator's peak memory per robot where the
backend reports it (``memory_stats``; None on the CPU).
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

from hlip_jax import plants

#: the plant the closed-loop benchmark measures
PLANT = "cassie"
SPEEDS = (0.0, 0.2, 0.4, 0.6)

HEADER = ("| batch | devices | CLF-QP loop, physics | steps | compile + first [s] | run [s] | robot-s / s | "
          "physics steps/s (closed loop) | physics only, 1 device [steps/s] | ratio | "
          "Warp physics only, 1 device [steps/s] | ratio to Warp | walking at end | "
          "peak memory / robot [MiB] |\n|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")


def configs(n: int, duration: float, qp_max_iter: int | None = None, qp_loop: str = "while",
            physics: str = "jax", qp_linsys: str = "cholesky", qp_rho_start: str = "previous",
            qp_kernel: str = "xla", condense: str = "eigen", terms: str = "mjx"):
    """n straight-line Cassie scenarios, speeds cycling through SPEEDS, with the default walk
    of docs/cassie_gait.md (the default gait preset's H-LIP timing and 3-state LQR stepping
    gain), the CLF-QP loop ``qp_loop``, its linear solve ``qp_linsys``, its iterations' kernel
    ``qp_kernel`` and the physics implementation ``physics`` (``ImplConfig.qp_loop``,
    ``qp_linsys``, ``qp_kernel``, ``physics``), the CLF-QP's starting step size
    ``qp_rho_start`` (``CassieConfig.qp_rho_start``), the condensation's solve ``condense``
    (``ImplConfig.condense``) and the whole-body terms ``terms`` (``ImplConfig.terms``)."""
    from hlip_jax.simulation.config import (CassieConfig, GainConfig, HLIPConfig, ImplConfig, PathConfig,
                                 ScenarioConfig)
    W = plants.tools(PLANT).default_gait()
    budget = {} if qp_max_iter is None else {"qp_max_iter": qp_max_iter}
    cassie = CassieConfig(qp_rho_start=qp_rho_start, **budget)
    impl = ImplConfig(qp_loop=qp_loop, physics=physics, qp_linsys=qp_linsys, qp_kernel=qp_kernel,
                      condense=condense, terms=terms)
    return [ScenarioConfig(plant=PLANT, seed=i, duration=duration, cassie=cassie, impl=impl,
                           hlip=HLIPConfig(z0=W["hlip.z0"], t_ssp=W["hlip.t_ssp"],
                                           t_dsp=W["hlip.t_dsp"]),
                           gain=GainConfig(type="lqr", with_position=True, q_c=W["gain.q_c"],
                                           q_p=1.0, q_v=W["gain.q_v"], r=W["gain.r"]),
                           path=PathConfig(shape="line", params=dict(
                               peak_speed=max(SPEEDS[i % len(SPEEDS)], 0.01), length=5.0)))
            for i in range(n)]


def _peak_bytes(devices):
    try:
        stats = [d.memory_stats() for d in devices]
    except Exception:  # noqa: BLE001 - a backend without memory statistics
        return None
    if not stats or any(s is None or "peak_bytes_in_use" not in s for s in stats):
        return None
    return sum(s["peak_bytes_in_use"] for s in stats)


def timed_run(batch, static, emit: Callable[[str], None] | None = None, label: str = "",
              devices=None):
    """Run the compiled closed loop twice on ``batch``: the first call compiles, the second is
    timed.  ``devices``: the host batch run over them as a sweep runs it
    (:func:`hlip_jax.simulation.execution.run_on`, outputs brought to the host); None: the batch as placed
    (:func:`hlip_jax.simulation.execution.run`).  Returns (compile + first run [s], run [s], output).
    ``emit`` (optional) hears when each call starts, so a run cut off by a time limit shows
    whether the compile or the timed run was under way."""
    import jax

    from hlip_jax.simulation import execution
    say = emit or (lambda _: None)
    if devices is None:
        go = lambda: execution.run(batch, static)                          # noqa: E731
    else:
        go = lambda: execution.run_on(batch, static, devices, execution.spread_of(devices))  # noqa: E731
    with jax.default_matmul_precision("highest"):
        say(f"{label}: compile + first run started")
        t0 = time.perf_counter()
        jax.block_until_ready(go())
        t1 = time.perf_counter()
        say(f"{label}: compile + first run took {t1 - t0:.1f} s; timed run started")
        out = jax.block_until_ready(go())
    return t1 - t0, time.perf_counter() - t1, out


ADMM_HEADER = ("| batch | CLF-QP ADMM budget [iterations] | run [s] | physics steps/s | "
               "ADMM iterations' share of the closed loop |\n|---:|---:|---:|---:|---:|")


def admm_share(t_full: float, t_short: float, it_full: int, it_short: int) -> float:
    """Share of the closed-loop time spent in ADMM iterations, from two runs that differ only
    in the CLF-QP's iteration budget: (t_full − t_short) is the cost of it_full − it_short
    iterations per tick, so the it_full iterations cost (t_full − t_short)·it_full /
    (it_full − it_short).  Exact when every tick of the batch runs its whole budget (a vmapped
    ADMM loop stops only when every robot's QP has converged: with thousands of robots some
    robot is always at an impact); the QP's setup (building, scaling, factorising) is not
    counted."""
    return (t_full - t_short) * it_full / (it_full - it_short) / t_full


def _physics_only_rate(B: int, ticks: int, steps: int, physics: str = "jax") -> float:
    """Physics steps per second of B zero-torque robots over ``ticks`` control ticks stepped
    by ``physics`` ("jax": MJX-JAX, "warp": MJX's Warp implementation), the compiled call
    timed on its second run."""
    import jax

    physics_only, d = plants.tools(PLANT).physics_only(B, ticks, physics)
    jax.block_until_ready(physics_only(d))
    t0 = time.perf_counter()
    jax.block_until_ready(physics_only(d))
    return B * steps / (time.perf_counter() - t0)


def _admm_run(batch, static, B: int, steps: int, rows: list, emit) -> list[str]:
    """The batch again on one device with the CLF-QP's ADMM budget cut to one convergence
    check (same scenarios, only the static budget differs); adds the ADMM share to the
    one-device row of ``rows`` and returns the ADMM table's rows."""
    import jax

    qp_s = static.plant_settings.qp
    full, short = qp_s.max_iter, qp_s.check_interval
    s2 = static._replace(plant_settings=static.plant_settings._replace(qp=qp_s._replace(max_iter=short)))
    try:
        _, t_short, _ = timed_run(batch, s2, emit, f"batch {B}, ADMM budget cut",
                                  devices=jax.devices()[:1])
    except Exception as exc:  # noqa: BLE001
        emit(f"batch {B}, ADMM budget {short}: failed: {type(exc).__name__}")
        return []
    one = [r for r in rows if r["batch"] == B and r["devices"] == 1]
    if not one:
        return []
    share = admm_share(one[0]["run_s"], t_short, full, short)
    one[0].update(admm_share=share, run_s_short_qp=t_short)
    return [f"| {B} | {full} | {one[0]['run_s']:.2f} | {one[0]['physics_steps_per_s']:,.0f} | "
            f"{share:.2f} |", f"| {B} | {short} | {t_short:.2f} | {B * steps / t_short:,.0f} | |"]


def _device_runs(batch, static, B: int, steps: int, devices, emit, loop: str) -> list[tuple]:
    """The batch timed on each device count of ``devices`` (a failure is reported and
    skipped; ``loop`` names the variant in the progress lines).  Returns (devices,
    compile + first [s], run [s], statuses, peak bytes) each."""
    import jax
    import numpy as np

    runs = []
    for n_dev in devices:
        if n_dev > len(jax.devices()) or B % n_dev:
            emit(f"skipping {n_dev} devices (have {len(jax.devices())}; batch {B})")
            continue
        devs = jax.devices()[:n_dev]
        try:
            t_first, t_run, out = timed_run(batch, static, emit,
                                            f"batch {B} on {n_dev} device(s), {loop}", devs)
        except Exception as exc:  # noqa: BLE001 - e.g. out of accelerator memory
            emit(f"batch {B} on {n_dev} device(s), {loop} failed: {type(exc).__name__}: "
                 f"{str(exc).splitlines()[0][:200] if str(exc) else ''}")
            continue
        # a partial result survives a later failure or a time limit
        emit(f"batch {B} on {n_dev} device(s), {loop}: compile + first {t_first:.1f} s, "
             f"run {t_run:.2f} s, {B * steps / t_run:,.0f} physics steps/s")
        runs.append((n_dev, t_first, t_run, np.asarray(out["status"]), _peak_bytes(devs)))
    return runs


def _loop(static) -> str:
    """The CLF-QP loop (``ImplConfig.qp_loop``) of a build's static settings."""
    if static.plant_settings.qp_compact:
        return "compact"
    return "while" if static.plant_settings.qp.early_exit else "fixed"


def _variant(static, rho_start: str = "previous") -> str:
    """'<CLF-QP loop> loop[, <linsys>][, fused kernel][, ρ from 0.1 every tick], <physics>
    physics' of a build's static settings and its CLF-QP's starting step size (each named
    where it is not the default)."""
    linsys = static.plant_settings.qp.linsys
    solve = "" if linsys == "cholesky" else f", {linsys}"
    if static.plant_settings.qp.block_kernel == "fused":
        solve += ", fused kernel"
    if static.plant_settings.condense != "eigen":
        solve += f", {static.plant_settings.condense} condensation"
    if static.plant_settings.terms != "mjx":
        solve += f", {static.plant_settings.terms} terms"
    rho = ", ρ from 0.1 every tick" if rho_start == "default" else ""
    return f"{_loop(static)} loop{solve}{rho}, {static.plant_settings.physics} physics"


def _row(static, B: int, T: float, steps: int, prates: dict, n_dev: int, t_first: float,
         t_run: float, status, peak) -> dict:
    """One result row of the closed-loop benchmark (a run of ``_device_runs``); ``prates``
    {"jax": rate, "warp": rate or None} are the physics-only rates measured in this process
    (MJX-JAX always, Warp where the benchmark runs Warp physics)."""
    import numpy as np

    from hlip_jax.core import steplog
    rate = B * steps / t_run
    return dict(batch=B, devices=n_dev, qp_loop=_loop(static),
                qp_linsys=static.plant_settings.qp.linsys,
                qp_kernel=static.plant_settings.qp.block_kernel,
                condense=static.plant_settings.condense, terms=static.plant_settings.terms,
                physics=static.plant_settings.physics, steps=static.n_steps,
                compile_first_s=t_first, run_s=t_run,
                robot_s_per_s=B * static.n_steps * T / t_run, physics_steps_per_s=rate,
                physics_only_steps_per_s=prates["jax"], ratio=rate / prates["jax"],
                physics_only_warp_steps_per_s=prates.get("warp"),
                ratio_warp=None if prates.get("warp") is None else rate / prates["warp"],
                walking=float(np.mean(status == steplog.STATUS_OK)),
                peak_mib_per_robot=None if peak is None else peak / B / 2**20)


def _table_row(r: dict, variant: str) -> str:
    """The markdown row of :data:`HEADER` for result row ``r``."""
    mem = "–" if r["peak_mib_per_robot"] is None else f"{r['peak_mib_per_robot']:.2f}"
    warp = ("– | –" if r["ratio_warp"] is None else
            f"{r['physics_only_warp_steps_per_s']:,.0f} | {r['ratio_warp']:.2f}")
    return (f"| {r['batch']} | {r['devices']} | {variant} | {r['steps']} | "
            f"{r['compile_first_s']:.1f} | {r['run_s']:.2f} | {r['robot_s_per_s']:,.1f} | "
            f"{r['physics_steps_per_s']:,.0f} | {r['physics_only_steps_per_s']:,.0f} | "
            f"{r['ratio']:.2f} | {warp} | "
            f"{r['walking']:.3f} | {mem} |")


def _variants(physics, qp_loops, qp_linsys, qp_kernels, qp_rho_start,
              condense=("eigen",), terms=("mjx",)) -> list[dict]:
    """The keyword arguments of :func:`configs` for every combination of the benchmark's
    variant lists, without the fused kernel on Cholesky solves (it needs the inverse)."""
    import itertools
    combos = itertools.product(physics, qp_loops, qp_linsys, qp_kernels, qp_rho_start, condense,
                               terms)
    return [dict(physics=ph, qp_loop=q, qp_linsys=ls, qp_kernel=k, qp_rho_start=r, condense=c,
                 terms=t)
            for ph, q, ls, k, r, c, t in combos if not (k == "fused" and ls != "inverse")]


def closed_loop(batches: Sequence[int], duration: float, devices: Sequence[int] = (1,),
                emit: Callable[[str], None] = print, admm: bool = False,
                qp_loops: Sequence[str] = ("while",),
                physics: Sequence[str] = ("jax",),
                on_row: Callable[[list], None] | None = None,
                qp_linsys: Sequence[str] = ("cholesky",),
                qp_rho_start: Sequence[str] = ("previous",),
                qp_kernels: Sequence[str] = ("xla",),
                condense: Sequence[str] = ("eigen",),
                terms: Sequence[str] = ("mjx",)) -> list[dict]:
    """Run the benchmark for every batch size × CLF-QP loop (``qp_loops``, values of
    ``ImplConfig.qp_loop``) × linear solve (``qp_linsys``, ``ImplConfig.qp_linsys``) ×
    iterations' kernel (``qp_kernels``, ``ImplConfig.qp_kernel``; "fused" with the
    "inverse" solve only) × condensation solve (``condense``, ``ImplConfig.condense``) ×
    whole-body terms (``terms``, ``ImplConfig.terms``) ×
    starting step size (``qp_rho_start``, ``CassieConfig.qp_rho_start``) ×
    physics implementation (``physics``, values of ``ImplConfig.physics``) × device count; ``emit`` gets the markdown table (header, then
    one row per run).  With ``admm`` every batch size is also run (one device, the first
    variant) with the CLF-QP's ADMM budget cut to one convergence check, and the ADMM
    iterations' share of the tick follows (:func:`admm_share`, second table).  Returns one
    dict per run; ``on_row`` (optional) gets the rows so far after each one, so a run cut off
    by a time limit keeps what it measured."""
    import jax
    import numpy as np

    from hlip_jax.simulation import arrays
    parts = plants.tools(PLANT)

    emit(f"backend {jax.default_backend()} device {jax.devices()[0].device_kind}; "
         f"{duration} s per robot")
    emit(HEADER)
    rows, admm_rows = [], []
    for B in batches:
        builds = [(v["qp_rho_start"], arrays.build(configs(B, duration, **v)))
                  for v in _variants(physics, qp_loops, qp_linsys, qp_kernels, qp_rho_start,
                                     condense, terms)]
        batch, static = builds[0][1]
        T = float(np.asarray(batch.t_ssp[0] + batch.t_dsp[0]))
        ticks = static.n_steps * int(round(T / parts.CONTROL_DT))
        steps = ticks * parts.SUBSTEPS
        prates = {ph: _physics_only_rate(B, ticks, steps, ph)   # first: a cut-off run keeps them
                  for ph in ("jax", "warp") if ph == "jax" or ph in physics}
        for ph, rate in prates.items():
            emit(f"batch {B}: physics only ({ph}), 1 device: {rate:,.0f} physics steps/s")
        for rho, (b_q, st_q) in builds:
            for run in _device_runs(b_q, st_q, B, steps, devices, emit, _variant(st_q, rho)):
                rows.append(dict(_row(st_q, B, T, steps, prates, *run), qp_rho_start=rho))
                if on_row is not None:
                    on_row(rows)
                emit(_table_row(rows[-1], _variant(st_q, rho)))
        if admm:
            admm_rows += _admm_run(batch, static, B, steps, rows, emit)
            if on_row is not None:
                on_row(rows)                   # the row now carries its ADMM share
    if admm_rows:
        emit(ADMM_HEADER)
        for r in admm_rows:
            emit(r)
    return rows
