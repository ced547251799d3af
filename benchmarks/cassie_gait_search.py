"""Random search of Cassie gait presets on the training set (docs/cassie_protocol).

Writes a sweep file: the scenarios of ``sweeps/cassie_train.toml`` × ``--sets`` gait sets as
one zipped grid axis (every gait field is per-scenario data, so the whole search is one
compile).  Set 0 is the current "paper" preset (the reference); the others are drawn uniformly
(log-uniformly where marked) over the ranges with ``numpy.random.default_rng(--seed)``, or,
with ``--around``, within ±``--spread`` of each range around a given set.  The ranges are
:data:`RANGES` (rounds 1–3) unless ``--ranges`` names a round of :data:`ROUNDS` or gives
them as JSON.  A round may constrain its draws: with ``reach_within_landing`` (or
``--reach-within-landing``) a drawn set whose ``cassie.reach`` exceeds the swing profile's
landing fraction s*(clearance, strike) is drawn again, so the swing foot's horizontal blend is
complete before T_SSP (reach · T_SSP / s* <= T_SSP).  Run the file with ``hlip-sweep run``
(a GPU job) and rank the sets with ``--rank RESULTS_DIR``: per set the number of training
scenarios walked without a fall, then the mean pre-impact distance to the path, and the COM
height's distance from z0 where tick logs were replayed into the results.  Only the training
set is ever searched; the validation sweeps are run once, after.

    python benchmarks/cassie_gait_search.py --sets 48 --duration 8 --out search.toml
    python benchmarks/cassie_gait_search.py --ranges round14 --sets 48 --seed 14 \
        --out docs/experiments/cassie_gait_round14.toml
    hlip-sweep run search.toml --out results/search --batch 768
    python benchmarks/cassie_gait_search.py --rank results/search
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.plants.cassie import gaits  # noqa: E402

# dotted field: (lo, hi, log-scale)
RANGES = {
    "hlip.t_ssp": (0.22, 0.40, False), "hlip.t_dsp": (0.02, 0.10, False),
    "hlip.z0": (0.75, 0.90, False), "mpc.step_width_min": (0.10, 0.20, False),
    "gain.q_v": (0.1, 2.0, True), "gain.r": (0.5, 10.0, True),
    "cassie.clearance": (0.05, 0.15, False), "cassie.strike": (0.0, 0.02, False),
    "cassie.reach": (0.7, 1.0, False), "cassie.early_contact": (0.5, 0.9, False),
    "cassie.omega_pelvis": (2.0, 15.0, True), "cassie.omega_height": (1.5, 15.0, True),
    "cassie.omega_swing": (4.0, 40.0, True), "cassie.omega_yaw": (3.0, 15.0, True),
    "cassie.weight_pelvis": (1.0, 8.0, True),
}

#: named rounds: {"ranges": {dotted field: (lo, hi, log)}, "reach_within_landing": bool, "why"}
ROUNDS = {
    # docs/cassie_gait.md, "Round 14": the cadence of Xiong & Ames' Cassie H-LIP controller
    # (T_SSP 0.35 s, T_DSP 0.05 s, z0 0.75 m) with a margin, touchdown allowed from half the
    # SSP, a COM-height output fast enough to hold z0 within 2 cm, the blend done before T_SSP.
    "round14": {
        "ranges": {**RANGES,         # round 1's ranges, these six changed (same field order)
                   "hlip.t_ssp": (0.30, 0.40, False), "hlip.t_dsp": (0.03, 0.07, False),
                   "hlip.z0": (0.75, 0.87, False), "cassie.reach": (0.6, 1.0, False),
                   "cassie.early_contact": (0.5, 0.8, False),
                   "cassie.omega_height": (5.0, 20.0, True)},
        "reach_within_landing": True,
        "why": "hardware cadence; reach <= s*; early_contact 0.5-0.8; omega_height 5-20 rad/s",
    },
}

#: the tolerance of the constraint reach <= s*: s* is bisected to 2^-41, reach rounded to 1e-4
#: and compared after rounding, so a stored set satisfies it exactly
REACH_TOL = 0.0


def landing_fraction(clearance: float, strike: float, iters: int = 40) -> float:
    """s*: where the swing profile clearance · 64 s³(1 − s)³ − strike · s²(3 − 2s) returns to
    the ground, s ∈ [½, 1], by bisection (numpy twin of
    ``hlip_jax.plants.cassie.outputs.landing_fraction``; 1 when strike = 0)."""
    def h(s):
        return clearance * 64.0 * s ** 3 * (1.0 - s) ** 3 - strike * s ** 2 * (3.0 - 2.0 * s)
    a, b = 0.5, 1.0
    for _ in range(iters):
        m = 0.5 * (a + b)
        a, b = (m, b) if h(m) > 0.0 else (a, m)
    return 0.5 * (a + b)


def reach_ok(s: dict) -> bool:
    """Whether the set's swing blend ends by T_SSP: reach <= s*(clearance, strike)."""
    return s["cassie.reach"] <= landing_fraction(s["cassie.clearance"], s["cassie.strike"]) + REACH_TOL


