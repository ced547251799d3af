"""The package's import graph, read from the source with :mod:`ast` (nothing is imported).

Every ``import`` counts, also one inside a function (a lazy import is still a dependency).
The rules of issue #53:

* no cycle of modules;
* no cycle of rooms, where a room is a top-level module or a top-level subpackage taken whole
  (a layer: ``hlip_jax.core``, ``hlip_jax.plants``, ...): an import from a subpackage back into
  a module that imports the subpackage runs back up a layer;
* no import into a higher layer or across one level (:data:`LAYERS`, bottom to top: core and
  runtime; analysis and plants; simulation; sweep I/O; presentation), and every module of the
  package lives in a layer;
* no module outside ``hlip_jax.plants`` imports one plant's modules: the layers above reach a
  plant through the registry (``plants.load``, ``plants.tools``) and its interface
  (``plants.base``);
* no private names across modules: ``from hlip_jax.X import _y`` or ``X._y`` with X another
  hlip_jax module.  A module's own tests may use its private names; other modules may not;
* the sets and the MPC (``sets``, ``invariant``, ``robust``, ``mpc``) never import the
  statistics pipeline (``hlip_jax.analysis``), which imports them;
* no test module changes ``sys.path``: shared test code lives in ``tests/support`` and a
  benchmark script is loaded with ``support.load_benchmark``.

Violations in modules that are still to be reworked are listed in the allow-lists below,
each with its issue, so that a new one fails the test and a fixed one must leave the list.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = "hlip_jax"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE
TESTS = Path(__file__).resolve().parent

ALLOWED_PRIVATE: set = set()

ALLOWED_ROOM_CYCLES: set = set()

#: the layers, bottom to top: a module imports only from its own room or a lower level
LAYERS = {"hlip_jax.core": 0, "hlip_jax.runtime": 0, "hlip_jax.analysis": 1, "hlip_jax.plants": 1,
          "hlip_jax.simulation": 2, "hlip_jax.sweepio": 3, "hlip_jax.presentation": 4}
#: the package's own entry points, above every layer
TOP = {"hlip_jax", "hlip_jax.__main__"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        out[_module_name(path)] = (path, ast.parse(path.read_text(encoding="utf-8"), str(path)))
    return out


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module of ``from <node.module> import ...`` written in ``module``."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    base = base[:len(base) - node.level + (1 if is_package else 0)]
    return ".".join(base + ([node.module] if node.module else []))


def _scan(modules):
    """(edges, private uses): edges = {module: {imported hlip_jax module}}; private uses =
    {(module, other module, name)}."""
    edges = {m: set() for m in modules}
    private = set()
    for mod, (path, tree) in modules.items():
        is_package = path.name == "__init__.py"
        alias = {}          # local name -> hlip_jax module it is bound to (anywhere in the file)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.split(".")[0] != PACKAGE:
                        continue
                    target = a.name
                    while target not in modules and "." in target:
                        target = target.rpartition(".")[0]
                    edges[mod].add(target)
                    if a.asname:
                        alias[a.asname] = a.name
                    else:
                        alias[PACKAGE] = PACKAGE
            elif isinstance(node, ast.ImportFrom):
                src = _absolute(mod, is_package, node)
                if src.split(".")[0] != PACKAGE:
                    continue
                for a in node.names:
                    sub = f"{src}.{a.name}"
                    if sub in modules:                  # from package import module
                        edges[mod].add(sub)
                        alias[a.asname or a.name] = sub
                        continue
                    owner = src
                    while owner not in modules and "." in owner:
                        owner = owner.rpartition(".")[0]
                    edges[mod].add(owner)
                    if _is_private(a.name) and owner != mod:
                        private.add((mod, owner, a.name))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _is_private(node.attr):
                dotted = _dotted(node.value, alias)
                if dotted in modules and dotted != mod:
                    private.add((mod, dotted, node.attr))
        edges[mod].discard(mod)
    return edges, private


def _dotted(node, alias):
    """The hlip_jax module an expression ``a.b.c`` names through the file's imports, or None."""
    if isinstance(node, ast.Name):
        return alias.get(node.id)
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value, alias)
        return f"{head}.{node.attr}" if head else None
    return None


