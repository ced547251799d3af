"""Report of a results directory: ``report.html``, ``report.md`` and ``figures/*.png``.

Reads only the store (``manifest.json``, ``chunks/``, ``summary.csv``; see
:mod:`hlip_jax.sweepio.store`).  Contents:

* Overview: sweep, scenario counts per status, environment (versions, JAX backend, commit).
* The across-run coverage table from ``coverage.csv`` (:func:`hlip_jax.sweepio.store.
  write_coverage`): W and E from training runs, coverage of the test runs' errors with its
  95 % interval, in-sample coverage as a consistency column, E's extent along c, p, v beside
  the largest measured errors; this is the primary coverage statistic.
* Per path (one ``[[paths]]`` entry; its representative scenario is the first one that
  finished "ok", else the first): the paper-style figures —
  the x–y plane (desired path red, H-LIP COM blue, robot COM green, obstacles grey),
  global position and velocity against time (reference dashed), and the step sizes in the
  sagittal and lateral planes (steps rotated into the path heading θ_d(t_k)); the invariant-set
  figure per plane (:func:`hlip_jax.presentation.set_figures.plot_planes`: E of the [p, v] error dynamics
  with the observed errors; planes of the path's heading frame when the gain is the same in
  both, :func:`hlip_jax.errors.analysis_frame`); and a coverage table — W, E and the in-sample bracket
  (inner F_s, outer F_s/(1−α)) from all runs of that path sharing the representative's gain,
  plus held-out coverage (W from half of those runs, coverage on the other half; with a single
  run, the per-run figure of ``summary.csv``: W from the first half of its steps).
* Grid sweeps: heat maps of success rate and mean RMS tracking error over the first two
  swept dimensions (grid axes, and the path when there are several), averaged over the rest.
* Failures (status ≠ ok) and the per-scenario summary table.

matplotlib runs with the Agg backend; every figure is a PNG next to the report.
"""

from __future__ import annotations

import base64
import html
import json
import math
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from hlip_jax.analysis import metrics
from hlip_jax.presentation import set_figures, tick_report
from hlip_jax.core import steplog
from hlip_jax.sweepio import store, sweep
from hlip_jax.runtime import workers
from hlip_jax.analysis import errors

__all__ = ["ReportError", "write_report", "FIGURE_KINDS"]

FIGURE_KINDS = ("xy", "time", "steps", "invariant")
MAX_TABLE_ROWS = 500
DPI = 90


class ReportError(RuntimeError):
    """The results directory cannot be reported (one clear line)."""


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def _fmt(v, digits=4) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
        return f"{v:.{digits}g}"
    return str(v)


# --------------------------------------------------------------------------------------------
# figures of one scenario


def _isnan(v) -> bool:
    try:
        return math.isnan(float(v))
    except (TypeError, ValueError):
        return True


def _mask(log, s=0):
    return steplog.alive(log["valid"][s])


def fig_xy(log, cfg: dict, path: Path, title: str) -> None:
    plt = _plt()
    m = _mask(log)
    fig, ax = plt.subplots(figsize=(6, 5.5))
    r = log["ref_pos"][0][m]
    ax.plot(r[:, 0], r[:, 1], "r-", lw=2, label="desired path")
    h = log["x_hlip"][0][m][:, :, 0]
    ax.plot(h[:, 0], h[:, 1], "b.-", ms=3, lw=1, label="H-LIP COM")
    c = log["x_robot"][0][m][:, :, 0]
    ax.plot(c[:, 0], c[:, 1], "g.-", ms=3, lw=1, label="robot COM")
    for o in cfg.get("obstacles", []):
        ax.add_patch(plt.Circle((o["x"], o["y"]), o["radius"], color="0.5", alpha=0.5))
    if c.shape[0]:
        ax.plot(*c[-1], "gx", ms=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    fig.subplots_adjust(left=0.13, right=0.97, bottom=0.1, top=0.93)
    store.save_figure_atomic(fig, path, DPI)
    plt.close(fig)


def fig_time(log, path: Path, title: str) -> None:
    plt = _plt()
    m = _mask(log)
    t = log["t"][0][m]
    fig, axs = plt.subplots(2, 2, figsize=(9, 5.5), sharex=True)
    for p, plane in enumerate("xy"):
        ax = axs[0, p]
        ax.plot(t, log["ref_pos"][0][m][:, p], "r--", label="desired")
        ax.plot(t, log["x_hlip"][0][m][:, p, 0], "b-", lw=1, label="H-LIP")
        ax.plot(t, log["x_robot"][0][m][:, p, 0], "g-", lw=1, label="robot")
        ax.set_ylabel(f"{plane} [m]")
        ax = axs[1, p]
        ax.plot(t, log["ref_vel"][0][m][:, p], "r--", label="desired")
        ax.plot(t, log["x_hlip"][0][m][:, p, 2], "b.-", ms=2, lw=1, label="H-LIP")
        ax.plot(t, log["x_robot"][0][m][:, p, 2], "g.-", ms=2, lw=1, label="robot")
        ax.set_ylabel(f"v{plane} [m/s]")
        ax.set_xlabel("t [s] (pre-impact samples)")
    for ax in axs.flat:
        ax.grid(alpha=0.3)
    axs[0, 0].legend(fontsize=8)
    fig.suptitle(title + " — global position and velocity", fontsize=9)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.1, top=0.92, wspace=0.25, hspace=0.12)
    store.save_figure_atomic(fig, path, DPI)
    plt.close(fig)