def parse_ranges(text: str | None) -> tuple[dict, bool]:
    """(ranges, reach_within_landing) of ``--ranges``: a round of :data:`ROUNDS`, a JSON
    {dotted field: [lo, hi, log]}, or None (:data:`RANGES`, unconstrained)."""
    if text is None:
        return RANGES, False
    if text in ROUNDS:
        return ROUNDS[text]["ranges"], ROUNDS[text]["reach_within_landing"]
    raw = json.loads(text)
    return {k: (float(v[0]), float(v[1]), bool(v[2])) for k, v in raw.items()}, False


def draw_one(rng, ranges: dict, centre: dict, around: bool, spread: float) -> dict:
    """One set: each field uniform (log-uniform where marked) over its range, or within
    ±spread of the range around ``centre`` with ``around``; rounded to 4 decimals."""
    out = {}
    for k, (lo, hi, log) in ranges.items():
        a, b = (np.log(lo), np.log(hi)) if log else (lo, hi)
        if around:
            c = np.log(centre[k]) if log else centre[k]
            a, b = max(a, c - spread * (b - a)), min(b, c + spread * (b - a))
        v = rng.uniform(a, b)
        out[k] = round(float(np.exp(v) if log else v), 4)
    return out


def draw(n: int, seed: int, around: dict | None, spread: float, ranges: dict | None = None,
         reach_within_landing: bool = False, max_tries: int = 10000) -> dict[str, list]:
    """Set 0: the centre (``around`` or the "paper" preset, the reference, kept whether or
    not it meets the constraint); sets 1..n-1 random, each drawn again (all fields) until
    reach <= s* when ``reach_within_landing``."""
    ranges = ranges or RANGES
    rng = np.random.default_rng(seed)
    centre = around or {k: gaits.PRESETS["paper"][k] for k in ranges}
    cols = {k: [float(centre[k])] for k in ranges}
    for _ in range(n - 1):
        for _try in range(max_tries):
            s = draw_one(rng, ranges, centre, around is not None, spread)
            if not reach_within_landing or reach_ok(s):
                break
        else:
            raise SystemExit(f"no set with reach <= s* in {max_tries} draws: widen the ranges")
        for k in ranges:
            cols[k].append(s[k])
    return cols


def write(cols: dict, duration: float, out: pathlib.Path, header: str = "",
          name: str = "cassie_gait_search") -> None:
    """The training sweep with ``cols`` as one zipped axis; ``header`` (comment lines)
    goes first."""
    text = (ROOT / "sweeps" / "cassie_train.toml").read_text()
    if header:                     # the training file's own comments describe a 12 s run
        text = text[text.index("name = "):]
    text = text.replace('name = "cassie_train"', f'name = "{name}"')
    text = text.replace("duration = 12.0", f"duration = {duration}")
    zips = "\n".join(f'"{k}" = {json.dumps(v)}' for k, v in cols.items())
    out.write_text(header + text + f"\n[[grid.zip]]\n{zips}\n")


