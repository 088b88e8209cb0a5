"""Round 11 of the held-out battery, seen from Python (tests/bad_input_round11.rs holds the command line's side):
``diffcassi.STATUS`` named only codes 0-7 (a ray ``out of range``, 8, or ``evanescent``, 9, had no name), the
library's messages named command-line options a Python caller cannot pass (``--read-noise-e``, ``raise
--electrons-per-unit``), and ``reconstruct(iterations=...)`` advertised 0 as valid before refusing it."""
import warnings

import numpy as np
import pytest

import diffcassi


def test_status_names_every_code_of_the_library():
    assert sorted(diffcassi.STATUS) == list(range(10))
    assert diffcassi.STATUS[3] == "total internal reflection"
    assert diffcassi.STATUS[8] == "out of range" and diffcassi.STATUS[9] == "evanescent"


@pytest.fixture(scope="module")
def scene():
    return diffcassi.System.preset("sp"), *diffcassi.synthetic_scene(8, 8, seed=1)


def test_messages_name_the_python_keywords(scene):
    sp, cube, wl = scene
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.render(sp, cube, wl, rays=1, planes=0)
    assert str(e.value).startswith("planes 0: must be in 1..=100000"), e.value
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.render(sp, cube, wl, rays=1, planes=2, noise={"noise": "shot", "read_noise_e": 3})
    assert "read_noise_e needs `read` in noise" in str(e.value) and "--" not in str(e.value), e.value
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        diffcassi.render(sp, cube, wl, rays=1, planes=2, noise={"noise": "shot", "electrons_per_unit": 1e-6})
    text = " ".join(str(x.message) for x in w)
    assert "raise electrons_per_unit" in text and "--electrons-per-unit" not in text, text
    # reconstruct's settings too (the library names them `--sigma-max` on the command line).
    op = diffcassi.exact(sp, 8, 8, rays=1, planes=2, bands_nm=[450.0, 650.0])
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.reconstruct(op, op.apply(np.ones((8, 8, 2), np.float32)), solver="pnp-gap", sigma_max=1e-50)
    assert str(e.value).startswith("sigma_max 1e-50"), e.value


def test_reconstruct_iterations_range_starts_at_one(scene):
    sp, _, _ = scene
    op = diffcassi.exact(sp, 8, 8, rays=1, planes=2, bands_nm=[450.0, 650.0])
    y = op.apply(np.ones((8, 8, 2), np.float32))
    for bad in (0, 2**70):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"iterations: expected an integer in 1\.\.=100000"):
            diffcassi.reconstruct(op, y, iterations=bad)


def test_only_options_standing_alone_are_renamed(tmp_path, scene):
    """A second prober: a path holding ``--seed`` lost its dashes, and ``--bands`` (``render``'s ``bands_nm``,
    ``study``'s ``bands``) was renamed ``bands``; it reads as ``bands_nm`` (round 15: "bands_nm (study: bands)"
    read awkwardly), and ``study`` respells it ``bands``."""
    missing = tmp_path / "--seed" / "x--seed.npy"
    with pytest.raises(diffcassi.DiffcassiFileError) as e:
        diffcassi.load_scene(str(missing))
    assert str(missing) in str(e.value), e.value
    sp, cube, wl = scene
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.render(sp, cube, wl, rays=1, planes=2, bands_nm=[450.0, 450.0])
    assert "the bands (bands_nm) and planes" in str(e.value), e.value
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.render(sp, cube, wl, rays=1, planes=2, bands_nm=[500.0, 1e9])
    assert str(e.value).startswith("bands_nm:"), e.value