def heading_frame_steps(u, heading):
    """Step sizes (…, 2) in the world frame → (sagittal, lateral) in the heading frame θ."""
    return steplog.to_heading_frame(u, heading)


def fig_steps(log, path: Path, title: str) -> None:
    plt = _plt()
    m = _mask(log)
    t = log["t"][0][m]
    th = log["ref_heading"][0][m]
    ur = heading_frame_steps(log["u_robot"][0][m], th)
    uh = heading_frame_steps(log["u_hlip"][0][m], th)
    fig, axs = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    for p, name in enumerate(("sagittal (step length)", "lateral (step width)")):
        axs[p].plot(t, uh[:, p], "b.-", ms=3, lw=1, label="H-LIP u")
        axs[p].plot(t, ur[:, p], "g.-", ms=3, lw=1, label="robot u")
        axs[p].set_ylabel(f"{name} [m]")
        axs[p].grid(alpha=0.3)
    axs[0].legend(fontsize=8)
    axs[1].set_xlabel("t [s]")
    fig.suptitle(title + " — step sizes in the path's heading frame", fontsize=9)
    fig.subplots_adjust(left=0.12, right=0.98, bottom=0.1, top=0.92, hspace=0.1)
    store.save_figure_atomic(fig, path, DPI)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# invariant sets


def _plane_mats(log, s):
    """What runs must share to pool their errors: the error model's A, B, K and the
    closed-loop matrix (which the planner's ``mpc.mode`` changes)."""
    A, B, K, _, Acl, _ = errors.error_system(log, s)
    return A, B, K, Acl


def invariant_analysis(log, members: list[int], man: dict, warmup: int, out: Path):
    """The consistency view (:func:`hlip_jax.analysis.coverage.consistency`) of the runs
    ``members`` (rows of ``log``, one A, B, K) with the analysis's own masks: (result, the
    runs' :class:`hlip_jax.analysis.runs.RunErrors`)."""
    from hlip_jax.analysis import coverage as cov, runs as runs_mod
    found = []
    for s in members:
        cfg = store.stored_config(man["configs"], int(log["index"][s]), out)
        pushes = metrics.push_windows(cfg)
        Acl, _, run = runs_mod.run_errors(log, s, pushes, warmup)
        found.append(run)
    return cov.consistency(Acl, found), found


def fig_invariant(an, runs, path: Path, title: str) -> None:
    plt = _plt()
    e = [np.concatenate([r.kept_e(p) for r in runs]) for p in (0, 1)]
    fig = set_figures.plot_planes((an.planes[0].E, an.planes[1].E), e,
                                  title=title + " — error invariant sets E and kept errors e_k")
    store.save_figure_atomic(fig, path, DPI)
    plt.close(fig)


def plane_names(frame: str) -> tuple[str, str]:
    """Row labels of the two analysis planes for ``frame`` ("heading" or "world")."""
    from hlip_jax.analysis import coverage as cov
    return cov.PLANES[frame]


def _coverage_rows(an, n_runs: int, row_summary: dict | None,
                   frame: str = "heading") -> list[list[str]]:
    rows = []
    for p, plane in enumerate(plane_names(frame)):
        pa = an.planes[p]
        W = pa.W
        wlo = ", ".join(f"{v:.3g}" for v in np.asarray(W.lo)) if hasattr(W, "lo") else "hull"
        whi = ", ".join(f"{v:.3g}" for v in np.asarray(W.hi)) if hasattr(W, "hi") else ""
        if pa.heldout is not None:
            held = f"{_fmt(pa.heldout.inner)} – {_fmt(pa.heldout.outer)} (n={pa.heldout.n})"
        elif row_summary is not None:
            key = "cov_" + "xy"[p] + "_heldout"
            held = f"{_fmt(row_summary.get(key, math.nan))} (later half of the steps, all steps)"
        else:
            held = "–"
        rows.append([plane, f"[{wlo}] – [{whi}]", str(pa.s), f"{pa.alpha:.3g}",
                     f"{pa.volume:.3g}",
                     f"{_fmt(pa.coverage.inner)} – {_fmt(pa.coverage.outer)} (n={pa.coverage.n})",
                     held])
    return rows


def _placement_note(rep: dict | None) -> str:
    """'; scenario: RMS |δu| …, mean along the path …' from a summary row, or ''."""
    if not rep:
        return ""
    rms, along = rep.get("place_err_rms", math.nan), rep.get("place_err_along", math.nan)
    if _isnan(rms):
        return ""
    return (f"; this scenario: RMS |δu| {_fmt(float(rms))} m, mean along the path "
            f"{_fmt(float(along))} m")


COVERAGE_HEAD = ["plane", "W box lo – hi", "s", "α", "size of E",
                 "consistency: in-sample coverage (inner – outer)", "held-out coverage"]


ACROSS_HEAD = ["group", "split", "plane", "E", "runs train / test", "runs covered [95 % CI]",
               "steps covered [95 % CI over runs]", "in-sample (runs)", "push windows in E (runs)",
               "c [m]: E / q-quantile / max", "p [m]: E / q-quantile / max",
               "v [m/s]: E / q-quantile / max"]
W_LABELS = {"box": "mRPI of box W", "hull": "mRPI of hull W",
            "conformal_step": "mRPI of conformal step box",
            "conformal_run": "run-calibrated mRPI shape", "conformal_box": "run-calibrated box"}


