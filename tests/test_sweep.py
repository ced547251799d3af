"""Sweep files → validated ScenarioConfig lists (hlip_jax.sweepio.sweep).

The broken corpus in tests/sweeps_broken/ holds one mistake per file; each file's
``# expect: ...`` header lines list substrings its error message must contain (the field, the
value, what is allowed), so every file checks its own message.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest

from hlip_jax.simulation import config as C
from hlip_jax.sweepio import sweep

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = sorted((ROOT / "sweeps").glob("*.toml"))
# the experiments the docs cite: run from the checkout, not shipped in the wheel
EXPERIMENTS = sorted((ROOT / "docs" / "experiments").glob("*.toml"))
MAX_SHIPPED = 12   # each shipped sweep a user's question (issue 53)
BROKEN = sorted((Path(__file__).parent / "sweeps_broken").glob("*.toml"))


def _expects(path: Path) -> list[str]:
    return [ln.split("# expect:", 1)[1].strip() for ln in path.read_text().splitlines()
            if ln.startswith("# expect:")]


def test_corpus_is_large_enough():
    assert len(BROKEN) >= 150
    assert all(_expects(p) for p in BROKEN), "every broken file states its expected message"


@pytest.mark.parametrize("path", SHIPPED + EXPERIMENTS,
                         ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_shipped_sweeps_validate(path):
    sw = sweep.load_sweep(path)
    assert sw.name == path.stem
    assert len(sw.scenarios) == sw.total >= 1
    assert all(isinstance(c, C.ScenarioConfig) for c in sw.scenarios)
    names = [c.name for c in sw.scenarios]
    assert len(set(names)) == len(names), "scenario names are unique"
    n_grid = math.prod(len(a) for a in sw.axes) if sw.axes else 1
    assert sw.total == len(sw.paths) * n_grid


def test_shipped_and_experiment_sweeps_are_listed():
    """At most MAX_SHIPPED sweeps ship, each a row of sweeps/README.md's table; every experiment
    is a row of docs/experiments/README.md's; no name is both (``hlip-sweep run NAME`` would
    find only the shipped one)."""
    assert 1 <= len(SHIPPED) <= MAX_SHIPPED and EXPERIMENTS
    for files, readme in ((SHIPPED, ROOT / "sweeps" / "README.md"),
                          (EXPERIMENTS, ROOT / "docs" / "experiments" / "README.md")):
        rows = [ln for ln in readme.read_text().splitlines() if ln.startswith("| `")]
        missing = [p.name for p in files if not any(f"`{p.name}`" in r for r in rows)]
        assert not missing, f"{readme.relative_to(ROOT)} lists no row for {missing}"
    assert not {p.name for p in SHIPPED} & {p.name for p in EXPERIMENTS}


def test_paper_sweep_contents():
    sw = sweep.load_sweep(ROOT / "sweeps" / "paper_hlip.toml")
    assert 10 <= len(sw.scenarios) <= 40
    shapes = {c.path.shape for c in sw.scenarios}
    assert {"circle", "sinusoid", "square", "cardioid"} <= shapes
    assert {c.path.params.get("profile") for c in sw.scenarios} >= {"trapezoid", "triangle"}
    obst = [c for c in sw.scenarios if c.obstacles]
    assert obst and all(c.path.shape == "sinusoid" for c in obst)
    pushed = [c for c in sw.scenarios if c.disturbance.pushes]
    assert pushed
    p = pushed[0].disturbance.pushes[0]
    assert (p.force, p.duration, p.time, p.direction) == (200.0, 0.1, 10.0, 90.0)


def test_paper_sweep_runs_on_cassie():
    """The shipped paper.toml is the paper's evaluation on Cassie: the four shapes, the
    obstacle on the sinusoid (with a planning margin), the 200 N push at 10 s."""
    sw = sweep.load_sweep(ROOT / "sweeps" / "paper.toml")
    assert {c.plant for c in sw.scenarios} == {"cassie"}
    assert {"circle", "sinusoid", "square", "cardioid", "line"} == {c.path.shape for c in sw.scenarios}
    obst = [c for c in sw.scenarios if c.obstacles]
    assert len(obst) == 1 and obst[0].obstacles[0].margin > 0
    p = [c for c in sw.scenarios if c.disturbance.pushes][0].disturbance.pushes[0]
    assert (p.force, p.duration, p.time, p.direction) == (200.0, 0.1, 10.0, 90.0)


@pytest.mark.parametrize("eager", [True, False], ids=["eager", "counted"])
@pytest.mark.parametrize("path", BROKEN, ids=lambda p: p.stem)
def test_broken_sweep_fails_with_its_message(path, eager, monkeypatch):
    """Each broken file fails with its message, whether the grid is expanded scenario by
    scenario (small grids) or counted and validated on a covering subset (large grids)."""
    if not eager:
        monkeypatch.setattr(sweep, "EAGER_SCENARIOS", 0)
    with pytest.raises(sweep.SweepError) as ei:
        sweep.load_sweep(path)
    msg = str(ei.value)
    assert "\n" not in msg, "one line"
    assert msg.startswith(str(path)), "names the file"
    for frag in _expects(path):
        assert frag in msg, f"{frag!r} missing from: {msg}"


def test_broken_messages_are_distinct():
    msgs = set()
    for p in BROKEN:
        try:
            sweep.load_sweep(p)
        except sweep.SweepError as err:
            msgs.add(str(err).split(": ", 1)[1])
    assert len(msgs) == len(BROKEN)


GRID = """
name = "g"
[base]
duration = 5.0
seed = 7
[[base.disturbance.pushes]]
force = 50.0
time = 2.0
[[paths]]
shape = "circle"
radius = 2
[[paths]]
shape = "line"
name = "straight"
[grid.product]
"mpc.alpha" = [0.01, 0.1]
"gain.type" = ["lqr", "deadbeat"]
[[grid.zip]]
"disturbance.pushes.0.force" = [1, 2, 3]
"path.peak_speed" = [0.3, 0.4, 0.5]
"""


def test_expansion_product_and_zip():
    sw = sweep.parse_sweep(GRID)
    assert sw.total == len(sw.scenarios) == 2 * 2 * 2 * 3
    assert sw.paths == ("circle", "straight")
    # path-major, then the product in axis order (itertools.product semantics)
    expect = list(itertools.product(["circle", "straight"], [0.01, 0.1], ["lqr", "deadbeat"],
                                    [(1.0, 0.3), (2.0, 0.4), (3.0, 0.5)]))
    for cfg, (p, a, g, (f, v)) in zip(sw.scenarios, expect):
        assert cfg.swept["path"] == p
        assert cfg.mpc.alpha == a and cfg.swept["mpc.alpha"] == a
        assert cfg.gain.type == g
        assert cfg.disturbance.pushes[0].force == f and isinstance(cfg.disturbance.pushes[0].force, float)
        assert cfg.path.params["peak_speed"] == v
        assert cfg.duration == 5.0
    assert sw.scenarios[0].path.params["radius"] == 2.0
    assert "radius" not in sw.scenarios[-1].path.params
    text = sw.describe()
    assert "24" in text and "mpc.alpha" in text and "zip" in text


def test_seeds_depend_only_on_the_scenario():
    a = sweep.parse_sweep(GRID)
    b = sweep.parse_sweep(GRID, limit=5)
    assert [c.seed for c in a.scenarios[:5]] == [c.seed for c in b.scenarios]
    assert len({c.seed for c in a.scenarios}) == len(a.scenarios)
    assert all(0 <= c.seed < 2**31 for c in a.scenarios)
    c = sweep.parse_sweep(GRID.replace("seed = 7", "seed = 8"))
    assert all(x.seed != y.seed for x, y in zip(a.scenarios, c.scenarios))


def test_overrides_and_limit():
    sw = sweep.parse_sweep(GRID, plant="cassie", duration=3.0, limit=3)
    assert len(sw.scenarios) == 3 and sw.total == 24
    assert all(c.plant == "cassie" and c.duration == 3.0 for c in sw.scenarios)
    with pytest.raises(sweep.SweepError, match="--duration: -1 is out of range"):
        sweep.parse_sweep(GRID, duration=-1.0)
    with pytest.raises(sweep.SweepError, match="base.plant"):
        sweep.parse_sweep(GRID, plant="atlas")
    with pytest.raises(sweep.SweepError, match="--limit"):
        sweep.parse_sweep(GRID, limit=0)


def test_path_overrides_apply_to_one_path():
    text = """
