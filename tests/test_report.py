"""Report of a results directory (hlip_jax.presentation.report): every figure and table is present.

Runs the tiny sweep of test_store.py through its fake closed loop (the report only reads the
store, so the closed loop does not matter here) and checks the HTML/Markdown for each item.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pytest

from test_store import TINY, fake_simulate  # noqa: E402

from hlip_jax.presentation import report
from hlip_jax.sweepio import runner, store, sweep  # noqa: E402


@pytest.fixture(scope="module")
def tiny_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("rep") / "tiny"
    runner.run_sweep(sweep.parse_sweep(TINY), out, batch=4, progress=False, simulate=fake_simulate)
    html_p, md_p = report.write_report(out)
    return out, html_p.read_text(), md_p.read_text()


def test_every_figure_exists_and_is_referenced(tiny_report):
    """Markdown links figures/*.png; the HTML is one self-contained file: every figure is
    embedded as a base64 data URI holding exactly that PNG's bytes."""
    out, html, md = tiny_report
    embedded = {base64.b64decode(src.split(",", 1)[1])
                for src in re.findall(r"<img src='(data:image/png;base64,[^']+)'", html)}
    for path in ("circle", "line"):
        for kind in report.FIGURE_KINDS:
            f = out / "figures" / f"{path}_{kind}.png"
            assert f.is_file() and f.stat().st_size > 1000, f
            assert f.read_bytes() in embedded, f
            assert f"figures/{path}_{kind}.png" in md
    for name in ("success", "error"):
        f = out / "figures" / f"heatmap_{name}.png"
        assert f.is_file() and f.read_bytes() in embedded
    assert len(re.findall(r"<img src='", html)) == len(re.findall(r"<img src='data:", html))
    text = re.sub(r"data:image/png;base64,[^']+", "", html)     # base64 may spell anything
    assert "<script" not in text and "http" not in text


def test_tables(tiny_report):
    out, html, md = tiny_report
    for head in report.COVERAGE_HEAD:
        assert head in md
    # same gain in both planes: the planes of the path heading frame, one row per path in its
    # consistency table and one in the coverage summary; no group of the tiny sweep varies a
    # seed, path or speed, so coverage.csv is empty and the report says so instead of a table
    assert store.read_coverage(out) == []
    assert "no held-out statistic" in md
    assert md.count("| sagittal |") == 4 and md.count("| lateral |") == 4
    assert md.index("## Coverage over held-out runs") < md.index("## Path:")
    assert "world x" not in md
    assert "Planes: sagittal along the path heading" in md
    assert "Coverage summary" in md and "held-out" in md
    assert "## Failures (2)" in md and "fell" in md
    assert "Per-scenario summary" in md
    assert md.count("circle/gain.type=") >= 4
    assert "<table>" in html and "Path: circle" in html and "Path: line" in html
    # the two failed scenarios' rows of the per-scenario table are marked
    assert html.count("<tr class='bad'>") == 2


def test_heading_frame_steps():
    # a step of (1, 0) in the world seen from heading 90° is (0, -1): 1e-15 rounding only
    u = np.array([[1.0, 0.0], [0.0, 2.0]])
    th = np.array([np.pi / 2, np.pi / 2])
    np.testing.assert_allclose(report.heading_frame_steps(u, th), [[0.0, -1.0], [2.0, 0.0]],
                               atol=1e-15)


def test_report_errors(tmp_path):
    with pytest.raises(report.ReportError, match="not found"):
        report.write_report(tmp_path / "missing")
    with pytest.raises(report.ReportError, match="not a results directory"):
        report.write_report(tmp_path)
    out = tmp_path / "part"
    runner.run_sweep(sweep.parse_sweep(TINY), out, batch=4, progress=False,
                    simulate=fake_simulate, max_chunks=1)
    with pytest.raises(report.ReportError, match="incomplete"):
        report.write_report(out)


def test_heatmap_axes_are_chosen_by_name(tiny_report, tmp_path):
    out, _, md = tiny_report
    # default: the first two swept dimensions, named in the figures' alt text
    assert "over gain.type × mpc.alpha" in md
    _, md_p = report.write_report(out, heatmap_axes=("path", "mpc.alpha"))
    assert "over path × mpc.alpha" in md_p.read_text()
    for bad, msg in ((("path", "gain.typo"), "'gain.typo' is not a swept dimension"),
                     (("path", "path"), "same dimension"), (("path",), "expected two")):
        with pytest.raises(report.ReportError, match=msg) as err:
            report.write_report(out, heatmap_axes=bad)
        assert "allowed: 'gain.type', 'mpc.alpha', 'path'" in str(err.value)
    report.write_report(out)          # leave the module fixture's report as it was