def _ci_text(r: dict) -> str:
    if _isnan(r.get("coverage", math.nan)):
        return "– (" + str(r.get("note") or "no test samples") + ")"
    return (f"{r['covered']}/{r['test_samples']} = {_fmt(r['coverage'])} "
            f"[{_fmt(r['ci_low'])}, {_fmt(r['ci_high'])}]")


def _runs_text(r: dict) -> str:
    """'train / test' runs, with how many of each fell where any did."""
    text = f"{r['train_runs']} / {r['test_runs']}"
    fell = (r.get("train_fell"), r.get("test_fell"))
    if any(isinstance(f, int) and f > 0 for f in fell):
        text += f" (fell {fell[0]} / {fell[1]})"
    return text


def across_run_rows(cov_rows: list[dict]) -> list[list[str]]:
    """Rows of the report's coverage table from ``coverage.csv``: one per group, split, plane
    and method, the run-level figure first and the step-level one beside it."""
    steps = {(r["group"], r["split"], r["plane"], r["w_method"]): r for r in cov_rows
             if r["level"] == "step"}
    out = []
    for r in (r for r in cov_rows if r["level"] == "run"):
        st = steps.get((r["group"], r["split"], r["plane"], r["w_method"]), {})
        w = W_LABELS.get(r["w_method"], r["w_method"])
        if not _isnan(r.get("q", math.nan)):
            w += f" q={_fmt(r['q'])}"
        push = ("–" if not r.get("push_test_runs") else
                f"{_fmt(r['push_coverage'])} ({r['push_test_runs']})")
        sizes = [" / ".join(_fmt(r[f"{k}_{c}"], 3) for k in ("e_half", "err_q", "err_max"))
                 for c in "cpv"]
        out.append([r["group"], r["split"], r["plane"], w, _runs_text(r), _ci_text(r),
                    _ci_text(st) if st else "–", _fmt(r["insample_coverage"]), push] + sizes)
    return out


ACROSS_NOTE = (
    "What is guaranteed. A test run counts as covered when it did not fall and every kept "
    "pre-impact error of it lies in E; the interval is Clopper–Pearson over runs, the unit of "
    "independence (steps of one run are correlated). The 'run-calibrated' sets are run-level "
    "conformal sets: a shape E_shape fitted on half of the training runs ('box': the box of "
    "their errors, about as wide in each coordinate as their errors reach; 'mRPI shape': "
    "mRPI(A + BK, box W of their disturbances)), each other training run scored by the "
    "smallest scale of E_shape that holds all its kept errors (a fall scores infinity), "
    "E_q = the ⌈(n+1)q⌉-th smallest of the n scores times E_shape; a new run drawn "
    "exchangeably with the training runs stays in E_q with probability ≥ q. The split says "
    "what exchangeable means here: 'seed' (other noise draws of the same paths and speeds) "
    "gives it; 'path' and 'speed' hold out paths or speeds that no training run walked, "
    "which are not a random draw, so there the figure is a check, not a guarantee. The mRPI "
    "sets of a box W are invariance sets (if every future disturbance stays in W), with no "
    "probability attached; their size beside the test errors shows how conservative they are: "
    "each size column gives E's half-width, the q-quantile over test runs of each run's "
    "largest |error|, and the largest. Steps: the fraction of kept test errors in E, with a "
    "bootstrap interval that resamples whole runs. Kept errors: after the warm-up (e_0 never "
    "counts) and outside push windows (from a push until the error is back in the run's "
    "pre-push box), which are reported apart and never enter W. From coverage.csv.")


def _projections(dim: int) -> list[tuple[int, int]]:
    return [(0, 1), (1, 2), (0, 2)] if dim == 3 else [(0, 1)]


def fig_coverage_sets(planes, fitted, path: Path, title: str) -> None:
    """One row per plane, one panel per 2-D projection of the state: the test runs' kept
    errors (points), the box W's mRPI set (light) and the run-calibrated box E_q (dark)."""
    plt = _plt()
    dims = _projections(fitted[0][0].dim)
    fig, axes = plt.subplots(len(fitted), len(dims), figsize=(3.6 * len(dims), 3.2 * len(fitted)),
                             squeeze=False)
    for (E_box, E_q, e), row, plane in zip(fitted, axes, planes):
        lab = set_figures.STATE_LABELS[E_box.dim]
        for ax, (a, b) in zip(row, dims):
            set_figures.plot_set_2d(E_box, None, dims=(a, b), ax=ax, face_color="tab:blue",
                                    alpha=0.12)
            if E_q is not None:
                set_figures.plot_set_2d(E_q, None, dims=(a, b), ax=ax, face_color="tab:orange",
                                        alpha=0.35)
            ax.scatter(e[:, a], e[:, b], s=2, c="k", alpha=0.4)
            ax.set_xlabel(lab[a]), ax.set_ylabel(lab[b])
            ax.set_title(f"{plane}", fontsize=9)
    fig.suptitle(title + " — held-out errors, mRPI of box W (blue), run-calibrated box E_q "
                 "(orange)",
                 fontsize=9)
    fig.tight_layout()
    store.save_figure_atomic(fig, path, DPI)
    plt.close(fig)


def coverage_figure_calls(doc, out: Path, split: str) -> list[tuple]:
    """Place :func:`fig_coverage_sets`'s figure of every group of ``split`` in ``doc`` and
    return the calls that draw them (drawn with the path sections, :func:`write_report`)."""
    from hlip_jax.analysis import coverage as cov
    fig_dir = out / "figures"
    fig_dir.mkdir(exist_ok=True)
    calls = []
    for i, (label, frame, fitted) in enumerate(store.coverage_sets(out, split)):
        fn = f"coverage_{split}_{i}.png"
        calls.append((cov.PLANES[frame], fitted, fig_dir / fn, f"{label} ({split} split)"))
        doc.img(f"figures/{fn}", f"held-out errors of {label} against E")
    return calls


