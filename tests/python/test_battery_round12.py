"""Round 12 of the held-out battery, seen from Python (tests/bad_input_round12.rs holds the command line's side):
an f32 render measures its own rounding (``info["f32_chief_ray_error"]``), a device render of a
high-dynamic-range scene warns that the fixed-point accumulation resolves its dim regions coarsely, and the
host-only calls refuse ``device="cuda"`` for what they are rather than for a missing driver."""
import warnings

import numpy as np
import pytest

import diffcassi

SMALL = dict(bands_nm=[450.0, 550.0, 650.0], planes=4, rays=2)


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


def test_an_f32_render_records_its_measured_rounding(sp):
    cube, wl = diffcassi.synthetic_scene(8, 8, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, info = diffcassi.render(sp, cube, wl, precision="f32", **SMALL)
    f = info["f32_chief_ray_error"]
    assert 0 < f["error_um"] < f["threshold_um"] == 0.1 and f["rays"] == 27 and "message" not in f
    _, info = diffcassi.render(sp, cube, wl, **SMALL)
    assert "f32_chief_ray_error" not in info


def test_a_twin_render_of_a_high_dynamic_range_scene_warns(sp):
    wl = np.array([450.0, 550.0, 650.0])
    cube = np.ones((16, 16, 3), np.float32)
    cube[3, 4] = 1e12
    with pytest.warns(UserWarning, match="fixed-point accumulation"):
        _, info = diffcassi.render(sp, cube, wl, device="cpu-twin", opening=1.0, **SMALL)
    assert "fixed_point_warning" in info["device"]
    cube[3, 4] = 1e6
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, info = diffcassi.render(sp, cube, wl, device="cpu-twin", opening=1.0, **SMALL)
    assert "fixed_point_warning" not in info["device"]


def test_library_errors_name_python_keywords(sp):
    cube, wl = diffcassi.synthetic_scene(8, 8, seed=1)
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.render(sp, cube, wl, scene_fov_deg=1.0, **SMALL)
    assert "scene_fov_deg 1: system `sp` has a finite object" in str(e.value) and "--" not in str(e.value), e.value
