"""Cold and warm start of a sweep: time to the first progress line and to the end.

Runs ``hlip-sweep run SWEEP --no-report`` ``--runs`` times back to back against one
compilation cache in a fresh temporary directory (so the first run compiles and traces, the
later ones read the cache), stamping every progress line with the seconds since the command
started::

    python benchmarks/warm_start.py paper --duration 3

prints, per run, the time of the first progress line that reports a finished step
("first progress") and of the command's end.  The first progress line comes after the first
segment of steps has been simulated (about a twentieth of the run, :func:`hlip_jax.simulation.rollout.
segment_length`), so the time the simulation started is "first progress" minus that
segment's share of the run's simulation time (printed as an estimate).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STEP = re.compile(r"step (\d+)/(\d+)")


def one_run(sweep: str, cache: Path, out: Path, extra: list[str]) -> list[tuple[float, str]]:
    """(seconds since start, line) for every line the command writes."""
    cmd = [sys.executable, "-m", "hlip_jax.presentation.cli", "run", sweep, "--no-report", "--overwrite",
           "--out", str(out), "--compile-cache", str(cache), *extra]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    for raw in proc.stdout:
        for part in raw.replace("\r", "\n").splitlines():
            if part.strip():
                lines.append((time.perf_counter() - t0, part.strip()))
    if proc.wait() != 0:
        sys.exit("run failed:\n" + "\n".join(l for _, l in lines[-20:]))
    lines.append((time.perf_counter() - t0, "<end>"))
    return lines


def summary(lines: list[tuple[float, str]]) -> dict:
    """First and last progress step with their times, and the end."""
    steps = [(t, int(m.group(1)), int(m.group(2))) for t, l in lines if (m := STEP.search(l))]
    if not steps:
        return {"end": lines[-1][0]}
    (t1, k1, K), (tn, kn, _) = steps[0], steps[-1]
    per_step = (tn - t1) / max(kn - k1, 1)
    return {"first_progress": t1, "first_step": k1, "steps": K, "per_step": per_step,
            "simulating_from": t1 - k1 * per_step, "end": lines[-1][0]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", help="sweep file or shipped sweep name")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--duration", type=float, help="passed to hlip-sweep run")
    ap.add_argument("--limit", type=int, help="passed to hlip-sweep run")
    args = ap.parse_args(argv)
    extra = [] if args.duration is None else ["--duration", str(args.duration)]
    extra += [] if args.limit is None else ["--limit", str(args.limit)]
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            s = summary(one_run(args.sweep, Path(tmp) / "cache", Path(tmp) / "out", extra))
            label = "empty cache" if i == 0 else "warm cache"
            if "first_progress" not in s:
                print(f"run {i + 1} ({label}): no progress lines; end {s['end']:.1f} s")
                continue
            print(f"run {i + 1} ({label}): first progress {s['first_progress']:.1f} s "
                  f"(step {s['first_step']}/{s['steps']}), simulating from ≈ "
                  f"{s['simulating_from']:.1f} s, {s['per_step']:.3f} s per step, "
                  f"end {s['end']:.1f} s", flush=True)


if __name__ == "__main__":
    main()
