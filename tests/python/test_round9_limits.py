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


# ---------------------------------------------------------------- a third prober (render, ddsp, co-design)
def test_a_float64_cube_cannot_give_the_mask_logits_an_inf_gradient():
    import torch
    import diffcassi.torch as dt
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), 8, 8, free=["glass_nd:N-BK7"], rays=1, planes=4, seed=0)
    x = torch.full((1, 28, 8, 8), 1e20, dtype=torch.float64, requires_grad=True)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"the gradient of mask_logits would leave torch.float32.s range"):
        r(x).pow(2).mean().backward()
    assert r.mask_logits.grad is None  # nothing accumulated
    r(torch.full((1, 28, 8, 8), 0.5, dtype=torch.float64)).pow(2).mean().backward()
    assert torch.isfinite(r.mask_logits.grad).all()


def test_a_greyscale_mask_is_rendered_at_the_steps_it_is_recorded_with():
    sp = diffcassi.System.preset("sp")
    cube, wl = diffcassi.synthetic_scene(16, 16, seed=2)
    m = np.random.default_rng(5).random((16, 16)).astype(np.float32)
    steps = (np.floor(m * np.float32(65535) + np.float32(0.5)).astype(np.uint16).astype(np.float32) / np.float32(65535))
    a, info = diffcassi.render(sp, cube, wl, m, planes=4, rays=2)
    b, info_b = diffcassi.render(sp, cube, wl, steps, planes=4, rays=2)
    assert np.array_equal(a, b) and info["mask_png_sha256"] == info_b["mask_png_sha256"]
    t = diffcassi.Transport(sp, 16, 16, mask=m, planes=4, rays=2)
    assert np.array_equal(t.mask, steps)


def test_render_warns_as_the_cli_of_zero_acquisitions_and_exposures_below_an_electron():
    sp = diffcassi.System.preset("sp")
    cube, wl = diffcassi.synthetic_scene(16, 16, seed=2)
    with pytest.warns(UserWarning, match=r"the exposure puts .*\(< 1 electron.*zero everywhere"):
        acq, _ = diffcassi.render(sp, cube, wl, planes=4, rays=2, noise={"noise": "shot", "electrons_per_unit": 1e-300})
    assert not acq.any()
    with pytest.warns(UserWarning, match=r"zero everywhere \(no ray was traced: the mask is closed everywhere\)"):
        diffcassi.render(sp, cube, wl, np.zeros((16, 16), np.float32), planes=4, rays=2)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        diffcassi.render(sp, cube, wl, planes=4, rays=2, noise="shot")
