"""``diffcassi.render(..., tolerance_um=)``: the library's speed/accuracy choice for a render
(``diffcassi::fidelity::RenderTracing``), the CLI's ``render --tolerance-um`` from Python."""
import json
import subprocess

import numpy as np
import pytest

import diffcassi
from diffcassi import DiffcassiValueError

from conftest import random_cube

WL = np.linspace(450, 650, 28)


def test_a_tolerance_chooses_rays_and_precision_as_the_cli_does(cli, tmp_path):
    """Python's choice is the CLI's (the same rays, precision and predicted error, the same acquisition bit for
    bit), and an explicit render with the chosen rays and precision gives the same acquisition again."""
    n, planes, tol = 12, 8, 5.0
    cube = random_cube(n, n, len(WL), seed=7)
    np.save(tmp_path / "scene.npy", cube)
    np.save(tmp_path / "scene_wavelengths_nm.npy", WL)
    cache = tmp_path / "cache"
    sp = diffcassi.System.preset("sp")
    acq, info = diffcassi.render(sp, cube, WL, planes=planes, tolerance_um=tol, calibration_cache=str(cache))
    assert info["tolerance_um"] == tol and 0 < info["tolerance_predicted_error_um"] <= tol
    assert info["fidelity_choice"].startswith(f"fidelity: tolerance 5 µm → backend ") and "calibrated now" in info["fidelity_choice"]
    assert f"rays {info['rays_per_pixel']} " in info["fidelity_choice"]
    # The CLI with the same cache: the same choice, from the cache Python filled.
    out = tmp_path / "out"
    r = subprocess.run([cli, "render", "--preset", "sp", "--scene", str(tmp_path / "scene.npy"), "--scene-size", str(n),
                        "--planes", str(planes), "--tolerance-um", "5", "--calibration-cache", str(cache), "--out", str(out),
                        "--no-mapping"], check=True, capture_output=True, text=True)
    assert "calibration from the cache" in r.stdout, r.stdout
    info_cli = json.loads((out / "render.json").read_text())
    for k in ("tolerance_um", "tolerance_predicted_error_um", "rays_per_pixel", "precision", "rays_traced", "acquisition_total"):
        assert info[k] == info_cli[k], k
    exr = dict(diffcassi.read_exr(out / "acquisition.exr"))["Y"]
    assert np.array_equal(acq.astype(np.float32), exr)
    again, info2 = diffcassi.render(sp, cube, WL, planes=planes, rays=info["rays_per_pixel"], precision=info["precision"])
    assert np.array_equal(again, acq)
    assert info2["tolerance_um"] is None and info2["tolerance_predicted_error_um"] is None and "fidelity_choice" not in info2


def test_a_tolerance_refuses_what_it_would_choose(tmp_path):
    """rays, precision and backend beside tolerance_um, a tolerance that is no length, and a cache without a
    tolerance: a DiffcassiValueError naming the keywords, before any calibration (the cache folder stays empty)."""
    sp = diffcassi.System.preset("sp")
    cube = random_cube(8, 8, len(WL))
    cache = tmp_path / "cache"
    for kw, want in [(dict(rays=4), "cannot be combined with rays 4"),
                     (dict(precision="f32"), "cannot be combined with precision f32"),
                     (dict(backend="analytic"), "cannot be combined with backend"),
                     (dict(tolerance_um=float("nan")), "tolerance_um NaN: must be finite and > 0"),
                     (dict(tolerance_um=0.0), "tolerance_um 0: must be finite and > 0"),
                     (dict(tolerance_um=-1.0), "tolerance_um -1: must be finite and > 0"),
                     (dict(tolerance_um=None), "calibration_cache applies to tolerance_um only")]:
        k = dict(tolerance_um=5.0, planes=4, calibration_cache=str(cache))
        k.update(kw)
        with pytest.raises(DiffcassiValueError, match=want):
            diffcassi.render(sp, cube, WL, **k)
    with pytest.raises(DiffcassiValueError, match="tolerance_um: expected a number"):
        diffcassi.render(sp, cube, WL, planes=4, tolerance_um="5")
    assert not cache.exists() or not any(cache.iterdir())


def test_on_the_devices_twin_a_tolerance_chooses_f64_rays_only(tmp_path):
    """device="cpu-twin" (the GPU kernels on the CPU): the analytic f64 tracer's rays, named in the choice."""
    sp = diffcassi.System.preset("sp")
    cube = random_cube(8, 8, len(WL))
    acq, info = diffcassi.render(sp, cube, WL, planes=4, tolerance_um=5.0, device="cpu-twin",
                                 calibration_cache=str(tmp_path))
    assert info["precision"] == "f64" and info["tolerance_predicted_error_um"] <= 5.0
    assert "backend analytic rays" in info["fidelity_choice"] and "device cpu-twin" in info["fidelity_choice"]
    assert np.isfinite(acq).all() and acq.max() > 0


def test_a_calibration_cache_that_is_a_file_is_refused(tmp_path):
    """As the CLI: a file named as the cache is refused before any calibration; a cache that cannot be written
    is said in ``fidelity_choice`` (the library printed it on stderr before)."""
    sp = diffcassi.System.preset("sp")
    cube = random_cube(8, 8, len(WL))
    (tmp_path / "afile").write_text("x")
    with pytest.raises(DiffcassiValueError, match="calibration_cache .*afile: not a directory"):
        diffcassi.render(sp, cube, WL, planes=4, tolerance_um=5.0, calibration_cache=str(tmp_path / "afile"))
    _, info = diffcassi.render(sp, cube, WL, planes=4, tolerance_um=5.0, calibration_cache=str(tmp_path / "afile" / "sub"))
    assert "cache: not stored (" in info["fidelity_choice"]