def header(argv: list[str], duration: float, cols: dict, constrained: bool,
           why: str = "") -> str:
    """Comment lines naming how the file was drawn and set 0 as the reference."""
    cmd = " ".join(["python benchmarks/cassie_gait_search.py"] + argv)
    n = len(next(iter(cols.values())))
    ref = {k: v[0] for k, v in cols.items()}
    check = ""
    if constrained:
        state = "meets" if reach_ok(ref) else "violates"
        check = f"; it {state} reach <= s*(clearance, strike), every other set meets it"
    lines = [f"Written by: {cmd}",
             f"{n} gait sets x the 16 training scenarios x {duration:g} s = {16 * n} robots.",
             "Set 0 (the first value of every [[grid.zip]] list) is the reference, the centre "
             f"of the draw{check}."]
    lines += [f"Ranges: {why}."] if why else []
    lines += ["Scenarios: sweeps/cassie_train.toml (docs/cassie_protocol), run shorter."]
    return "".join(f"# {x}\n" for x in lines)


def height_error(results: pathlib.Path, indices: list[str]) -> tuple[float, float, int]:
    """(mean, RMS) of the COM height's distance from z0 over the stance foot [m], over every
    walking tick of the scenarios ``indices`` whose tick logs were replayed into
    ``results/ticks/INDEX.npz`` (``hlip-sweep run --ticks`` or ``hlip-sweep ticks``: row 3 of
    the logged output error ``y_err``), and how many scenarios had one; NaN without any.
    The step log and summary.csv hold no height (the step log keeps the horizontal H-LIP state
    per plane only), so without replayed ticks the height is not measurable from the results."""
    errs = []
    for i in indices:
        f = results / "ticks" / f"{i}.npz"
        if f.exists():
            with np.load(f) as z:
                errs.append(np.asarray(z["y_err"], np.float64)[:, 3])
    if not errs:
        return float("nan"), float("nan"), 0
    e = np.concatenate(errs)
    return float(np.mean(np.abs(e))), float(np.sqrt(np.mean(e ** 2))), len(errs)


def is_reference(fields: list[str], key: tuple) -> bool:
    """Whether a set's values are the "paper" preset's (set 0 of a search around it)."""
    ref = gaits.PRESETS["paper"]
    return all(k in ref and abs(float(v) - float(ref[k])) < 1e-9 for k, v in zip(fields, key))


def scored_sets(results: pathlib.Path) -> tuple[list, dict, list]:
    """(the dotted set columns of summary.csv, {set: its rows}, the sets best first as
    (−walked, mean RMS distance to the path, set, :func:`height_error`))."""
    rows = list(csv.DictReader(open(results / "summary.csv")))
    fields = [k for k in rows[0] if "." in k]
    by_set: dict[tuple, list] = {}
    for r in rows:
        by_set.setdefault(tuple(r[k] for k in fields), []).append(r)
    scored = []
    for key, rs in by_set.items():
        ok = sum(r["status"] == "ok" for r in rs)
        err = np.nanmean([float(r.get("rms_track_err") or "nan") for r in rs])
        scored.append((-ok, err, key, height_error(results, [r["index"] for r in rs])))
    scored.sort(key=lambda s: (s[0], s[1]))
    return fields, by_set, scored


def validation_sweep(results: pathlib.Path, out: pathlib.Path) -> dict:
    """Write the validation set (sweeps/cassie_validation.toml) with the best drawn set of a
    ranked search (:func:`scored_sets`: the first that is not the reference and meets
    reach <= s*) as its gait, a file that extends the validation sweep; returns that set."""
    fields, by_set, scored = scored_sets(results)
    for s in scored:
        d = dict(zip(fields, s[2]))
        reach = {k: float(d[k]) for k in ("cassie.clearance", "cassie.strike", "cassie.reach")
                 if k in d}
        if not is_reference(fields, s[2]) and (len(reach) < 3 or reach_ok(reach)):
            break
    else:
        raise SystemExit(f"{results}: no drawn set to validate")
    tables: dict[str, dict] = {}
    for k, v in d.items():
        table, key = k.split(".", 1)
        tables.setdefault(table, {})[key] = v
    parent = os.path.relpath(ROOT / "sweeps" / "cassie_validation.toml", out.resolve().parent)
    text = [f"# The validation set with the best drawn set of {results.name} "
            f"(walked {-s[0]} of its {len(by_set[s[2]])} training runs)",
            f'extends = "{parent}"', f'name = "{results.name}_validation"', ""]
    for table, kv in tables.items():
        text.append(f"[base.{table}]")
        text += [f"{k} = {_toml_value(v)}" for k, v in kv.items()] + [""]
    out.write_text("\n".join(text))
    return d


