"""The robot's motion in a stored scenario: the replay and its poses at the frame times.

The sweep keeps one record per walking step; a picture needs the robot's joint positions.
:func:`replays` re-simulates the scenarios as ``hlip-sweep ticks`` does
(:func:`hlip_jax.presentation.tick_report.runs`: within the chunk each ran in, the sweep's own run, or
alone) and keeps, of the plant's 1 kHz tick log, the joint positions ``qpos`` of every tick
that ran and the plant clock [s] at its start (:func:`hlip_jax.presentation.tick_report.flatten`).
:func:`frame_times` spaces the frames over a window of plant time and :func:`poses` picks,
for each frame, the last tick at or before it (a tick is 1 ms, so a frame is at most 1 ms
old).  Nothing is written.
"""

from __future__ import annotations

from typing import Iterator, NamedTuple

import numpy as np

from hlip_jax.presentation.render import RenderError


class Motion(NamedTuple):
    """One replayed scenario."""
    index: int            # the scenario's index in the results directory
    config: object        # its hlip_jax.simulation.config.ScenarioConfig
    step_log: dict        # the replay's step log, arrays (K, ...) (hlip_jax.core.steplog fields)
    time: np.ndarray      # (n,) plant clock at the start of each tick that ran [s], increasing
    qpos: np.ndarray      # (n, nq) the robot's generalised positions at those ticks
    verdict: str          # whether the replay is the stored run (tick_report.verdict)
    within: str           # "chunk" (the sweep's own batch) or "alone"


def replays(out_dir, indices, *, alone: bool = False) -> Iterator[Motion]:
    """Re-simulate scenarios ``indices`` of the results in ``out_dir`` (Cassie plant; within
    their chunks, one run per chunk, or ``alone``) and yield their :class:`Motion` in chunk
    order.  ValueError for an index out of range or a plant without a tick log."""
    from hlip_jax.presentation import tick_report
    runs = tick_report.runs(out_dir, list(indices), alone=alone)
    stored = tick_report.stored_logs(out_dir, list(indices))
    for i, cfg, step_log, ticks, within in runs:
        flat = tick_report.flatten({"qpos": ticks.qpos, "phase": ticks.phase}, step_log,
                                   cfg.plant)
        order = np.argsort(flat["time"], kind="stable")
        agreement = tick_report.compare(stored[i], step_log)
        yield Motion(index=i, config=cfg, step_log=step_log,
                     time=np.asarray(flat["time"], np.float64)[order],
                     qpos=np.asarray(flat["qpos"], np.float64)[order],
                     verdict=tick_report.verdict(agreement), within=within)


def window(motion: Motion, t0: float | None, t1: float | None) -> tuple[float, float]:
    """The plant-time window [s] to draw: [``t0``, ``t1``] (None: the run's first or last
    tick) within the run's ticks; RenderError naming ``--t0``/``--t1`` when it is empty."""
    first, last = float(motion.time[0]), float(motion.time[-1])
    lo = first if t0 is None else max(float(t0), first)
    hi = last if t1 is None else min(float(t1), last)
    if t0 is not None and t0 > last:
        raise RenderError(f"--t0: {t0:g} s is past the run's end; allowed: {first:g} to "
                          f"{last:.3f} s")
    if hi <= lo:
        raise RenderError(f"--t0/--t1: the window [{lo:g}, {hi:g}] s is empty; allowed: "
                          f"t0 < t1 within {first:g} to {last:.3f} s")
    return lo, hi


def frame_times(t_start: float, t_end: float, fps: float, speed: float) -> np.ndarray:
    """Plant times [s] of the frames of a clip of ``t_start`` to ``t_end`` [s] played at
    ``fps`` frames per second of video, ``speed`` simulated seconds per second of video:
    t_start, t_start + speed / fps, ... up to t_end."""
    step = speed / fps
    n = int(np.floor((t_end - t_start) / step + 1e-9)) + 1
    return t_start + step * np.arange(n)


def poses(motion: Motion, times: np.ndarray) -> np.ndarray:
    """(len(times), nq) ``qpos`` of the last tick at or before each time (the first tick's
    before the run's start)."""
    j = np.searchsorted(motion.time, np.asarray(times), side="right") - 1
    return motion.qpos[np.clip(j, 0, len(motion.time) - 1)]
