"""Code the tests share, and the one way a test reaches a benchmark script.

Helpers that tests and benchmark scripts both use live here, one module per concept:

* :mod:`support.cassie_cpu_reference` — the CPU reference of the standing CLF-QP controller
  (C MuJoCo + numpy + OSQP, one robot per tick);
* :mod:`support.cassie_orbits` — orbit walking of the Cassie plant without the MPC;
* :mod:`support.jaxpr_census` — a function's jaxpr equations counted by primitive and source
  line, and grouped by source file.

The tests import them as ``support.<module>`` (pytest puts ``tests/`` on the path); a benchmark
script puts the repository root on its path and imports ``tests.support.<module>``.

A test of a benchmark script itself (its command line, its output) loads the script with
:func:`load_benchmark`, from its file, without putting ``benchmarks/`` on ``sys.path``.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = ROOT / "benchmarks"


def load_benchmark(name: str) -> ModuleType:
    """The benchmark script ``benchmarks/<name>.py`` as a module (loaded once, then the same
    module object; registered in ``sys.modules`` under ``name`` so that its dataclasses and
    pickled functions resolve)."""
    path = BENCHMARKS / f"{name}.py"
    loaded = sys.modules.get(name)
    if loaded is not None and Path(getattr(loaded, "__file__", "") or "").resolve() == path:
        return loaded
    if not path.is_file():
        raise FileNotFoundError(f"no benchmark script {path}")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module