def across_run_section(doc, out: Path) -> list[tuple]:
    """The coverage section from ``coverage.csv`` (written first if absent, e.g. a results
    directory from before the file existed), with a figure per group of its first split;
    returns the :func:`fig_coverage_sets` calls that draw those figures."""
    if not (out / store.COVERAGE).is_file():
        store.write_coverage(out)
    doc.h(2, "Coverage over held-out runs")
    doc.p(ACROSS_NOTE)
    try:
        rows = store.read_coverage(out)
    except store.OtherRunError as err:      # e.g. copied from another run: this run's instead
        store.write_coverage(out)
        why = str(err).split("; rewrite it with")[0]
        print(f"hlip-sweep: note: {why}; rewritten from this run's chunks", file=sys.stderr)
        rows = store.read_coverage(out)
    if not any(r["level"] == "run" for r in rows):
        held = ", ".join(store.analysis_settings(out).splits)
        doc.p(f"No group has runs that differ in a held-out field of this run's splits ({held}): "
              "no held-out statistic. Sweep that field (or name another in the [analysis] "
              "table's splits) to get one.")
        return []
    doc.table(ACROSS_HEAD, across_run_rows(rows))
    said = dict.fromkeys((r["split"], r["assumption"]) for r in rows if r["level"] == "run")
    doc.p("What each split assumes: " + "; ".join(f"{sp}: {a}" for sp, a in said) + ".")
    return coverage_figure_calls(doc, out, next(r["split"] for r in rows if r["level"] == "run"))


# --------------------------------------------------------------------------------------------
# heat maps


def _dims(man: dict) -> list[tuple[str, list]]:
    """Swept dimensions: (label, values) for every grid axis, then 'path' if several."""
    dims = []
    for a in man.get("axes", []):
        label = " / ".join(a["fields"])
        vals = [tuple(v) if len(v) > 1 else v[0] for v in a["values"]]
        dims.append((label, vals, a["fields"]))
    if len(man.get("paths", [])) > 1:
        dims.append(("path", list(man["paths"]), ["path"]))
    return dims


def _point_of(cfg: dict, fields: list[str]):
    sw = cfg.get("swept", {})
    vals = [sw.get(f) for f in fields]
    return vals[0] if len(vals) == 1 else tuple(vals)


def heatmap_dims(man: dict, axes: Sequence[str] | None = None):
    """The two swept dimensions of the heat maps: the first two, or the two named in ``axes``
    (a dimension's label or any of its fields; 'path' for the paths).  None if the run has
    fewer than two.  Raises :class:`ReportError` naming the allowed dimensions."""
    dims = _dims(man)
    if axes is None:
        return (dims[0], dims[1]) if len(dims) >= 2 else None
    allowed = ", ".join(repr(d[0]) for d in dims) or "none (the run has no grid)"
    if len(axes) != 2:
        raise ReportError(f"heat-map axes: expected two swept dimensions, got {len(axes)}; "
                          f"allowed: {allowed}")
    picked = []
    for name in axes:
        hit = [d for d in dims if name == d[0] or name in d[2]]
        if not hit:
            raise ReportError(f"heat-map axis {name!r} is not a swept dimension of this run; "
                              f"allowed: {allowed}")
        picked.append(hit[0])
    if picked[0][0] == picked[1][0]:
        raise ReportError(f"heat-map axes: {axes[0]!r} and {axes[1]!r} are the same dimension; "
                          f"allowed: {allowed}")
    return picked[0], picked[1]


