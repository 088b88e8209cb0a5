"""Objects at infinity from Python (issue 42): ``scene_fov_deg`` on ``render``, the operators, ``Transport`` and
the differentiable ``CassiRenderer``.

The system is a public design at infinity opened as it is (tests/fixtures/zmx/cassegrain_mirrors_HoO_V2C18Ex03.zmx:
rayoptics' Cassegrain telescope, F/4, EFL 80 mm, two mirrors). A scene at infinity is given by its angular extent across its width;
the renderer samples it uniformly in field angle (docs/rendering.md), as the CLI's ``--scene-fov-deg`` does.
"""
import json
import pathlib
import subprocess

import numpy as np
import pytest

import diffcassi
from conftest import check_cassi_renderer_gradients, random_cube

ROOT = pathlib.Path(__file__).resolve().parents[2]
DESIGN = ROOT / "tests" / "fixtures" / "zmx" / "cassegrain_mirrors_HoO_V2C18Ex03.zmx"
SMALL = dict(bands_nm=[500.0, 600.0], planes=4, rays=2)


@pytest.fixture(scope="module")
def telescope():
    sys = diffcassi.System.from_file(DESIGN)
    assert sys.object_at_infinity
    return sys


def test_render_at_infinity_equals_the_cli_bit_for_bit(cli, telescope, tmp_path):
    n, fov = 8, 0.2
    wl = [500.0, 600.0]
    cube = random_cube(n, n, len(wl), seed=4)
    np.save(tmp_path / "scene.npy", cube)
    np.save(tmp_path / "scene_wavelengths_nm.npy", np.asarray(wl, dtype=np.float64))
    subprocess.run([cli, "render", "--system", str(DESIGN), "--scene", str(tmp_path / "scene.npy"), "--scene-size", str(n),
                    "--bands", "500,600", "--planes", "4", "--rays", "2", "--scene-fov-deg", repr(fov),
                    "--out", str(tmp_path / "out"), "--no-mapping"], check=True, capture_output=True)
    info_cli = json.loads((tmp_path / "out" / "render.json").read_text())
    acq, info = diffcassi.render(telescope, cube, wl, scene_fov_deg=fov, **SMALL)
    assert info["scene_fov_deg"] == fov == info_cli["scene_fov_deg"]
    assert info["scene_pitch_rad"] == info_cli["scene_pitch_rad"] == pytest.approx(np.radians(fov) / n, rel=1e-15)
    assert info["acquisition_total"] == info_cli["acquisition_total"] > 0
    exr = dict(diffcassi.read_exr(tmp_path / "out" / "acquisition.exr"))["Y"]
    assert np.array_equal(acq.astype(np.float32), exr)
    assert np.isfinite(acq).all() and info["ray_stats"]["arrived"] > 0


def test_operators_and_transport_at_infinity_equal_render(telescope):
    n, fov = 8, 0.2
    cube = random_cube(n, n, 2, seed=5)
    acq, _ = diffcassi.render(telescope, cube, SMALL["bands_nm"], scene_fov_deg=fov, **SMALL)
    # The exact operator is the renderer's transport: applied to the same cube, the same image.
    op = diffcassi.exact(telescope, n, n, scene_fov_deg=fov, **SMALL)
    y = op.apply(cube)
    assert y.shape == acq.shape
    np.testing.assert_allclose(y, acq, rtol=1e-5, atol=1e-6 * float(acq.max()))
    t = diffcassi.Transport(telescope, n, n, scene_fov_deg=fov, **SMALL)
    assert np.array_equal(t.apply(cube), acq)
    # The model operators take the angular extent too and map onto the same detector.
    for make in (diffcassi.mapping_operator, diffcassi.shift_operator):
        m = make(telescope, n, n, scene_fov_deg=fov, **SMALL)
        ym = m.apply(cube)
        assert ym.shape == acq.shape and np.isfinite(ym).all() and ym.sum() > 0


@pytest.mark.parametrize("fov", [None, 0.0, 180.0, -5.0, float("nan"), float("inf")])
def test_bad_or_missing_angular_extent_is_a_clear_error(telescope, fov):
    cube = random_cube(4, 4, 2)
    with pytest.raises(ValueError, match="scene-fov-deg|scene_fov_deg"):
        diffcassi.render(telescope, cube, SMALL["bands_nm"], scene_fov_deg=fov, **SMALL)
    with pytest.raises(ValueError, match="scene-fov-deg|scene_fov_deg"):
        diffcassi.exact(telescope, 4, 4, scene_fov_deg=fov, **SMALL)


def test_angular_extent_on_a_finite_object_is_refused():
    cube = random_cube(4, 4, 2)
    with pytest.raises(ValueError, match="finite object"):
        diffcassi.render(diffcassi.System.preset("sp"), cube, SMALL["bands_nm"], scene_fov_deg=10.0, **SMALL)
    with pytest.raises(ValueError, match="scene_fov_deg: expected a number"):
        diffcassi.render(diffcassi.System.preset("sp"), cube, SMALL["bands_nm"], scene_fov_deg="wide", **SMALL)


