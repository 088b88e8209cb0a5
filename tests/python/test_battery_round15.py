"""Round 15 of the held-out battery (2 Dec 2026): what its probers found in Python (docs/robustness.md,
"round 15"); the Rust side is tests/bad_input_round15.rs, C++'s cpp/tests/test_errors.cpp."""
import os
import warnings

import numpy as np
import pytest

import diffcassi
import diffcassi.torch as dt
from diffcassi.unrolled import load_unrolled

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
V1_SP = os.path.join(ROOT, "diffcassi", "weights", "unrolled-gap-v1-sp.safetensors")


def test_an_operator_names_its_system_and_unrolled_weights_of_another_are_refused():
    """An msp operator ran sp's v1 weights in silence unless ``system=`` was given (``reconstruct --weights``
    refuses them): the operator's own system is checked now."""
    msp = diffcassi.System.preset("msp")
    op = diffcassi.exact(msp, 16, 16, planes=28, rays=1, seed=1)
    assert op.system.name == "msp"
    phi = dt.CassiOperator.from_operator(op, matrix_free=True)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"trained for system 'sp', not 'msp' \(refused\)"):
        load_unrolled(V1_SP, phi)
    # A system named that is not the operator's is refused too (a regression prober: system="sp" loaded sp's
    # weights on the msp operator).
    for named in ("sp", diffcassi.System.preset("sp")):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"is not the system the operator was built from \('msp'; refused\)"):
            load_unrolled(V1_SP, phi, system=named)
    sp = diffcassi.System.preset("sp")
    phi_sp = dt.CassiOperator.from_operator(diffcassi.exact(sp, 16, 16, planes=28, rays=1, seed=1), matrix_free=True)
    assert load_unrolled(V1_SP, phi_sp) is not None
    assert load_unrolled(V1_SP, phi_sp, system="sp") is not None


def test_noise_factor_is_bounded():
    """``noise_factor=1e300`` made δ infinite: the run stopped at its first iteration with a record of nulls."""
    sp = diffcassi.System.preset("sp")
    op = diffcassi.exact(sp, 12, 12, bands_nm=[500.0, 550.0, 600.0], planes=3, rays=1, seed=1)
    twin = diffcassi.exact(sp, 12, 12, bands_nm=[500.0, 550.0, 600.0], planes=3, rays=1, seed=2)
    y = np.ones(op.image_shape, np.float32)
    for bad in (1e300, 0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(diffcassi.DiffcassiValueError, match="noise_factor"):
            diffcassi.reconstruct(op, y, iterations=2, noise_twin=twin, noise_factor=bad)
    _, rec = diffcassi.reconstruct(op, y, iterations=2, noise_twin=twin, noise_factor=1.5)
    assert rec["stopping"]["iterations_run"] >= 1


def test_a_denoisers_band_mismatch_is_a_value_error():
    """A 4-band cube given to the 28-band denoiser raised DiffcassiFileError (an OSError) though no file was wrong."""
    sp = diffcassi.System.preset("sp")
    op = diffcassi.shift_operator(sp, 16, 16, bands_nm=list(np.linspace(450, 650, 4)), planes=8, rays=2)
    y = np.ones(op.image_shape, np.float32)
    with pytest.raises(diffcassi.DiffcassiValueError, match="trained for 28 bands, the cube has 4") as e:
        diffcassi.reconstruct(op, y, solver="pnp-gap", iterations=10, tv_warmup=3)
    assert not isinstance(e.value, OSError)


def test_metrics_are_one_flat_dict_with_or_without_wavelengths():
    t = np.random.default_rng(0).random((16, 16, 4)).astype(np.float32)
    e = (t * 0.9).astype(np.float32)
    wl = [450.0, 516.0, 583.0, 650.0]
    a = diffcassi.metrics(t, e)
    b = diffcassi.metrics(t, e, wl, wl)
    assert b["psnr_db"] == a["psnr_db"] and b["sam_rad"] == a["sam_rad"]
    assert b["wavelengths_nm"] == wl and "metrics" not in b


def test_study_names_its_bands_keyword(tmp_path):
    """The library names the render bands as render's keyword ``bands_nm``; ``study``'s keyword is ``bands``
    (Python read "bands_nm (study: bands)" everywhere)."""
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.study(tmp_path / "out", synthetic=1, bands="500,1e9")
    assert "bands" in str(e.value) and "bands_nm" not in str(e.value), e.value


def test_field_units_are_named_as_python_spells_them():
    """``chief_rays(fields_mm=…)`` at infinity was told to give ``--field-deg``, a command-line option."""
    tel = diffcassi.System.from_file(os.path.join(ROOT, "tests", "fixtures", "zmx", "cassegrain_mirrors_HoO_V2C18Ex03.zmx"))
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        tel.chief_rays(np.array([[0.0, 1.0]]), tel.primary_wavelength_nm)
    assert "fields_deg X,Y" in str(e.value) and "--field" not in str(e.value), e.value


def test_render_warns_once_per_note():
    """The render's notes are the library's (`render::folder::render_notes`): the planes beyond the scene's
    bands are said once (the Python wrapper raised its own copy too)."""
    sp = diffcassi.System.preset("sp")
    wl = [480.0, 520.0]
    scene = np.full((8, 8, 2), 0.5, np.float32)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        _, info = diffcassi.render(sp, scene, wl, bands_nm=[450.0, 550.0, 650.0], planes=6, rays=1)
    said = [str(x.message) for x in w if "beyond the scene's bands" in str(x.message)]
    assert len(said) == 1 and "spectral_extrapolation" in info, said


def test_a_device_string_with_spaces_is_refused_everywhere():
    """``mapping(device=" cpu")`` was taken, ``render(device=" cpu")`` refused: both refuse it now."""
    sp = diffcassi.System.preset("sp")
    for dev in (" cpu", "cpu-twin "):
        with pytest.raises(diffcassi.DiffcassiValueError, match="no spaces"):
            diffcassi.mapping(sp, 8, 8, [520.0], device=dev)
