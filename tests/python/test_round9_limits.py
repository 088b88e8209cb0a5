"""Round 9 of the held-out battery, the library's checks seen from Python (the C++ prober's findings, whose
root causes were in the library: tests/bad_input_round9.rs and cpp/tests/test_errors.cpp hold the rest): a
distortion grid 1e-12 mm wide reported 200 % distortion, a mapping cube 1e300 mm across came back all
invalid without an error, and the denoiser allocated its activations before any memory budget."""
import numpy as np
import pytest

import diffcassi


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


def test_a_distortion_grid_narrower_than_a_micrometre_is_refused():
    sp = diffcassi.System.preset("sp")
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"half width 1e-12 mm: must be in \[1e-3"):
        diffcassi.distortion(sp, 520.0, 5, 1e-12)
    ok = diffcassi.distortion(sp, 520.0, 3, 1e-3)
    assert np.isfinite(ok["max_distortion_pct"]) and abs(ok["max_distortion_pct"]) < 1.0


def test_the_denoiser_checks_the_memory_budget_before_allocating(default_limits):
    cube = np.full((64, 64, 28), 0.5, dtype=np.float32)
    diffcassi.set_limits(max_memory_gb=1e-4)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"denoiser on a 64×64×28 cube .*max_memory_gb"):
        diffcassi.denoise(cube, 0.05)
    diffcassi.set_limits()
    out = diffcassi.denoise(cube, 0.05)
    assert out.shape == cube.shape and np.isfinite(out).all()
