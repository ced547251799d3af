"""XLA settings the CLI makes before JAX starts: reproducible GPU runs, every CPU core at work.

**Deterministic GPU operations.** On a GPU, XLA implements scatters and some reductions with
atomic additions whose order varies from run to run.  The closed loop is chaotic, so those
last-bit differences grow: runs of the same five paper scenarios on one H200 differed by
up to 10 cm in the COM after ten steps (docs/benchmarks/sweeps.md, "GPU runs repeat bit for bit").
``--xla_gpu_deterministic_ops=true`` makes XLA use order-fixed implementations; with it the two
runs were equal bit for bit, at the same speed for that batch.  The CPU backend ignores it
(its operations are deterministic).

**One CPU device per core.** XLA runs the closed loop's small batched operations on one
core: on the 2-core machine a sweep ran faster pinned to one core than free on two.  With
``--xla_force_host_platform_device_count=N`` (N = the cores this process may use) the CPU
backend has N devices and a sweep's scenarios are split over them, each device running its
share of the loop on its own core (:func:`hlip_jax.simulation.execution.run`; 1.2–1.4× on 2 cores,
docs/benchmarks/sweeps.md, "CPU cores as devices").  jaxlib 0.10's LAPACK kernels wait on XLA's CPU
thread pool for their batch's tasks; with every pool thread busy running a device's program
none is left for those tasks and the process hangs, so the pool is given 2N threads
(``PJRT_NPROC``; jaxlib 0.11 no longer splits the batch).

Each setting is added only where the user's environment does not already choose it
(``XLA_FLAGS`` naming the flag, ``PJRT_NPROC`` or ``NPROC`` set to a count in ASCII digits:
a value such as ``²`` counts as unset).

**Flags XLA would abort on.** XLA parses ``XLA_FLAGS`` when JAX starts its backend and ends
the process on a value it cannot read (a device count of ``abc`` or ``²`` prints its whole flag
listing and exits 1; ``0`` or ``-1`` fails to start the CPU backend).  :func:`problem` checks
the two flags this module reads or sets before that: each device count must be a count of
:data:`MAX_CPU_DEVICES` or fewer in ASCII digits, each ``--xla_gpu_deterministic_ops`` value
``true`` or ``false`` (or ``1``/``0``); a flag XLA does not know (it logs "Unknown flag in
XLA_FLAGS" and ends the process) is found by :func:`refused` in a probe process; :func:`apply`
refuses each in one line, exit 2.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from typing import MutableMapping

FLAG = "--xla_gpu_deterministic_ops"
DEVICES_FLAG = "--xla_force_host_platform_device_count"
POOL_VARS = ("PJRT_NPROC", "NPROC")     # read by the CPU client for its thread pool's size


def _sets(flags: str, flag: str) -> bool:
    return any(f.split("=", 1)[0] == flag for f in flags.split())


def with_flag(flags: str, flag: str, value: str) -> str:
    """``flags`` (an XLA_FLAGS value) with ``flag=value`` appended, unless it sets ``flag``."""
    if _sets(flags, flag):
        return flags
    return f"{flags} {flag}={value}".strip()


def with_deterministic_ops(flags: str) -> str:
    """``flags`` with ``FLAG=true`` appended, unless it already sets FLAG."""
    return with_flag(flags, FLAG, "true")


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:           # not on Linux
        return os.cpu_count() or 1


class PoolTooSmall(RuntimeError):
    """A batch split over at least as many CPU devices as XLA's CPU thread pool has threads
    (the user's own ``PJRT_NPROC``/``NPROC``): jaxlib < 0.11 would hang."""


def _is_count(text: str) -> bool:
    """Whether ``text`` is a count in ASCII digits (``int`` refuses '²', which ``isdigit``
    accepts)."""
    return text.isascii() and text.isdigit()


def cpu_pool_threads(environ: MutableMapping[str, str] = os.environ) -> int:
    """Threads of XLA's CPU thread pool as ``environ`` sizes it (:data:`POOL_VARS`, else one
    per usable core)."""
    return next((int(environ[v]) for v in POOL_VARS if _is_count(environ.get(v, ""))),
                usable_cores())


def cpu_devices(flags: str) -> int:
    """The CPU devices ``flags`` ask for (1 where they do not set :data:`DEVICES_FLAG`)."""
    for f in flags.split():
        name, _, value = f.partition("=")
        if name == DEVICES_FLAG and _is_count(value.strip()):
            return max(1, int(value))
    return 1


#: the most CPU devices a device count may ask for (each is a thread pool's worth of work)
MAX_CPU_DEVICES = 4096

#: the most threads a user's pool size (:data:`POOL_VARS`) may ask for: XLA's CPU client starts
#: them all at once (``NPROC=100000`` ran 300 s without a word before it was killed)
MAX_POOL_THREADS = 4096


def pool_problem(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Why the user's pool size in ``environ`` (:data:`POOL_VARS`) would stall XLA's CPU
    client, or None: a count in ASCII digits above :data:`MAX_POOL_THREADS`.  One line naming
    the variable and what is allowed."""
    for v in POOL_VARS:
        text = environ.get(v, "")
        if _is_count(text) and int(text) > MAX_POOL_THREADS:
            return (f"{v}={text[:40]!r}: too many threads for XLA's CPU thread pool (it starts "
                    f"them all at once); allowed: an integer from 1 to {MAX_POOL_THREADS} in "
                    f"ASCII digits, or unset {v}")
    return None


#: the values XLA reads as a boolean flag's (lower-cased)
_BOOLS = ("true", "false", "1", "0")


def problem(flags: str) -> str | None:
    """Why XLA would refuse the ``XLA_FLAGS`` value ``flags`` at start-up, for the flags this
    module reads or sets (:data:`DEVICES_FLAG`, :data:`FLAG`), or None: a device count that
    is not a count from 1 to :data:`MAX_CPU_DEVICES` in ASCII digits, a deterministic-ops
    value other than true/false/1/0.  One line naming ``XLA_FLAGS`` and what is allowed."""
    for f in flags.split():
        name, eq, value = f.partition("=")
        if name == DEVICES_FLAG and not (_is_count(value) and 1 <= int(value) <= MAX_CPU_DEVICES):
            return (f"XLA_FLAGS: {DEVICES_FLAG}={value[:40]!r} is not a device count; allowed: "
                    f"an integer from 1 to {MAX_CPU_DEVICES} in ASCII digits, e.g. {DEVICES_FLAG}=2")
        if name == FLAG and eq and value.lower() not in _BOOLS:
            return (f"XLA_FLAGS: {FLAG}={value[:40]!r} is not a boolean; allowed: {FLAG}=true or "
                    f"{FLAG}=false")
    return None


def refused(flags: str, environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Whether XLA would end the process on ``flags`` for a flag it does not know: a fatal log
    line ("Unknown flag in XLA_FLAGS"), not an exception, when the backend starts.  Asked of a
    separate Python process that starts JAX's CPU backend with ``flags`` (about a second),
    and only when ``flags`` names a flag other than the two this module reads
    (:data:`DEVICES_FLAG`, :data:`FLAG`).  None, or one line naming ``XLA_FLAGS``, the flag
    and what to do; a probe that fails for another reason says nothing (the run goes on)."""
    extra = [f for f in flags.split() if f.partition("=")[0] not in (DEVICES_FLAG, FLAG)]
    if not extra:
        return None
    env = dict(environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    try:
        r = subprocess.run([sys.executable, "-c", "import jax; jax.devices()"], env=env,
                           capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"Unknown flags? in XLA_FLAGS: *(\S.*)", r.stderr)
    if r.returncode == 0 or m is None:
        return None
    return (f"XLA_FLAGS: {ascii(m.group(1).strip()[:80])} is not a flag of the installed XLA "
            "(XLA would end the process); allowed: the flags XLA lists for this jaxlib (remove "
            "it or unset XLA_FLAGS)")


class FlagsError(ValueError):
    """A user's ``XLA_FLAGS`` that XLA would abort on (the message names the flag and what is
    allowed, :func:`problem`)."""


def apply(environ: MutableMapping[str, str] = os.environ, cores: int | None = None) -> None:
    """Set ``environ`` as the module doc says (call before the first JAX computation: XLA
    reads the variables when the backend starts).  ``cores`` defaults to
    :func:`usable_cores`.  A user's ``XLA_FLAGS`` that XLA would abort on (:func:`problem`)
    is refused with :class:`FlagsError` (the CLI reports it as one line on stderr, exit 2),
    ``environ`` left as it was; so is a pool size XLA would stall on (:func:`pool_problem`)."""
    why = (problem(environ.get("XLA_FLAGS", "")) or pool_problem(environ)
           or refused(environ.get("XLA_FLAGS", ""), environ))
    if why is not None:
        raise FlagsError(why)
    cores = usable_cores() if cores is None else cores
    flags = with_deterministic_ops(environ.get("XLA_FLAGS", ""))
    if cores > 1:
        flags = with_flag(flags, DEVICES_FLAG, str(cores))
    environ["XLA_FLAGS"] = flags
    devices = cpu_devices(flags)
    if devices > 1 and not any(_is_count(environ.get(v, "")) for v in POOL_VARS):
        environ[POOL_VARS[0]] = str(2 * max(devices, cores))