def heatmaps(man: dict, rows: list[dict], fig_dir: Path,
             axes: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """Success-rate and mean-RMS-error maps over two swept dimensions (:func:`heatmap_dims`;
    the other dimensions are pooled in each cell)."""
    pair = heatmap_dims(man, axes)
    if pair is None:
        return []
    plt = _plt()
    (la, va, fa), (lb, vb, fb) = pair
    ka = {repr(v): i for i, v in enumerate(va)}
    kb = {repr(v): i for i, v in enumerate(vb)}
    ok = np.zeros((len(va), len(vb)))
    cnt = np.zeros((len(va), len(vb)))
    err = np.zeros((len(va), len(vb)))
    ecnt = np.zeros((len(va), len(vb)))
    cfgs = man["configs"]
    for r in rows:
        cfg = cfgs[int(r["index"])]
        pa, pb = _point_of(cfg, fa), _point_of(cfg, fb)
        ia, ib = ka.get(repr(pa)), kb.get(repr(pb))
        if ia is None or ib is None:
            continue
        cnt[ia, ib] += 1
        ok[ia, ib] += r["status"] == "ok"
        e = r.get("rms_track_err")
        if isinstance(e, (int, float)) and math.isfinite(e):
            err[ia, ib] += e
            ecnt[ia, ib] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(cnt > 0, ok / cnt, np.nan)
        merr = np.where(ecnt > 0, err / ecnt, np.nan)
    out = []
    for name, data, cmap, clabel in (("success", rate, "RdYlGn", "success rate"),
                                     ("error", merr, "viridis", "mean RMS tracking error [m]")):
        fig, ax = plt.subplots(figsize=(1.2 + 0.7 * len(vb) + 2, 1.2 + 0.5 * len(va) + 1))
        im = ax.imshow(data, cmap=cmap, aspect="auto", origin="lower",
                       vmin=0.0 if name == "success" else None,
                       vmax=1.0 if name == "success" else None)
        ax.set_xticks(range(len(vb)), [_fmt(v, 3) if not isinstance(v, tuple) else
                                       "(" + ", ".join(_fmt(x, 3) for x in v) + ")" for v in vb],
                      rotation=45 if len(vb) > 4 else 0, ha="right" if len(vb) > 4 else "center",
                      fontsize=7)
        ax.set_yticks(range(len(va)), [_fmt(v, 3) if not isinstance(v, tuple) else
                                       "(" + ", ".join(_fmt(x, 3) for x in v) + ")" for v in va],
                      fontsize=7)
        ax.set_xlabel(lb), ax.set_ylabel(la)
        for i in range(len(va)):
            for j in range(len(vb)):
                if not np.isnan(data[i, j]):
                    lvl = float(im.norm(data[i, j]))
                    dark = lvl < 0.55 if name == "error" else (lvl < 0.2 or lvl > 0.8)
                    ax.text(j, i, _fmt(float(data[i, j]), 2), ha="center", va="center",
                            fontsize=6, color="w" if dark else "k")
        fig.colorbar(im, ax=ax, label=clabel)
        ax.set_title(f"{clabel}\nover {la} × {lb}", fontsize=9)
        fig.tight_layout()  # tick labels of unknown length: worth the cost for 2 figures
        fn = f"heatmap_{name}.png"
        store.save_figure_atomic(fig, fig_dir / fn, DPI)
        plt.close(fig)
        out.append((f"{clabel} over {la} × {lb}", f"figures/{fn}"))
    return out


# --------------------------------------------------------------------------------------------
# document assembly


def _data_uri(png: Path) -> str:
    """``png`` as a base64 ``data:image/png`` URI (the file's own path if it is missing)."""
    if not png.is_file():
        return html.escape(str(png))
    return "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")


class _Doc:
    """Collects report content and renders it as HTML and Markdown."""

    def __init__(self):
        self.parts: list[tuple] = []

    def h(self, level, text):
        self.parts.append(("h", level, text))

    def p(self, text):
        self.parts.append(("p", text))

    def table(self, head, rows, bad=()):
        """A table; the rows whose indices are in ``bad`` are marked (failed scenarios)."""
        self.parts.append(("table", head, rows, frozenset(bad)))

    def img(self, src, alt):
        self.parts.append(("img", src, alt))

    def video(self, src, alt):
        """A video file (path relative to the report, not embedded) and its link."""
        self.parts.append(("video", src, alt))

    def html(self, title, base: Path) -> str:
        """One self-contained HTML file: figures (paths relative to ``base``) embedded as
        base64 data URIs (videos only linked), wide tables scroll inside their box, marked
        rows in red."""
        out = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>",
               f"<title>{html.escape(title)}</title>",
               "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;"
               "padding:0 1em;color:#222}table{border-collapse:collapse;font-size:12px;"
               "margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:2px 6px;"
               "text-align:right}th{background:#f0f0f0}td:first-child,th:first-child"
               "{text-align:left}img{max-width:100%;margin:0.3em 0}.bad{color:#b00}"
               "h2{border-bottom:1px solid #ccc;margin-top:2em}.wide{overflow-x:auto}"
               "tr.bad td{color:#b00;background:#fff4f4}</style></head><body>"]
        for part in self.parts:
            if part[0] == "h":
                out.append(f"<h{part[1]}>{html.escape(part[2])}</h{part[1]}>")
            elif part[0] == "p":
                out.append(f"<p>{html.escape(part[1])}</p>")
            elif part[0] == "img":
                out.append(f"<div><img src='{_data_uri(base / part[1])}' "
                           f"alt='{html.escape(part[2])}'></div>")
            elif part[0] == "video":
                src = html.escape(part[1])
                out.append(f"<div><video controls muted loop preload='metadata' src='{src}' "
                           f"style='max-width:100%'></video><br><a href='{src}'>"
                           f"{html.escape(part[2])}</a></div>")
            else:
                out.append("<div class='wide'><table><tr>"
                           + "".join(f"<th>{html.escape(str(c))}</th>" for c in part[1]) + "</tr>")
                for i, r in enumerate(part[2]):
                    cls = " class='bad'" if i in part[3] else ""
                    out.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r)
                               + "</tr>")
                out.append("</table></div>")
        out.append("</body></html>")
        return "\n".join(out) + "\n"

    def markdown(self) -> str:
        out = []
        for part in self.parts:
            if part[0] == "h":
                out.append("#" * part[1] + " " + part[2] + "\n")
            elif part[0] == "p":
                out.append(part[1] + "\n")
            elif part[0] == "img":
                out.append(f"![{part[2]}]({part[1]})\n")
            elif part[0] == "video":
                out.append(f"[video: {part[2]}]({part[1]})\n")
            else:
                esc = lambda c: str(c).replace("|", "\\|")  # noqa: E731
                out.append("| " + " | ".join(esc(c) for c in part[1]) + " |")
                out.append("|" + "---|" * len(part[1]))
                for r in part[2]:
                    out.append("| " + " | ".join(esc(c) for c in r) + " |")
                out.append("")
        return "\n".join(out) + "\n"