def _cycles(edges) -> list[frozenset]:
    """Strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def _room(module: str) -> str:
    return ".".join(module.split(".")[:2])


def _room_edges(edges):
    rooms = {}
    for a, targets in edges.items():
        for b in targets:
            ra, rb = _room(a), _room(b)
            if ra != rb and PACKAGE not in (ra, rb):
                rooms.setdefault(ra, set()).add(rb)
    return rooms


def test_graph_is_read():
    """The scan sees the imports it is meant to (function-level ones included)."""
    edges, _ = _scan(_modules())
    assert "hlip_jax.core.sets" in edges["hlip_jax.core.invariant"]
    assert "hlip_jax.runtime.trace_cache" in edges["hlip_jax.runtime.compile_cache"]      # inside enable()
    assert "hlip_jax.analysis.estimators" in edges["hlip_jax.analysis.settings"]   # lazy


def test_no_module_cycles():
    edges, _ = _scan(_modules())
    assert _cycles(edges) == []


def test_no_room_cycles():
    edges, _ = _scan(_modules())
    found = set(_cycles(_room_edges(edges)))
    assert found - ALLOWED_ROOM_CYCLES == set(), "new cycle between rooms"
    assert ALLOWED_ROOM_CYCLES - found == set(), "fixed: remove it from ALLOWED_ROOM_CYCLES"


def _upward(edges) -> set:
    """(importer, imported) pairs that go up or across the layers (or into no layer)."""
    return {(a, b) for a, targets in edges.items() for b in targets
            if _room(a) in LAYERS and _room(b) != _room(a)
            and (_room(b) not in LAYERS or LAYERS[_room(b)] >= LAYERS[_room(a)])}


def _direct_plant_imports(edges) -> set:
    """(importer, imported) pairs where a module outside hlip_jax.plants imports one plant's
    own module (anything under hlip_jax.plants but the registry and hlip_jax.plants.base)."""
    return {(a, b) for a, targets in edges.items() for b in targets
            if _room(a) != "hlip_jax.plants" and b.startswith("hlip_jax.plants.")
            and b != "hlip_jax.plants.base"}


def test_layers_import_only_downwards():
    """Every module is in a layer; an import goes to the same room or a lower level."""
    edges, _ = _scan(_modules())
    assert {_room(m) for m in edges} - set(LAYERS) == TOP, "a module outside the layers"
    assert _upward(edges) == set(), "an import up or across the layers"


def test_generic_modules_reach_plants_through_the_registry():
    """Outside hlip_jax.plants only the registry (hlip_jax.plants) and the plant interface
    (hlip_jax.plants.base) are imported, never one plant's own modules."""
    edges, _ = _scan(_modules())
    assert _direct_plant_imports(edges) == set()


def test_layer_rules_catch_a_violation():
    """The two rules fail on an upward import, an import across one level and a direct plant
    import, and pass the registry and a downward import."""
    edges = {"hlip_jax.core.sets": {"hlip_jax.sweepio.store", "hlip_jax.core.hlip"},
             "hlip_jax.analysis.coverage": {"hlip_jax.plants", "hlip_jax.core.sets"},
             "hlip_jax.presentation.cli": {"hlip_jax.plants.cassie.model", "hlip_jax.plants",
                                           "hlip_jax.plants.base"}}
    assert _upward(edges) == {("hlip_jax.core.sets", "hlip_jax.sweepio.store"),
                              ("hlip_jax.analysis.coverage", "hlip_jax.plants")}
    assert _direct_plant_imports(edges) == {("hlip_jax.presentation.cli",
                                             "hlip_jax.plants.cassie.model")}


def test_no_private_names_across_modules():
    _, private = _scan(_modules())
    assert private - ALLOWED_PRIVATE == set(), "a module uses another module's private name"
    assert ALLOWED_PRIVATE - private == set(), "fixed: remove it from ALLOWED_PRIVATE"


def test_sets_and_mpc_do_not_import_analysis():
    """The sets and the MPC (sets, invariant, robust, mpc) never import the statistics
    pipeline (hlip_jax.analysis), which imports them."""
    edges, _ = _scan(_modules())
    for core in ("hlip_jax.core.sets", "hlip_jax.core.invariant", "hlip_jax.core.robust", "hlip_jax.core.mpc"):
        assert not {m for m in edges[core] if _room(m) == "hlip_jax.analysis"}, core


def _sys_path_changes(tree: ast.Module) -> list[int]:
    """Lines of ``sys.path.<insert|append|extend|...>(...)``, ``sys.path = ...``,
    ``sys.path += ...`` and ``sys.path[...] = ...`` in a module."""
    def is_sys_path(node):
        return (isinstance(node, ast.Attribute) and node.attr == "path"
                and isinstance(node.value, ast.Name) and node.value.id == "sys")

    lines = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and is_sys_path(node.func.value)):
            lines.append(node.lineno)
        elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if is_sys_path(t) or (isinstance(t, ast.Subscript) and is_sys_path(t.value)):
                    lines.append(node.lineno)
    return sorted(lines)


def test_sys_path_scan_sees_an_insert():
    tree = ast.parse("import sys\nsys.path.insert(0, 'benchmarks')\nsys.path += ['x']\n")
    assert _sys_path_changes(tree) == [2, 3]


def test_no_test_module_changes_sys_path():
    """Tests share code through ``tests/support`` (``from support import ...``) and load a
    benchmark script with ``support.load_benchmark(name)``; none puts a folder on
    ``sys.path`` itself."""
    found = [f"{path.relative_to(TESTS.parent)}:{line}"
             for path in sorted(TESTS.rglob("*.py"))
             for line in _sys_path_changes(ast.parse(path.read_text(encoding="utf-8"), str(path)))]
    assert found == [], ("a test module changes sys.path (" + ", ".join(found) + "): put shared "
                         "code in tests/support and import it as `from support import ...`; "
                         "load a benchmark script with `support.load_benchmark(name)`")
