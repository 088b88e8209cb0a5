"""Every API call on the four presets, compared with the Rust CLI's own outputs bit for bit."""
import csv
import json
import math
import subprocess

import numpy as np
import pytest

import diffcassi
from conftest import PRESETS, SMALL, random_cube


def test_version_equals_the_crates():
    text = (pytest.importorskip("pathlib").Path(__file__).resolve().parents[2] / "Cargo.toml").read_text()
    assert f'version = "{diffcassi.__version__}"' in text


def test_system_data(system):
    assert system.name in PRESETS
    assert len(system.wavelengths_nm) >= 1 and all(w > 0 for w in system.wavelengths_nm)
    s = system.surfaces
    assert len(s) > 5 and sum(r["is_stop"] for r in s) == 1
    again = diffcassi.System.from_string(system.to_toml())
    assert again.to_toml() == system.to_toml()


def test_from_file_formats(tmp_path, system):
    p = tmp_path / "s.toml"
    p.write_text(system.to_toml())
    assert diffcassi.System.from_file(p).to_json() == system.to_json()
    j = tmp_path / "s.json"
    j.write_text(system.to_json())
    assert diffcassi.System.from_file(str(j)).to_toml() == system.to_toml()


def _cli_trace(cli, preset, tmp_path):
    out = tmp_path / f"{preset}.csv"
    subprocess.run([cli, "trace", "--preset", preset, "--wavelength-nm", "520", "--field-mm", "0.5,-0.25",
                    "--pupil", "hexapolar:6", "--csv", str(out)], check=True, capture_output=True)
    rows = [r for r in csv.DictReader(l for l in out.read_text().splitlines() if not l.startswith("#"))]
    return rows


@pytest.mark.parametrize("preset", PRESETS)
def test_trace_equals_the_cli_bit_for_bit(cli, preset, tmp_path):
    s = diffcassi.System.preset(preset)
    o, d, w = s.rays_for_field([0.5, -0.25], 520.0, "hexapolar:6")
    t = diffcassi.trace(s, o, d, w)
    rows = _cli_trace(cli, preset, tmp_path)
    assert len(rows) == len(t["status"])
    ok = 0
    for i, r in enumerate(rows):
        assert (r["status"] == "ok") == (t["status"][i] == 0)
        if r["status"] == "ok":
            ok += 1
            assert float(r["x_mm"]) == t["positions"][i, 0] and float(r["y_mm"]) == t["positions"][i, 1]
            assert float(r["dir_z"]) == t["directions"][i, 2]
    assert ok > 0


@pytest.mark.parametrize("preset", PRESETS)
def test_mapping_equals_the_cli_bit_for_bit(cli, preset, tmp_path):
    out = tmp_path / "m.npy"
    subprocess.run([cli, "mapping", "--preset", preset, "--height", "6", "--width", "5", "--wavelengths-nm", "450:650:4",
                    "--npy", str(out), "--f64"], check=True, capture_output=True)
    pos, valid = diffcassi.mapping(diffcassi.System.preset(preset), 6, 5, np.linspace(450, 650, 4))
    assert pos.shape == (6, 5, 4, 2) and valid.shape == (6, 5, 4) and valid.dtype == bool
    assert np.array_equal(np.load(out), pos)
    assert np.array_equal(np.load(tmp_path / "m_valid.npy").astype(bool), valid)


def test_analyses(system):
    sp = diffcassi.spot(system, [0.0, 0.0], 520.0)
    assert sp["stats"]["count"] > 100 and sp["x_mm"].shape == sp["y_mm"].shape
    assert sp["lost"] == [] and sp["stats"]["count"] == sp["rays"]
    # Far off axis (SP and mSP vignette part of the beam at 9 mm, all of it at 12 mm): the lost rays are
    # counted by outcome and surface, and account for every ray that did not arrive.
    for x_mm in (9.0, 12.0):
        far = diffcassi.spot(system, [x_mm, 0.0], 520.0)
        arrived = far["stats"]["count"] if far["stats"] else 0
        assert all(l["status"] != "ok" and l["count"] > 0 for l in far["lost"])
        assert arrived + sum(l["count"] for l in far["lost"]) == far["rays"]
        assert int(np.sum(np.asarray(far["status"]) != "Ok")) == far["rays"] - arrived
    g = diffcassi.distortion(system, grid=5)
    assert len(g["points"]) == 25 and math.isfinite(g["max_distortion_pct"])
    d = diffcassi.dispersion(system, np.linspace(450, 650, 5))
    assert d["x_mm"].shape == (5,) and d["spread_um"] > 0


def test_jacobian_by_name(system):
    o, d, w = system.chief_rays(np.array([[0.0, 0.0], [0.5, 0.0]]), 520.0)
    j = diffcassi.jacobian(system, "prism_tilt_x, wavelength", o, d, w)
    assert j["jacobian"].shape == (2, 6, 2) and len(j["parameters"]) == 2
    assert j["available"].all() and np.isfinite(j["jacobian"]).all()
    assert np.abs(j["jacobian"][:, 0, 1]).max() > 0  # the image moves in x with wavelength (dispersion)
    t = diffcassi.trace(system, o, d, w)
    assert np.array_equal(t["positions"], j["positions"])


def _write_scene(tmp_path, cube, wl):
    p = tmp_path / "scene.npy"
    np.save(p, cube)
    np.save(tmp_path / "scene_wavelengths_nm.npy", np.asarray(wl, dtype=np.float64))
    return p


