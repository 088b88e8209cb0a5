"""Bad inputs raise the documented exceptions with messages naming the argument, expected and actual."""
import numpy as np
import pytest

import diffcassi
from conftest import SMALL, random_cube

WL = SMALL["bands_nm"]


def test_unknown_preset_and_missing_file():
    with pytest.raises(diffcassi.DiffcassiValueError, match="unknown preset `nope`"):
        diffcassi.System.preset("nope")
    with pytest.raises(OSError, match="no such file"):
        diffcassi.System.from_file("/nonexistent/system.toml")
    with pytest.raises(diffcassi.DiffcassiFileError):
        diffcassi.load_scene("/nonexistent/scene.npy")
    assert issubclass(diffcassi.DiffcassiFileError, diffcassi.DiffcassiError)


@pytest.mark.parametrize("bad, message", [
    (random_cube(8, 8, 4).astype(np.float64), "expected dtype float32.*got float64"),
    (random_cube(8, 8, 4)[:, :, 0], "expected 3 dimensions"),
    (random_cube(8, 8, 8)[:, :, ::2], "not C-contiguous"),
    ([[1.0]], "expected a numpy.ndarray"),
])
def test_scene_dtype_shape_contiguity(bad, message):
    sp = diffcassi.System.preset("sp")
    with pytest.raises(ValueError, match=message) as e:
        diffcassi.render(sp, bad, WL, **SMALL)
    assert "scene" in str(e.value)


def test_nan_and_band_count_and_mask():
    sp = diffcassi.System.preset("sp")
    x = random_cube(8, 8, 4)
    x[1, 2, 3] = np.nan
    with pytest.raises(ValueError, match=r"scene: value NaN at index \[1, 2, 3\] is not finite"):
        diffcassi.render(sp, x, WL, **SMALL)
    with pytest.raises(ValueError, match="5 wavelengths_nm"):
        diffcassi.render(sp, random_cube(8, 8, 4), [450, 500, 550, 600, 650], **SMALL)
    with pytest.raises(ValueError, match=r"mask: expected shape \(8, 8\)"):
        diffcassi.render(sp, random_cube(8, 8, 4), WL, mask=np.ones((4, 4), np.float32), **SMALL)
    with pytest.raises(ValueError, match="not in \\[0, 1\\]"):
        diffcassi.render(sp, random_cube(8, 8, 4), WL, mask=np.full((8, 8), 2, np.float32), **SMALL)
    with pytest.raises(ValueError, match="rays"):
        diffcassi.render(sp, random_cube(8, 8, 4), WL, bands_nm=WL, rays=0)


def test_operator_and_trace_shapes():
    sp = diffcassi.System.preset("sp")
    t = diffcassi.Transport(sp, 8, 8, **SMALL)
    with pytest.raises(ValueError, match=r"cube: expected shape \[8, 8, 4\], got \[8, 8, 3\]"):
        t.operator.apply(random_cube(8, 8, 3))
    with pytest.raises(ValueError, match="image: expected"):
        t.adjoint(np.zeros((3, 3), np.float32))
    o, d, w = sp.rays_for_field([0, 0], 520.0, "hexapolar:2")
    with pytest.raises(ValueError, match="same N"):
        diffcassi.trace(sp, o, d[:-1], w)
    with pytest.raises(ValueError, match="unknown backend"):
        diffcassi.trace(sp, o, d, w, backend="nope")
    with pytest.raises(ValueError, match="set_num_threads: n: .*got int -1"):
        diffcassi.set_num_threads(-1)


def test_settings_keywords_are_checked_in_one_place():
    sp = diffcassi.System.preset("sp")
    with pytest.raises(ValueError, match=r"unexpected keyword `foo` \(valid: bands_nm, planes, rays"):
        diffcassi.exact(sp, 4, 4, foo=1)
    with pytest.raises(ValueError, match=r"unexpected keyword `interpolation`"):
        diffcassi.Transport(sp, 4, 4, interpolation="nearest")
    with pytest.raises(ValueError, match=r"planes: expected an integer in 1..=18446744073709551615 or None, got str 'many'"):
        diffcassi.shift_operator(sp, 4, 4, planes="many")
    with pytest.raises(ValueError, match=r"airy: expected True or False or None, got int"):
        diffcassi.render(sp, np.ones((4, 4, 2), np.float32), [500.0, 600.0], airy=3)