def representatives(man: dict, rows: list[dict]) -> dict[str, int]:
    """{path name: the index of the scenario the report shows for it} (its first scenario
    that finished ok, else its first)."""
    return {p: int(rep["index"]) for p, (rep, _) in _representatives(man, rows).items()}


def _representatives(man, rows):
    by_path: dict[str, list[dict]] = {}
    for r in rows:
        by_path.setdefault(str(r["path"]), []).append(r)
    reps = {}
    for pname in man.get("paths", []) or list(by_path):
        rs = by_path.get(pname, [])
        if rs:
            ok = [r for r in rs if r["status"] == "ok"]
            reps[pname] = ((ok or rs)[0], rs)
    return reps


def _read_results(out: Path, heatmap_axes) -> tuple[dict, list[dict]]:
    """The manifest and summary rows of a complete results directory (writes summary.csv if a
    complete run lacks it); :class:`ReportError` otherwise."""
    try:
        man = store.read_manifest(out)
    except store.StoreError as err:
        raise ReportError(str(err)) from None
    if not store.chunk_files(out):
        raise ReportError(f"{out}: no results stored yet (no chunks)")
    heatmap_dims(man, heatmap_axes)          # a bad axis fails before any figure is drawn
    if not (out / store.SUMMARY).is_file():
        if man.get("status") != "complete":
            raise ReportError(f"{out}: the run is incomplete; finish it with `hlip-sweep run "
                              f"... --resume` first")
        store.write_summary(out)
    rows = store.read_summary(out, man)
    stored = sum(int(b) - int(a) for a, b in
                 store.chunk_ranges(int(man["n_scenarios"]), int(man["batch"]))[:len(store.chunk_files(out))])
    if sorted(r.get("index") for r in rows) != list(range(len(rows))) or len(rows) != stored:
        raise ReportError(f"{out / store.SUMMARY}: {len(rows)} rows for the {stored} stored "
                          "scenarios (cut or altered); delete it and run `hlip-sweep report` "
                          "again to rewrite it from the chunks")
    return man, rows


def _header_section(doc: "_Doc", man: dict, rows: list[dict], out: Path) -> str:
    """Title, description and the run's facts table; returns the title."""
    title = f"hlip_jax sweep report: {man.get('sweep_name', out.name)}"
    doc.h(1, title)
    if man.get("description"):
        doc.p(man["description"])
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    jaxinfo = man.get("jax", {})
    doc.table(["item", "value"], [
        ["sweep file", man.get("sweep_file", "")],
        ["scenarios", f"{len(rows)} of {man.get('n_scenarios')}"],
        ["status", ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))],
        ["paths", ", ".join(man.get("paths", []))],
        ["grid axes", "; ".join(" / ".join(a["fields"]) + f" ({len(a['values'])})"
                                for a in man.get("axes", [])) or "none"],
        ["chunk size", man.get("batch")],
        ["JAX", f"{man.get('versions', {}).get('jax', '?')} on {jaxinfo.get('backend', '?')} "
                f"({', '.join(jaxinfo.get('devices', []))})"
                + ({True: ", float64", False: ", float32"}.get(jaxinfo.get("x64"), ""))],
        ["git commit", man.get("git_commit") or "–"],
        ["started / ended", f"{man.get('start_time')} / {man.get('end_time')}"],
        ["simulation time", f"{man.get('seconds', math.nan):.1f} s"],
    ])

    return title


#: scenarios per worker process drawing the path sections (below two workers' worth: in-process)
REPORT_RUNS_PER_WORKER = 128


def path_part(out: Path, man: dict, pname: str, rep: dict, members_rows: list[dict],
              fig_dir: Path) -> tuple[list, list]:
    """One path's section (:func:`_path_section`) on its own: (the report parts, its rows of
    the coverage summary), so that path sections can be drawn in worker processes
    (:func:`hlip_jax.runtime.workers.starmap`) and joined in path order."""
    doc = _Doc()
    summary = _path_section(doc, out, man, pname, rep, members_rows, fig_dir)
    return doc.parts, summary