@pytest.mark.parametrize("preset", PRESETS)
def test_render_defaults_equal_the_cli_bit_for_bit(cli, preset, tmp_path):
    """Only --rays/--planes shrink the run; every other default is the CLI's (bands, mask, seed, Airy, ...)."""
    n = 12
    wl = np.linspace(440, 660, 12)
    cube = random_cube(n, n, len(wl), seed=3)
    p = _write_scene(tmp_path, cube, wl)
    subprocess.run([cli, "render", "--preset", preset, "--scene", str(p), "--scene-size", str(n), "--rays", "2",
                    "--planes", "28", "--out", str(tmp_path / "out"), "--no-mapping"], check=True, capture_output=True)
    info_cli = json.loads((tmp_path / "out" / "render.json").read_text())
    acq, info = diffcassi.render(diffcassi.System.preset(preset), cube, wl, rays=2, planes=28)
    assert info["acquisition_total"] == info_cli["acquisition_total"]
    exr = dict(diffcassi.read_exr(tmp_path / "out" / "acquisition.exr"))["Y"]
    assert np.array_equal(acq.astype(np.float32), exr)
    for k in ("bands_nm", "planes_nm", "detector", "rays_traced", "mask", "mask_opening", "airy", "seed", "sampling"):
        assert info[k] == info_cli[k], k


def test_render_all_settings_and_transport_equal_render(system):
    cube = random_cube(10, 10, 4, seed=1)
    acq, info = diffcassi.render(system, cube, SMALL["bands_nm"], seed=5, **SMALL)
    assert acq.dtype == np.float64 and acq.shape == (info["detector"]["height"], info["detector"]["width"])
    assert info["acquisition_total"] == pytest.approx(acq.sum(), rel=1e-12)
    t = diffcassi.Transport(system, 10, 10, seed=5, **SMALL)
    assert t.detector_shape == acq.shape and t.nbytes > 0
    assert np.array_equal(t.apply(cube), acq)
    # apply reuses its scene buffer: a second scene, then the first again, are each still equal to render.
    cube2 = random_cube(10, 10, 4, seed=2)
    assert np.array_equal(t.apply(cube2), diffcassi.render(system, cube2, SMALL["bands_nm"], seed=5, **SMALL)[0])
    assert np.array_equal(t.apply(cube), acq)


def test_render_noise_is_seeded():
    sp = diffcassi.System.preset("sp")
    cube = random_cube(8, 8, 4)
    a, ia = diffcassi.render(sp, cube, SMALL["bands_nm"], noise={"noise": "shot,read,adc", "noise_seed": 1}, **SMALL)
    b, _ = diffcassi.render(sp, cube, SMALL["bands_nm"], noise={"noise": "shot,read,adc", "noise_seed": 1}, **SMALL)
    c, ic = diffcassi.render(sp, cube, SMALL["bands_nm"], **SMALL)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert ia["noise"] is not None and ic["noise"] is None


def test_thread_count_does_not_change_results():
    sp = diffcassi.System.preset("msp")
    cube = random_cube(8, 8, 4)
    diffcassi.set_num_threads(1)
    assert diffcassi.get_num_threads() == 1
    a, _ = diffcassi.render(sp, cube, SMALL["bands_nm"], **SMALL)
    diffcassi.set_num_threads(2)
    b, _ = diffcassi.render(sp, cube, SMALL["bands_nm"], **SMALL)
    diffcassi.set_num_threads(0)
    assert np.array_equal(a, b)


def test_metrics_match_definitions():
    rng = np.random.default_rng(0)
    t = rng.random((16, 16, 3), dtype=np.float32)
    e = np.clip(t + 0.05 * rng.standard_normal(t.shape).astype(np.float32), 0, 1).astype(np.float32)
    m = diffcassi.metrics(t, e)
    mse = np.mean((t.astype(np.float64) - e) ** 2)
    assert m["rmse"] == pytest.approx(math.sqrt(mse), rel=1e-6)
    assert m["psnr_db"] == pytest.approx(10 * math.log10(t.max() ** 2 / mse), rel=1e-6)
    assert 0 < m["ssim"] < 1 and m["sam_deg"] == pytest.approx(math.degrees(m["sam_rad"]))


def test_spot_refuses_pupil_points_outside_the_unit_disc():
    # As the CLI's --pupil-csv (analysis::first_point_outside_pupil); traced as "Ok" before (a held-out battery).
    sp = diffcassi.System.preset("sp")
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"pupil row 1 \(px, py\) = \(2, 0\).*px² \+ py² ≤ 1"):
        diffcassi.spot(sp, (0.0, 0.0), 520.0, pupil=np.array([[0.0, 0.5], [2.0, 0.0]]))
    d = diffcassi.spot(sp, (0.0, 0.0), 520.0, pupil=np.array([[0.0, 0.5], [1.0, 0.0]]))
    assert len(d["pupil"]) == 2


def test_render_warns_when_planes_lie_beyond_the_scene_bands():
    sp = diffcassi.System.preset("sp")
    cube = np.full((8, 8, 4), 0.5, np.float32)
    with pytest.warns(UserWarning, match=r"beyond the scene's bands \(450.0–583.3 nm\)"):
        _, info = diffcassi.render(sp, cube, [450.0, 494.4, 538.9, 583.3], bands_nm=[450.0, 516.7, 583.3, 650.0], planes=8, rays=2)
    assert info["spectral_extrapolation"]["planes"] >= 1
    with pytest.raises(diffcassi.DiffcassiValueError, match="lie outside the render's planes"):
        diffcassi.render(sp, cube, [1000.0, 1100.0, 1200.0, 1300.0], bands_nm=[450.0, 516.7, 583.3, 650.0], planes=8, rays=2)
