"""Round 14, seen from Python: a bool is not a number. ``opening=True`` rendered through an all-open mask,
``airy_diameter_px=True`` blurred by a 1-pixel disk, ``tolerance_um=True`` chose for 1 µm and ``step=True`` solved with
a step of 1, all silently (the integer keywords refused a bool since round 9); ``accelerated=1`` was PyO3's TypeError.
Every real-valued keyword now refuses a bool, naming the keyword, and nothing is rendered or written."""
import inspect

import numpy as np
import pytest

import diffcassi
from diffcassi import DiffcassiValueError

WL = np.linspace(450, 650, 28)
SMALL = dict(bands_nm=[450.0, 550.0, 650.0], planes=4, rays=2)


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


@pytest.mark.parametrize("key", ["opening", "airy_diameter_px", "scene_fov_deg", "tolerance_um"])
def test_render_refuses_a_bool_for_a_number(sp, key):
    cube = np.ones((8, 8, 3), np.float32)
    settings = dict(SMALL)
    if key == "tolerance_um":
        del settings["rays"]
    with pytest.raises(DiffcassiValueError, match=f"{key}: expected a number.* got bool True"):
        diffcassi.render(sp, cube, SMALL["bands_nm"], **settings, **{key: True})
    # The operators and the transport read the same keywords.
    if key in ("opening", "airy_diameter_px"):
        with pytest.raises(DiffcassiValueError, match=f"{key}: expected a number"):
            diffcassi.exact(sp, 8, 8, **SMALL, **{key: np.True_ if key == "opening" else True})


def test_reconstruct_refuses_a_bool_for_a_number_and_a_number_for_a_bool(sp):
    op = diffcassi.exact(sp, 8, 8, **SMALL)
    y = op.apply(np.random.default_rng(0).random((8, 8, 3), dtype=np.float32))
    for k in diffcassi._SOLVER_FLOATS:
        with pytest.raises(DiffcassiValueError, match=f"^{k}: expected a number, got bool True"):
            diffcassi.reconstruct(op, y, **{k: True})
    for k in diffcassi._SOLVER_BOOLS:
        with pytest.raises(DiffcassiValueError, match=f"^{k}: expected True or False, got int 1"):
            diffcassi.reconstruct(op, y, **{k: 1})
    # Numbers of every kind still pass: a NumPy float, an int.
    cube, record = diffcassi.reconstruct(op, y, iterations=3, step=np.float32(1.0), tv_weight=0)
    assert np.isfinite(cube).all() and record["config"]["step"] == 1.0 and record["config"]["tv_weight"] == 0.0


def test_every_solver_keyword_has_a_checked_kind():
    """A keyword added to the native solve must be classed here (integer, number, True/False or an object the
    wrapper checks), or its bools and strings reach PyO3 unchecked."""
    native = [k for k in inspect.signature(diffcassi._native._reconstruct).parameters
              if k not in ("operator", "acquisition", "solver", "init")]
    objects = {"tv_coupling", "denoiser", "noise_twin"}
    classed = set(diffcassi._SOLVER_INTS) | set(diffcassi._SOLVER_FLOATS) | set(diffcassi._SOLVER_BOOLS) | objects
    assert set(native) == classed, set(native) ^ classed


def test_study_refuses_a_bool_for_a_number(tmp_path):
    with pytest.raises(DiffcassiValueError, match="opening: expected a number in \\[0, 1\\] or None, got bool True"):
        diffcassi.study(str(tmp_path / "s"), opening=True)
    assert not (tmp_path / "s").exists()


def test_tracing_calls_refuse_bools_for_lengths_and_wavelengths(sp):
    """``mapping(pitch_mm=True)`` was a 1 mm pitch; ``chief_rays(f, True)`` a 1 nm wavelength; ``[True, 520]`` 1 nm
    and 520 nm."""
    for kw in (dict(pitch_mm=True), dict(pitch_mm="0.01"), dict(scene_fov_deg=np.True_)):
        (k, v), = kw.items()
        with pytest.raises(DiffcassiValueError, match=f"^{k}: expected a number, got "):
            diffcassi.mapping(sp, 4, 4, [520.0], **kw)
    with pytest.raises(DiffcassiValueError, match="wavelengths_nm: expected a sequence of numbers, got bool True in it"):
        diffcassi.mapping(sp, 4, 4, [True, 520.0])
    with pytest.raises(DiffcassiValueError, match="wavelengths_nm: expected a sequence of numbers, got an array of bools"):
        diffcassi.mapping(sp, 4, 4, np.array([True]))
    with pytest.raises(DiffcassiValueError, match="^wavelength_nm: expected a number, got bool True"):
        sp.chief_rays(np.zeros((1, 2)), True)
    with pytest.raises(DiffcassiValueError, match="^wavelength_nm: expected a number, got bool"):
        sp.rays_for_field([0.0, 0.0], np.True_)
    # Numbers of every kind still pass, and the default pitch is the CLI's 10 µm.
    a, _ = diffcassi.mapping(sp, 4, 4, [520.0])
    b, _ = diffcassi.mapping(sp, 4, 4, np.array([520], dtype=np.int64), pitch_mm=np.float64(0.01))
    assert np.array_equal(a, b)
    assert sp.chief_rays(np.zeros((1, 2)), 520)[0].shape == (1, 3)


def test_a_semi_diameter_beyond_the_surface_edge_warns_on_load(tmp_path):
    """As the CLI prints it: a UserWarning when the System is made, naming the surface and the edge, and
    ``System.warnings`` keeps it; a preset and a copy of a clean system are silent."""
    import copy
    import warnings
    toml = diffcassi.System.preset("sp").to_toml()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sp = diffcassi.System.from_string(toml)
        assert sp.warnings == [] and copy.deepcopy(sp).warnings == []
    spec = sp.to_json()
    import json
    d = json.loads(spec)
    d["surfaces"][17]["semi_diameter_mm"] = 25.0
    p = tmp_path / "wide.json"
    p.write_text(json.dumps(d))
    with pytest.warns(UserWarning, match="surface 17: semi-diameter 25 mm is beyond the surface's edge at r = 22.28 mm"):
        wide = diffcassi.System.from_file(p)
    assert len(wide.warnings) == 1 and "give a semi-diameter ≤ 22.28 mm" in wide.warnings[0]
