"""Round 21 of the held-out battery, prober `cpp` (the C++ API at its extremes, and the wheel): the Python side.

- Finding 9: a build without Embree (the wheel) refuses an ``embree-*`` backend of ``trace``, ``jacobian`` and
  ``mapping`` with the documented fix, through ``_check_backend`` (simulated here with ``EMBREE = False``).
- Finding 10: without PyTorch, ``import diffcassi.unrolled`` / ``diffcassi.denoiser`` say what they need.
- Finding 7: budgets that protect nothing are refused by ``set_limits`` (the library's check, shared with the CLI
  and C++).
- Finding 2 (shared): the pool's fork handling now lives in the library; Python's fork children still trace,
  bit-identically.
"""
import os
import subprocess
import sys

import numpy as np
import pytest

import diffcassi

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FIX = "this diffcassi was built without Embree; install Embree 4.3 (bash scripts/setup.sh) and reinstall (pip install .), or use backend='analytic'"


@pytest.fixture()
def no_embree(monkeypatch):
    monkeypatch.setattr(diffcassi, "EMBREE", False)


@pytest.mark.parametrize("backend", ["embree-user", "embree-mesh:0.5", "embree-user:f64"])
def test_embree_less_build_names_the_documented_fix(no_embree, backend):
    sp = diffcassi.System.preset("sp")
    o = np.zeros((2, 3))
    d = np.tile([0.0, 0.0, 1.0], (2, 1))
    w = np.full(2, 520.0)
    calls = {
        "trace": lambda: diffcassi.trace(sp, o, d, w, backend=backend),
        "trace positional": lambda: diffcassi.trace(sp, o, d, w, backend),
        "jacobian": lambda: diffcassi.jacobian(sp, "wavelength", o, d, w, backend=backend),
        "mapping": lambda: diffcassi.mapping(sp, 2, 2, [520.0], backend=backend),
    }
    for name, call in calls.items():
        with pytest.raises(diffcassi.DiffcassiValueError) as e:
            call()
        msg = str(e.value)
        assert FIX in msg and f"backend `{backend}`" in msg and "rebuild with" not in msg, (name, msg)


def test_wrapped_calls_still_trace_as_the_native_ones():
    sp = diffcassi.System.preset("sp")
    o = np.zeros((3, 3))
    d = np.tile([0.0, 0.0, 1.0], (3, 1))
    w = np.full(3, 520.0)
    a = diffcassi.trace(sp, o, d, w)
    b = diffcassi._native.trace(sp, o, d, w, "analytic")
    assert all(np.array_equal(a[k], b[k]) for k in b)
    pos, valid = diffcassi.mapping(sp, 2, 2, [520.0], 0.01, "analytic")
    pos2, valid2 = diffcassi._native.mapping(sp, 2, 2, [520.0], 0.01, "analytic")
    assert np.array_equal(pos, pos2) and np.array_equal(valid, valid2)
    j = diffcassi.jacobian(sp, ["wavelength"], o, d, w)
    assert j["jacobian"].shape == (3, 6, 1)
    with pytest.raises(diffcassi.DiffcassiValueError, match="backend: expected a string"):
        diffcassi.trace(sp, o, d, w, backend=3)


@pytest.mark.parametrize("module", ["diffcassi.unrolled", "diffcassi.denoiser", "diffcassi.torch"])
def test_torch_modules_say_they_need_pytorch(module):
    code = ("import sys; sys.modules['torch'] = None\n"
            f"try:\n    import {module}\nexcept ImportError as e:\n    print(type(e).__name__, '|', e)\n"
            "else:\n    print('imported')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/tmp",
                         env={**os.environ, "PYTHONPATH": ROOT}, timeout=120)
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip().splitlines()[-1]
    assert line == f"ImportError | {module} needs PyTorch: pip install torch", line


@pytest.mark.parametrize("kw, fragment", [
    (dict(max_memory_gb=1e300), "max_memory_gb=1e300: beyond the 140737 GB"),
    (dict(max_memory_gb=2e5), "max_memory_gb=200000: beyond the 140737 GB"),
    (dict(max_rays=1.5), "max_rays=1.5: must be a whole number of rays"),
    (dict(max_rays=1e17), "max_rays=1e17: must be a whole number of rays, 1..=9007199254740992"),
])
def test_budgets_that_protect_nothing_are_refused(kw, fragment):
    before = diffcassi.get_limits()
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.set_limits(**kw)
    assert fragment in str(e.value), str(e.value)
    assert diffcassi.get_limits() == before


def test_cli_refuses_the_same_budgets():
    cli = os.path.join(ROOT, "target", "release", "diffcassi")
    if not os.path.exists(cli):
        pytest.skip("no target/release/diffcassi")
    out = subprocess.run([cli, "--max-memory-gb", "1e300", "info", "--preset", "sp"], capture_output=True, text=True, timeout=60)
    assert out.returncode != 0 and "--max-memory-gb 1e300: beyond the 140737 GB" in out.stderr, out.stderr
    out = subprocess.run([cli, "--max-rays", "2.5", "info", "--preset", "sp"], capture_output=True, text=True, timeout=60)
    assert out.returncode != 0 and "--max-rays 2.5: must be a whole number of rays" in out.stderr, out.stderr


def test_fork_child_traces_bit_identically_with_the_library_pool():
    if not hasattr(os, "fork"):
        pytest.skip("no fork")
    sp = diffcassi.System.preset("sp")
    rng = np.random.default_rng(0)
    n = 2000
    o = np.zeros((n, 3))
    d = np.column_stack([rng.uniform(-0.02, 0.02, n), rng.uniform(-0.02, 0.02, n), np.ones(n)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    w = np.full(n, 520.0)
    parent = diffcassi.trace(sp, o, d, w)
    r, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(r)
        import signal
        signal.alarm(20)
        try:
            child = diffcassi.trace(sp, o, d, w)
            ok = all(np.array_equal(child[k], parent[k]) for k in parent)
            os.write(wfd, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.close(wfd)
    got = os.read(r, 1)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    assert got == b"1", (got, status)