def _path_section(doc: "_Doc", out: Path, man: dict, pname: str, rep: dict,
                  members_rows: list[dict], fig_dir: Path) -> list[list]:
    """One path: its figures, its invariant sets and coverage tables; returns its rows of the
    coverage summary."""
    cfgs = man["configs"]
    cov_summary: list[list] = []
    idx = int(rep["index"])
    cfg = cfgs[idx]
    slug = sweep.file_slug(pname)
    doc.h(2, f"Path: {pname}")
    params = ", ".join(f"{k}={v}" for k, v in cfg["path"]["params"].items())
    doc.p(f"shape {cfg['path']['shape']} ({params or 'defaults'}); "
          f"{len(members_rows)} scenario(s); figures show scenario #{idx} "
          f"'{cfg['name']}' (status {rep['status']}).")
    member_ids = [int(r["index"]) for r in members_rows]
    log = store.load_log(out, member_ids)
    pos = {int(i): j for j, i in enumerate(log["index"])}
    one = {k: v[pos[idx]:pos[idx] + 1] for k, v in log.items()}
    label = f"{pname}: {cfg['name']}"
    fig_xy(one, cfg, fig_dir / f"{slug}_xy.png", label)
    doc.img(f"figures/{slug}_xy.png", f"{pname} x-y plane")
    fig_time(one, fig_dir / f"{slug}_time.png", label)
    doc.img(f"figures/{slug}_time.png", f"{pname} position and velocity")
    fig_steps(one, fig_dir / f"{slug}_steps.png", label)
    doc.img(f"figures/{slug}_steps.png", f"{pname} step sizes")
    _strip(doc, out, idx, cfg["name"])

    # runs of this path with the representative's S2S model and gain
    mats0 = _plane_mats(log, pos[idx])
    same = [pos[i] for i in member_ids
            if all(x.shape == y.shape and np.allclose(x, y)
                   for x, y in zip(_plane_mats(log, pos[i]), mats0))
            and bool(np.asarray(log["valid"][pos[i]]).any())]
    doc.h(3, "Error invariant sets and coverage")
    try:
        frame = errors.analysis_frame(log, same[0])
        an, runs_ = invariant_analysis(log, same, man, store.analysis_settings(out).warmup, out)
        fig_invariant(an, runs_, fig_dir / f"{slug}_invariant.png", pname)
        doc.img(f"figures/{slug}_invariant.png", f"{pname} invariant sets")
        doc.p(f"W and E from {len(same)} run(s) sharing the gain of scenario #{idx}; "
              "E is the mRPI set of e⁺ = (A + BK) e + d (Raković et al. 2005) on "
              f"{'[c, p, v]' if an.planes[0].E.dim == 3 else '[p, v]'}, "
              "W the box of d = w + B δu (the S2S disturbance w plus the foot-placement "
              "error δu, executed step minus the law's step"
              + _placement_note(rep) + "), "
              "coverage = fraction of the kept errors (after the warm-up, outside push "
              "windows) inside E (bracket inner F_s – outer F_s/(1−α)); a consistency view, "
              "the coverage over held-out runs above is the statistic; held-out here: "
              + ("W from alternate runs, coverage of the others' kept errors."
                 if len(same) >= 2 else
                 "one run: the summary's per-scenario figure, W from the first half of its "
                 "steps.")
              + (" Planes: sagittal along the path heading θ_d(t_k), lateral to its left "
                 "(errors and disturbances rotated into that frame at every step)."
                 if frame == "heading" else
                 " Planes: world x and y (the gain differs between the planes, which a "
                 "rotation into the heading frame would not respect)."))
        doc.table(COVERAGE_HEAD, _coverage_rows(an, len(same), rep, frame))
        for p, plane in enumerate(plane_names(frame)):
            pa = an.planes[p]
            cov_summary.append([pname, plane, len(same), _fmt(pa.coverage.inner),
                                _fmt(pa.coverage.outer),
                                _fmt(pa.heldout.outer) if pa.heldout else
                                _fmt(rep.get(f"cov_{'xy'[p]}_heldout", math.nan))])
    except Exception as err:   # unstable gain, too few samples: say so, keep going
        doc.p(f"invariant analysis not available for this path: {type(err).__name__}: {err}")

    return cov_summary


def _closing_sections(doc: "_Doc", man: dict, rows: list[dict], fig_dir: Path, heatmap_axes,
                      cov_summary: list[list]) -> None:
    """Coverage summary, grid maps, failures, pushes and the per-scenario table."""
    if cov_summary:
        doc.h(2, "Coverage summary")
        doc.p("Per path, all runs sharing the representative's gain; the across-run "
              "coverage above (coverage.csv) is the primary statistic, these are "
              "consistency checks.")
        doc.table(["path", "plane", "runs", "consistency: in-sample inner",
                   "consistency: in-sample outer", "held-out"], cov_summary)

    hm = heatmaps(man, rows, fig_dir, heatmap_axes)
    if hm:
        doc.h(2, "Grid: success and error maps")
        for alt, src in hm:
            doc.img(src, alt)

    bad = [r for r in rows if r["status"] != "ok"]
    doc.h(2, f"Failures ({len(bad)})")
    if bad:
        doc.table(["#", "scenario", "status", "fail step", "steps"],
                  [[r["index"], r["name"], r["status"], r["fail_step"], r["steps"]]
                   for r in bad[:MAX_TABLE_ROWS]])
    else:
        doc.p("none: every scenario finished ok.")

    pushed = [r for r in rows if not _isnan(r.get("push_peak_err", math.nan))]
    if pushed:
        doc.h(2, f"Pushes ({len(pushed)})")
        doc.p(f"Largest COM-to-path distance from the first push on, and the steps until the "
              f"COM is back within {metrics.RECOVERY_TOL} m of the path and stays there to the end "
              f"(– : fell, or not back by the end).")
        doc.table(["#", "scenario", "status", "peak distance [m]", "steps to recover"],
                  [[r["index"], r["name"], r["status"], _fmt(r["push_peak_err"]),
                    "–" if _isnan(r.get("push_recovery_steps", math.nan))
                    else int(r["push_recovery_steps"])] for r in pushed[:MAX_TABLE_ROWS]])

    _tick_section(doc, fig_dir.parent)
    _video_section(doc, fig_dir.parent, man)

    doc.h(2, "Per-scenario summary")
    cols = ["index", "name", "status", "rms_track_err", "max_track_err", "final_pos_err",
            "cov_x_outer", "cov_y_outer", "cov_x_heldout", "cov_y_heldout", "e_size_x",
            "e_size_y", "qp_failures", "min_clearance"]
    doc.p(f"All columns in summary.csv ({len(rows)} rows); errors in m.")
    shown = rows[:MAX_TABLE_ROWS]
    doc.table(cols, [[_fmt(r.get(c, "")) for c in cols] for r in shown],
              bad=[i for i, r in enumerate(shown) if r.get("status") != "ok"])
    if len(rows) > MAX_TABLE_ROWS:
        doc.p(f"… {len(rows) - MAX_TABLE_ROWS} more rows in summary.csv")



