"""A `fork`-context multiprocessing pool that renders after the parent used diffcassi's thread pool (rayon's
workers do not exist in a fork child; before the fix the child waited for them forever). Each pool runs in
a subprocess with a timeout, so a regression fails instead of hanging the suite."""
import subprocess
import sys
import textwrap

import pytest

from conftest import ROOT

SCRIPT = textwrap.dedent("""
    import multiprocessing as mp, sys
    import numpy as np, diffcassi
    threads = int(sys.argv[1])
    if threads:
        diffcassi.set_num_threads(threads)
    sp = diffcassi.System.preset("sp")
    wl = [480.0, 520.0, 560.0, 600.0]
    cube = np.random.default_rng(0).random((8, 8, 4), dtype=np.float32)
    # The parent uses the pool first (its workers exist in the parent only).
    ref, _ = diffcassi.render(sp, cube, wl, planes=8, rays=4)

    def work(seed):
        acq, _ = diffcassi.render(sp, cube, wl, planes=8, rays=4)
        return float(np.abs(acq - ref).max()), diffcassi.get_num_threads()

    with mp.get_context("fork").Pool(2) as pool:
        out = pool.map(work, range(4))
    assert all(d == 0.0 for d, _ in out), out
    expect = threads or None
    assert all(n >= 1 and (expect is None or n == expect) for _, n in out), out
    print("ok", out)
""")


@pytest.mark.parametrize("threads", [0, 2])
def test_fork_pool_renders_after_the_parent_used_the_pool(threads):
    # threads 0: rayon's global pool in the parent; 2: a pool of set_num_threads.
    try:
        r = subprocess.run([sys.executable, "-c", SCRIPT, str(threads)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("the fork-context pool hung (the child waited for the parent's rayon threads)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ok"), r.stdout