#: A thick N-BK7 singlet at infinity (R1 = 50 mm, R2 = −80 mm, f ≈ 60 mm, entrance pupil 8 mm): the system of
#: tests/render_gradient.rs's gradient tests at infinity (tests/common/mod.rs, ``singlet_at_infinity``).
SINGLET = (ROOT / "tests" / "fixtures" / "systems" / "singlet_at_infinity.toml").read_text()


@pytest.fixture(scope="module")
def singlet():
    sys = diffcassi.System.from_string(SINGLET)
    assert sys.object_at_infinity
    return sys


def test_cassi_renderer_at_infinity_matches_finite_differences(singlet):
    """The torch module at infinity (``scene_fov_deg``): the lens's curvature and glass against central
    differences of the same-sample render (rays fixed in object space on both sides), the mask gradient exact."""
    pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    worst = check_cassi_renderer_gradients(singlet, ["s1.curvature", "glass_nd:N-BK7"], [450.0, 550.0, 650.0],
                                           [1e-8, 1e-7], scene_fov_deg=0.5)
    print(f"CassiRenderer at infinity: worst relative difference from central differences {worst:.1e}")


@pytest.mark.parametrize("fov", [None, 0.0, 180.0, -5.0, float("nan"), float("inf"), "wide"])
def test_cassi_renderer_angular_extent_errors(singlet, fov):
    """Missing at infinity, out of (0, 180) or not a number: a ValueError naming the value (the forward
    renderer's errors); on a finite object a given extent is refused."""
    pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    import diffcassi.torch as dt
    with pytest.raises(ValueError, match="scene-fov-deg|scene_fov_deg"):
        dt.CassiRenderer(singlet, 4, 4, free=["s1.curvature"], rays=1, planes=2, bands_nm=[500.0, 600.0],
                         scene_fov_deg=fov)


def test_cassi_renderer_refuses_an_angular_extent_on_a_finite_object():
    pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
    import diffcassi.torch as dt
    with pytest.raises(ValueError, match="finite object"):
        dt.CassiRenderer(diffcassi.System.preset("sp"), 4, 4, free=["prism_tilt_x"], rays=1, planes=2,
                         bands_nm=[500.0, 600.0], scene_fov_deg=10.0)


def test_ray_tools_at_infinity_take_angles_and_refuse_heights(telescope):
    """``spot``, ``dispersion``, ``System.chief_rays`` and ``mapping`` at infinity: a field is an angle
    (``field_deg`` / ``fields_deg``), a pixel's extent comes from ``scene_fov_deg``; a height in mm (or a pitch in
    mm) is refused naming it — it was read as radians (a 5 mm field traced at 5 rad: a held-out battery)."""
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"field_mm \(0, 0\.1\): system .* has its object at infinity"):
        diffcassi.spot(telescope, (0.0, 0.1), 550.0)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"field_mm .* has its object at infinity"):
        diffcassi.dispersion(telescope, [500.0, 600.0], field_mm=(0.0, 0.1))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"fields_mm .* has its object at infinity"):
        telescope.chief_rays(np.array([[0.0, 0.1]]), 550.0)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"has its object at infinity: give the scene's angular extent"):
        diffcassi.mapping(telescope, 4, 4, [550.0], pitch_mm=1.0)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"field_deg \(0, 95\): field angles must be finite and within"):
        diffcassi.spot(telescope, None, 550.0, field_deg=(0.0, 95.0))
    # Angles agree across the tools: the spot's chief ray is chief_rays' and rays_for_field's, at 0.1°.
    s = diffcassi.spot(telescope, None, 550.0, field_deg=(0.0, 0.1), pupil="chief")
    o, d, _ = telescope.chief_rays(None, 550.0, fields_deg=np.array([[0.0, 0.1]]))
    o2, d2, _ = telescope.rays_for_field(None, 550.0, pupil="chief", field_deg=[0.0, 0.1])
    assert np.array_equal(o, o2) and np.array_equal(d, d2)
    assert abs(d[0, 1] / d[0, 2] - np.tan(np.radians(0.1))) < 1e-12
    c = diffcassi.dispersion(telescope, [550.0, 600.0], field_deg=(0.0, 0.1))
    assert abs(c["y_mm"][0] - s["chief_mm"][1]) < 1e-9 and abs(c["y_mm"][0]) > 0.05  # EFL 80 mm · tan 0.1° ≈ 0.14 mm
    axis = diffcassi.dispersion(telescope, [500.0, 600.0])  # neither: the axis, in degrees at infinity
    assert np.allclose(axis["y_mm"], 0.0, atol=1e-9)
    # The mapping at infinity: scene_fov_deg across the width, as `mapping --scene-fov-deg`.
    pos, valid = diffcassi.mapping(telescope, 4, 4, [550.0], scene_fov_deg=0.4)
    assert valid.all() and np.isfinite(pos).all() and np.ptp(pos[..., 0]) > 0