def _tick_section(doc: "_Doc", out: Path) -> None:
    """The per-tick logs replayed into ``out/ticks`` (``hlip-sweep run --ticks``, ``hlip-sweep
    ticks``; :mod:`hlip_jax.presentation.tick_report`): each scenario's figure, how it was replayed and
    whether the replay is the stored run."""
    logs = sorted((p for p in out.glob("ticks/*.json") if p.stem.isascii() and p.stem.isdigit()),
                  key=lambda p: int(p.stem))
    if not logs:
        return
    doc.h(2, f"Per-tick logs ({len(logs)})")
    doc.p("Each scenario replayed with the controller's 1 kHz log: output errors, motor "
          "torques, contact forces, CLF-QP status and phase, and the COM-height acceleration "
          "the CLF-QP's model predicts beside the measured one (tick logs: ticks/INDEX.npz).")
    for p in logs:
        try:
            meta = json.loads(p.read_text(encoding="utf-8"))
        except ValueError as err:            # JSONDecodeError and UnicodeDecodeError
            meta = str(err)
        except RecursionError:               # arrays nested deeper than the parser goes
            meta = None
        if not isinstance(meta, dict) or not TICK_KEYS <= meta.keys():
            raise ReportError(f"{p}: not a per-tick record (expected an object with "
                              f"{', '.join(sorted(TICK_KEYS))}); replay the scenario again "
                              "with `hlip-sweep ticks`")
        how = "within its chunk" if meta["within"] == "chunk" else "alone"
        said = tick_report.verdict(tick_report.Agreement(
            meta["identical"], meta["first_step"], meta["largest"]))
        doc.p(f"#{p.stem} {meta['name']}: replayed {how}: {said}.")
        doc.img(f"ticks/{p.stem}.png", f"per-tick log of {meta['name']}")


def _strip(doc: "_Doc", out: Path, index: int, name: str) -> None:
    """Scenario ``index``'s snapshot strip, where ``hlip-sweep run --render`` drew one
    (:mod:`hlip_jax.presentation.render.files`)."""
    from hlip_jax.presentation.render import files
    p = files.strip(out, index, name)
    if p.is_file():
        doc.p(f"Scenario #{index} '{name}' drawn once per simulated second (hlip-sweep run "
              "--render): path grey, the H-LIP's planned footsteps yellow, the placed ones blue "
              "(left) and orange (right), keep-out discs red.")
        doc.img(p.relative_to(out).as_posix(), f"snapshots of {name}")


def _video_section(doc: "_Doc", out: Path, man: dict) -> None:
    """The videos in ``out/videos`` (``hlip-sweep run --render``, ``hlip-sweep render``), each
    with its snapshot strip where there is one; the video files are linked, not embedded."""
    from hlip_jax.presentation.render import files
    names = [c["name"] for c in man["configs"]]
    found = ((files.index_of(p), p) for p in out.glob(f"{files.VIDEOS}/*.mp4"))
    vids = sorted((i, p) for i, p in found if i is not None and i < len(names))
    if not vids:
        return
    doc.h(2, f"Videos ({len(vids)})")
    doc.p("Scenarios replayed within their chunks and drawn by MuJoCo's renderer (hlip-sweep "
          "render); the files lie beside the report in videos/ (linked, not embedded).")
    for i, v in vids:
        doc.video(v.relative_to(out).as_posix(), f"#{i} {names[i]} ({v.name})")
        strip = files.strip(out, i, names[i])
        if strip.is_file():
            doc.img(strip.relative_to(out).as_posix(), f"snapshots of {names[i]}")


#: the fields the report reads from a per-tick record (ticks/INDEX.json)
TICK_KEYS = frozenset(("within", "name", "identical", "first_step", "largest"))


def write_report(out_dir, heatmap_axes: Sequence[str] | None = None) -> tuple[Path, Path]:
    """Write ``report.html``, ``report.md`` and ``figures/`` for a results directory;
    ``heatmap_axes``: the two swept dimensions of the grid maps (default: the first two).

    Returns (html path, markdown path).  Raises :class:`ReportError` if the directory is not a
    complete results directory.
    """
    out = Path(out_dir)
    man, rows = _read_results(out, heatmap_axes)
    for name in ("figures", "report.html", "report.md"):
        store.inside(out, name)
    fig_dir = out / "figures"
    fig_dir.mkdir(exist_ok=True)
    doc = _Doc()
    title = _header_section(doc, man, rows, out)
    figure_calls = across_run_section(doc, out)
    path_calls = [(out, man, pname, rep, members_rows, fig_dir)
                  for pname, (rep, members_rows) in _representatives(man, rows).items()]
    tasks = [(fig_coverage_sets, c) for c in figure_calls] + [(path_part, c) for c in path_calls]
    n_workers = min(len(tasks), workers.count(len(rows), REPORT_RUNS_PER_WORKER))
    drawn = workers.starmap(workers.apply, tasks, n_workers)
    cov_summary = []
    for parts, summary in drawn[len(figure_calls):]:
        doc.parts += parts
        cov_summary += summary
    _closing_sections(doc, man, rows, fig_dir, heatmap_axes, cov_summary)
    html_p, md_p = out / "report.html", out / "report.md"
    store.write_atomic(html_p, doc.html(title, out))
    store.write_atomic(md_p, doc.markdown())
    return html_p, md_p