def _toml_value(text: str) -> str:
    """A summary.csv cell as a TOML value: a number as written, anything else quoted."""
    try:
        float(text)
        return text
    except ValueError:
        return json.dumps({"True": True, "False": False}.get(text, text))


def rank(results: pathlib.Path, top: int) -> None:
    """Per set (the dotted columns of summary.csv): scenarios walked, then mean RMS distance
    to the path; the COM height's distance from z0 where tick logs exist; s* and the reach
    constraint; the reference set marked."""
    fields, by_set, scored = scored_sets(results)
    if not any(s[3][2] for s in scored):
        print("COM height: not measurable from these results (summary.csv and the step log "
              "hold no height); replay tick logs with `hlip-sweep run --ticks REGEX` to get it")
    for s in scored[:top]:
        d = dict(zip(fields, s[2]))
        mean_h, rms_h, n_h = s[3]
        tag = "  [reference: the paper preset]" if is_reference(fields, s[2]) else ""
        lf = ""
        if {"cassie.clearance", "cassie.strike", "cassie.reach"} <= d.keys():
            st = {k: float(d[k]) for k in ("cassie.clearance", "cassie.strike", "cassie.reach")}
            lf = f"  s* {landing_fraction(st['cassie.clearance'], st['cassie.strike']):.3f}"
            lf += "" if reach_ok(st) else " (reach > s*)"
        height = f"  |z - z0| mean {mean_h:.3f} rms {rms_h:.3f} m ({n_h} runs)" if n_h else ""
        print(f"walked {-s[0]:2d}/{len(by_set[s[2]])}  rms track err {s[1]:.3f} m{height}{lf}{tag}  "
              + ", ".join(f"{k}={v}" for k, v in d.items()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", type=int, default=48)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--around", help="JSON {dotted field: value} to sample near")
    ap.add_argument("--spread", type=float, default=0.15)
    ap.add_argument("--ranges", help="a round of ROUNDS (" + ", ".join(ROUNDS) + ") or JSON "
                    "{dotted field: [lo, hi, log]} (default: RANGES)")
    ap.add_argument("--reach-within-landing", action="store_true",
                    help="draw again every set with cassie.reach > s*(clearance, strike)")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("cassie_gait_search.toml"))
    ap.add_argument("--rank", type=pathlib.Path, help="results directory of a search to rank")
    ap.add_argument("--top", type=int, default=10)
    ap.add_argument("--validation", type=pathlib.Path, help="results directory of a search: "
                    "write --out, the validation sweep with its best drawn set as the gait")
    a = ap.parse_args(argv)
    if a.rank:
        rank(a.rank, a.top)
        return 0
    if a.validation:
        chosen = validation_sweep(a.validation, a.out)
        print(f"wrote {a.out}: " + ", ".join(f"{k}={v}" for k, v in chosen.items()))
        return 0
    around = json.loads(a.around) if a.around else None
    ranges, constrained = parse_ranges(a.ranges)
    constrained = constrained or a.reach_within_landing
    cols = draw(a.sets, a.seed, around, a.spread, ranges, constrained)
    name = a.ranges if a.ranges in ROUNDS else "search"
    argv = sys.argv[1:] if argv is None else list(argv)
    why = ROUNDS[a.ranges]["why"] if a.ranges in ROUNDS else ""
    write(cols, a.duration, a.out, header(argv, a.duration, cols, constrained, why),
          f"cassie_gait_{name}")
    print(f"wrote {a.out}: {a.sets} sets x 16 training scenarios")
    return 0


if __name__ == "__main__":
    sys.exit(main())