[[paths]]
shape = "circle"
[[paths]]
shape = "sinusoid"
[[paths.overrides.obstacles]]
x = 1.0
y = 0.5
radius = 0.2
[grid.product]
"obstacles.0.radius" = [0.1, 0.2]
"""
    # the grid field exists only on the sinusoid: the circle lacks obstacle 0
    with pytest.raises(sweep.SweepError, match=r"path 'circle'.*index 0 does not exist"):
        sweep.parse_sweep(text)
    sw = sweep.parse_sweep(text.split("[grid.product]")[0])
    assert sw.scenarios[0].obstacles == ()
    assert sw.scenarios[1].obstacles == (C.ObstacleConfig(1.0, 0.5, 0.2),)


def test_config_hash_is_stable_and_sensitive():
    a = sweep.parse_sweep(GRID).scenarios
    b = sweep.parse_sweep(GRID).scenarios
    assert sweep.config_hash(a) == sweep.config_hash(b)
    assert sweep.config_hash(a, {"batch": 4}) != sweep.config_hash(a, {"batch": 5})
    c = sweep.parse_sweep(GRID.replace("0.01, 0.1", "0.01, 0.2")).scenarios
    assert sweep.config_hash(a) != sweep.config_hash(c)


def test_missing_file():
    with pytest.raises(sweep.SweepError, match="not found"):
        sweep.load_sweep("/nonexistent/x.toml")


# ------------------------------------------------------------------------------- extends

PARENT = """
name = "parent"
description = "the parent"
[base]
duration = 12.0
seed = 3
[base.hlip]
z0 = 0.8
t_ssp = 0.3
[base.path]
peak_speed = 0.5
[[paths]]
shape = "circle"
radius = 2.0
"""


def test_extends_merges_base_and_keeps_the_childs_name(tmp_path):
    (tmp_path / "parent.toml").write_text(PARENT)
    (tmp_path / "child.toml").write_text('extends = "parent"\n[base.hlip]\nz0 = 0.9\n'
                                         '[grid.product]\n"mpc.alpha" = [0.01, 0.1]\n')
    sw = sweep.load_sweep(tmp_path / "child.toml")
    par = sweep.load_sweep(tmp_path / "parent.toml")
    assert sw.name == "child" and sw.description == "the parent"
    assert len(sw.scenarios) == 2 and len(par.scenarios) == 1
    for c in sw.scenarios:        # deep merge: z0 from the child, t_ssp and the rest inherited
        assert c.hlip.z0 == 0.9 and c.hlip.t_ssp == 0.3 and c.duration == 12.0
        assert c.path == par.scenarios[0].path
    assert [c.mpc.alpha for c in sw.scenarios] == [0.01, 0.1]
    assert "# ---- extends parent ----" in sw.text and 'name = "parent"' in sw.text


def test_extends_paths_replace_the_parents(tmp_path):
    (tmp_path / "parent.toml").write_text(PARENT)
    (tmp_path / "c.toml").write_text('extends = "parent.toml"\n[[paths]]\nshape = "line"\nlength = 3.0\n')
    sw = sweep.load_sweep(tmp_path / "c.toml")
    assert [c.path.shape for c in sw.scenarios] == ["line"]
    assert sw.scenarios[0].duration == 12.0


def test_extends_grid_kinds_replace_one_by_one(tmp_path):
    """A child's grid.product replaces the parent's product and keeps the parent's zip; a
    child's zip replaces the parent's zip."""
    parent = PARENT + ('[[grid.zip]]\n"hlip.z0" = [0.8, 0.9]\n"hlip.t_ssp" = [0.3, 0.35]\n'
                       '[grid.product]\nseed = [1, 2, 3]\n')
    (tmp_path / "parent.toml").write_text(parent)
    (tmp_path / "seeds.toml").write_text('extends = "parent"\n[grid.product]\nseed = [7]\n')
    (tmp_path / "zip.toml").write_text('extends = "parent"\n[[grid.zip]]\n"mpc.alpha" = [0.1, 0.2]\n')
    assert len(sweep.load_sweep(tmp_path / "parent.toml").scenarios) == 6
    sw = sweep.load_sweep(tmp_path / "seeds.toml")
    assert [(c.hlip.z0, c.hlip.t_ssp, c.swept["seed"]) for c in sw.scenarios] == [(0.8, 0.3, 7), (0.9, 0.35, 7)]
    sw = sweep.load_sweep(tmp_path / "zip.toml")
    assert sorted({(c.mpc.alpha, c.hlip.z0) for c in sw.scenarios}) == [(0.1, 0.8), (0.2, 0.8)]
    assert len(sw.scenarios) == 6


@pytest.mark.parametrize("files, start, expect", [
    ({"a.toml": 'extends = "b"', "b.toml": 'extends = "a"'}, "a.toml", "a cycle"),
    ({"a.toml": 'extends = "a"'}, "a.toml", "a cycle"),
    ({"a.toml": 'extends = "missing"'}, "a.toml", "sweep file not found"),
    ({"a.toml": "extends = 3"}, "a.toml", "extends: expected the path of another sweep file"),
    ({"a.toml": 'extends = "b"', "b.toml": "[base\n"}, "a.toml", "not valid TOML"),
    ({f"s{i}.toml": f'extends = "s{i + 1}"' for i in range(12)}, "s0.toml", "more than 8 files"),
    ({"a.toml": 'extends = "b"', "b.toml": "[foo]\nbar = 1\n"}, "a.toml",
     r"a.toml: extends 'b': foo: unknown key \(known keys: name"),
])
def test_extends_errors(tmp_path, files, start, expect):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(sweep.SweepError, match=expect):
        sweep.load_sweep(tmp_path / start)


def test_extends_needs_a_file():
    with pytest.raises(sweep.SweepError, match="only a sweep file can extend"):
        sweep.parse_sweep('extends = "paper.toml"')


def test_replicates_extend_the_paper():
    """docs/experiments/paper_replicates.toml states only what differs from sweeps/paper.toml
    (``extends`` across folders): every scenario is the paper's scenario of the same path with
    the seed, duration and step noise changed."""
    paper = {c.name: c for c in sweep.load_sweep(ROOT / "sweeps" / "paper.toml").scenarios}
    reps = sweep.load_sweep(ROOT / "docs" / "experiments" / "paper_replicates.toml").scenarios
    assert len(reps) == 8 * len(paper)
    for c in reps:
        ref = paper[c.swept["path"]]
        # the base's 20 s; a path's own override (the pushed line's 30 s) still wins
        assert c.duration == (30.0 if c.swept["path"] == "line-push" else 20.0)
        assert c.disturbance.noise_v == 0.02 and c.disturbance.pushes == ref.disturbance.pushes
        assert c.path == ref.path and c.hlip == ref.hlip and c.mpc == ref.mpc and c.gain == ref.gain
        assert c.cassie == ref.cassie and c.obstacles == ref.obstacles


def test_large_grids_are_counted_then_built_on_demand(monkeypatch):
    """Above EAGER_SCENARIOS the scenarios are built on first use, equal to the eager ones."""
    eager = sweep.parse_sweep(GRID, limit=17)
    monkeypatch.setattr(sweep, "EAGER_SCENARIOS", 0)
    lazy = sweep.parse_sweep(GRID, limit=17)
    assert "scenarios" not in vars(lazy), "not built by parsing"
    assert lazy.n_scenarios == eager.n_scenarios == 17 and lazy.total == eager.total
    assert lazy.scenarios == eager.scenarios


def test_validation_points_cover_every_value_and_every_interacting_combination():
    axes = sweep._parse_axes({"product": {"mpc.alpha": [0.1, 0.2, 0.3], "seed": [1, 2],
                                          "duration": [5.0, 6.0], "hlip.t_ssp": [0.3, 0.4]}})
    pts = [tuple(v[0] for v in p) for p in sweep._validation_points(axes)]
    assert {(p[2], p[3]) for p in pts} == {(5.0, 0.3), (5.0, 0.4), (6.0, 0.3), (6.0, 0.4)}
    assert {p[0] for p in pts} == {0.1, 0.2, 0.3} and {p[1] for p in pts} == {1, 2}
    assert len(pts) == 4 + 2 + 1, "independent axes are not multiplied out"


@pytest.mark.parametrize("n,ok", [(11, True), (12, False)])
def test_the_scenario_limit_is_exclusive(n, ok, monkeypatch):
    """MAX_SCENARIOS is the first grid size refused; the count needs no expansion."""
    monkeypatch.setattr(sweep, "MAX_SCENARIOS", 12)
    text = ('[[paths]]\nshape = "circle"\n[grid.product]\n"seed" = [%s]\n'
            % ", ".join(map(str, range(n))))
    if ok:
        assert sweep.parse_sweep(text).total == 11
    else:
        with pytest.raises(sweep.SweepError, match="12 scenarios.*fewer than 12"):
            sweep.parse_sweep(text)


def test_path_names_and_slugs():
    assert sweep.file_slug("a b") == sweep.file_slug("a_b") == "a_b"
    # the report names its figures with file_slug itself; the slugs, spelled out
    for name, slug in (("a b", "a_b"), ("x+y", "x_y"), ("run.", "run"), ("circle-2", "circle-2"),
                       ("_z_", "z")):
        assert sweep.file_slug(name) == slug, name


def test_aliases_of_one_field_are_swept_twice():
    """`pushes.0` and `pushes.00` name the same push: sweeping both is refused (before, the
    names and summary said one force while the other was simulated)."""
    text = ('[base]\nduration = 10.0\n[[base.disturbance.pushes]]\ntime = 2.0\n'
            '[[paths]]\nshape = "line"\n[grid.product]\n'
            '"disturbance.pushes.0.force" = [100.0, 200.0]\n'
            '"disturbance.pushes.00.force" = [300.0]\n')
    with pytest.raises(sweep.SweepError, match="swept twice"):
        sweep.parse_sweep(text)


def test_an_axis_of_too_many_values_is_refused_at_once():
    values = ", ".join(str(i) for i in range(sweep.MAX_AXIS_VALUES + 1))
    with pytest.raises(sweep.SweepError, match="at most 100000 per axis"):
        sweep.parse_sweep(f'[[paths]]\nshape = "line"\n[grid.product]\nseed = [{values}]\n')


@pytest.mark.parametrize("text,frag", [
    ('[base]\nduration = ' + "9" * 400 + '\n[[paths]]\nshape = "line"\n', "400 digits"),
    ('[[paths]]\nshape = "circle"\nradius = ' + "9" * 400 + '\n', "400 digits"),
    ('[base]\nseed = ' + "9" * 5000 + '\n[[paths]]\nshape = "line"\n', "too long to read"),
    ('[base]\nduration = 10.0\n[[base.disturbance.pushes]]\ntime = 2.0\n[[paths]]\n'
     'shape = "line"\n[grid.product]\n"disturbance.pushes.\u0660.force" = [100.0]\n',
     "needs an index"),
])
def test_numbers_out_of_reach_and_non_ascii_indices_are_one_line(text, frag):
    """An integer beyond float's range, one over Python's 4300-digit limit, and an Arabic-Indic
    digit as a list index: each a SweepError naming what is wrong (they were tracebacks, or
    for the digit a silently accepted index)."""
    with pytest.raises(sweep.SweepError, match=frag):
        sweep.parse_sweep(text)
