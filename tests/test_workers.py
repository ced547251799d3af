"""The worker pool of hlip_jax.runtime.workers: kept between maps, replaced when the count
changes, ended by close(), and a dead worker never loses the map's results."""

from __future__ import annotations

import os
import signal
import time

from hlip_jax.runtime import workers


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                                   # a zombie that was not reaped yet counts as ended
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _pids(n_calls: int, n_workers: int) -> set[int]:
    return set(workers.starmap(os.getpid, [()] * n_calls, n_workers))


def test_the_pool_is_kept_between_maps_and_closed_on_request():
    try:
        first = _pids(6, 2)
        assert os.getpid() not in first and 1 <= len(first) <= 2
        again = _pids(6, 2)
        assert again <= first | again and again & first          # the same processes serve
        assert len(first | again) <= 2
        three = _pids(9, 3)                                       # another count: a new pool
        assert not three & (first | again)
        assert not any(_alive(p) for p in first | again)
    finally:
        workers.close()
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in three) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in three)


def test_a_killed_worker_costs_the_pool_not_the_results():
    try:
        pids = _pids(6, 2)
        for p in pids:
            os.kill(p, signal.SIGKILL)
        time.sleep(0.2)
        assert workers.starmap(abs, [(-1,), (-2,), (-3,)], 2) == [1, 2, 3]
        after = _pids(6, 2)                                       # a fresh pool
        assert after and not after & pids and os.getpid() not in after
    finally:
        workers.close()


def test_a_process_that_kept_a_pool_exits_without_a_word(tmp_path):
    """The kept pool is ended at exit, before the interpreter tears its modules down (a pool
    collected during teardown prints 'Exception ignored ...' on stderr)."""
    import subprocess
    import sys
    script = tmp_path / "keep.py"
    script.write_text("import os\nfrom hlip_jax.runtime import workers\n"
                      "if __name__ == '__main__':\n"
                      "    print(len(set(workers.starmap(os.getpid, [()] * 4, 2))))\n")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() in ("1", "2"), r.stderr
    assert r.stderr == "", r.stderr
