"""Round 10 of the held-out battery, seen from Python (tests/bad_input_round10.rs holds the command line's side):
solver settings the solvers hold in float32 were cast silently (a ``tv_weight`` of 1e-45 returned an all-NaN
cube, 1e-50 ran as 0, ``sigma_max=1e-50`` was reported as 0 and ``admm_eta=1e300`` as inf), and ``noise_twin``
took any operator of the right shape (a mapping operator gave δ 3× too large, the operator itself a spread of 0)."""
import numpy as np
import pytest

import diffcassi

BANDS = [450.0, 520.0, 590.0, 650.0]
SMALL = dict(bands_nm=BANDS, planes=4, rays=2)


@pytest.fixture(scope="module")
def setup():
    sp = diffcassi.System.preset("sp")
    rng = np.random.default_rng(3)
    cube = rng.uniform(0.1, 1.0, (12, 12, len(BANDS))).astype(np.float32)
    op = diffcassi.exact(sp, 12, 12, seed=0, **SMALL)
    y = op.apply(cube)
    return sp, op, y


@pytest.mark.parametrize("key,value", [("tv_weight", 1e-45), ("tv_weight", 1e-50), ("tv_weight", 1e300),
                                       ("step", 1e-46), ("admm_eta", 1e300)])
def test_float32_settings_are_checked_as_given(setup, key, value):
    _, op, y = setup
    solver = "admm-tv" if key == "admm_eta" else "gap-tv"
    with pytest.raises(diffcassi.DiffcassiValueError, match=rf"{key} {value:g}: must be finite, and 0 or within f32's range"):
        diffcassi.reconstruct(op, y, solver=solver, iterations=3, **{key: value})


def test_pnp_sigma_bounds_are_checked_as_given(setup):
    _, op, y = setup
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"sigma_max 1e-50: must be finite"):
        diffcassi.reconstruct(op, y, solver="pnp-gap", sigma_max=1e-50)


def test_a_tiny_normal_tv_weight_is_a_finite_solve(setup):
    """4w below half an f32 step of the iterate's peak: TV leaves the iterate as it is (the ROF solution to
    within 4w); the cube is finite, where 1e-45 gave NaN everywhere."""
    _, op, y = setup
    cube, record = diffcassi.reconstruct(op, y, solver="gap-tv", iterations=3, tv_weight=1e-30)
    assert np.isfinite(cube).all() and np.abs(cube).max() > 0
    plain, _ = diffcassi.reconstruct(op, y, solver="gap-tv", iterations=3, tv_weight=0.0)
    np.testing.assert_array_equal(cube, plain)


def test_the_noise_twin_is_the_exact_operator_with_another_seed(setup):
    sp, op, y = setup
    mapping = diffcassi.mapping_operator(sp, 12, 12, **{k: v for k, v in SMALL.items() if k == "bands_nm"})
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"noise_twin: a `mapping-nearest` operator"):
        diffcassi.reconstruct(op, y, iterations=3, noise_twin=mapping)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"noise_twin: its images equal the operator's"):
        diffcassi.reconstruct(op, y, iterations=3, noise_twin=op)
    same_seed = diffcassi.exact(sp, 12, 12, seed=0, **SMALL)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"the same seed"):
        diffcassi.reconstruct(op, y, iterations=3, noise_twin=same_seed)
    y_map = mapping.apply(np.full((12, 12, len(BANDS)), 0.5, dtype=np.float32))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"the operator is `mapping-nearest`"):
        diffcassi.reconstruct(mapping, y_map, iterations=3, noise_twin=op)
    twin = diffcassi.exact(sp, 12, 12, seed=1, **SMALL)
    cube, record = diffcassi.reconstruct(op, y, iterations=6, noise_twin=twin)
    assert np.isfinite(cube).all()
    assert record["stopping"]["noise_estimator"] == "monte-carlo-spread"


def test_the_noise_twin_has_the_operators_mask_and_settings(setup):
    """A twin of another mask, opening or ray count was taken (δ up to 1.8× too large, the solve stopped after 6
    iterations instead of 10; a held-out battery, round 10): the twin is the operator's recipe with another seed."""
    sp, op, y = setup
    for other, named in [(dict(mask_seed=5), "mask_seed"), (dict(opening=0.9), "opening"), (dict(rays=3), "rays")]:
        twin = diffcassi.exact(sp, 12, 12, seed=1, **{**SMALL, **other})
        with pytest.raises(diffcassi.DiffcassiValueError, match=rf"noise_twin: its {named} differ"):
            diffcassi.reconstruct(op, y, iterations=3, noise_twin=twin)
    closed = np.zeros((12, 12), dtype=np.float32)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"noise_twin: its mask differ"):
        diffcassi.reconstruct(op, y, iterations=3, noise_twin=diffcassi.exact(sp, 12, 12, closed, seed=1, **SMALL))
    # A Transport of the same recipe and another seed is a twin.
    twin = diffcassi.Transport(sp, 12, 12, seed=2, **SMALL)
    cube, _ = diffcassi.reconstruct(op, y, iterations=3, noise_twin=twin)
    assert np.isfinite(cube).all()
