"""Operators from Python: adjoint identity, equality with render, SciPy export that loads without diffcassi."""
import subprocess
import sys

import numpy as np
import pytest

import diffcassi
from conftest import PRESETS, SMALL, random_cube


@pytest.mark.parametrize("preset", PRESETS)
def test_exact_adjoint_identity_and_render_equality(preset):
    s = diffcassi.System.preset(preset)
    t = diffcassi.Transport(s, 8, 8, **SMALL)
    op = t.operator
    assert op.name == "exact" and op.cube_shape == (8, 8, 4) and op.image_shape == t.detector_shape
    x = random_cube(8, 8, 4, seed=2)
    y = np.random.default_rng(3).random(op.image_shape, dtype=np.float32)
    phix = op.apply(x)
    lhs = float(np.dot(phix.ravel().astype(np.float64), y.ravel()))
    rhs = float(np.dot(x.ravel().astype(np.float64), op.adjoint(y).ravel()))
    assert abs(lhs - rhs) <= 1e-6 * np.linalg.norm(phix) * np.linalg.norm(y)
    assert np.array_equal(t.adjoint(y), op.adjoint(y))
    ref = t.apply(x)
    assert np.abs(phix - ref).max() <= 1e-6 * ref.max()
    e = diffcassi.exact(s, 8, 8, **SMALL)
    assert np.array_equal(e.apply(x), phix)


def test_save_npz_loads_with_scipy_and_multiplies_to_the_acquisition(tmp_path):
    sp = diffcassi.System.preset("sp")
    t = diffcassi.Transport(sp, 8, 8, **SMALL)
    path = tmp_path / "phi.npz"
    t.save_npz(path)
    x = random_cube(8, 8, 4, seed=4)
    np.save(tmp_path / "x.npy", x)
    # A fresh interpreter that imports SciPy and NumPy only.
    code = ("import numpy as np, scipy.sparse as s, sys; sys.modules['diffcassi'] = None; "
            f"A = s.load_npz(r'{path}'); x = np.load(r'{tmp_path / 'x.npy'}'); "
            f"np.save(r'{tmp_path / 'y.npy'}', A @ x.ravel())")
    subprocess.run([sys.executable, "-c", code], check=True)
    y = np.load(tmp_path / "y.npy").reshape(t.detector_shape)
    acq = t.apply(x)
    assert np.abs(y - acq).max() <= 1e-5 * acq.max()
    a = t.to_scipy()
    assert a.shape == (acq.size, x.size) and a.format == "csr"
    assert np.abs(a.T @ acq.ravel().astype(np.float32) - t.adjoint(acq).ravel()).max() <= 1e-5 * np.abs(t.adjoint(acq)).max()


def test_sparse_export_is_refused_above_the_memory_budget():
    t = diffcassi.Transport(diffcassi.System.preset("ap"), 8, 8, **SMALL)
    with pytest.raises(ValueError, match=r"sparse export of `exact` .* bytes .* exceed the memory budget"):
        t.operator.to_scipy(memory_gb=1e-6)
    with pytest.raises(ValueError, match="memory_gb"):
        t.save_npz("never.npz", memory_gb=-1)


@pytest.mark.parametrize("kind", ["mapping-nearest", "mapping-bilinear", "shift"])
@pytest.mark.parametrize("preset", ["sp", "map"])
def test_model_operators_adjoint_identity(kind, preset):
    s = diffcassi.System.preset(preset)
    if kind == "shift":
        op = diffcassi.shift_operator(s, 8, 8, **SMALL)
    else:
        op = diffcassi.mapping_operator(s, 8, 8, interpolation=kind.split("-")[1], **SMALL)
    assert op.name == kind and op.cube_shape == (8, 8, 4)
    assert op.image_shape == diffcassi.Transport(s, 8, 8, **SMALL).detector_shape  # the render's detector
    x = random_cube(8, 8, 4, seed=5)
    y = np.random.default_rng(6).random(op.image_shape, dtype=np.float32)
    phix = op.apply(x)
    lhs = float(np.dot(phix.ravel().astype(np.float64), y.ravel()))
    rhs = float(np.dot(x.ravel().astype(np.float64), op.adjoint(y).ravel()))
    assert abs(lhs - rhs) <= 1e-6 * np.linalg.norm(phix) * np.linalg.norm(y)
    if kind.startswith("mapping"):
        init = op.initialisation(y)
        assert init.shape == (8, 8, 4) and np.isfinite(init).all()
    else:
        with pytest.raises(ValueError, match="only the mapping operator"):
            op.initialisation(y)


def test_reconstruct_recovers_a_scene_through_the_exact_operator():
    s = diffcassi.System.preset("sp")
    t = diffcassi.Transport(s, 12, 12, **SMALL)
    x = np.repeat(np.repeat(random_cube(3, 3, 4, seed=8), 4, axis=0), 4, axis=1)  # blocky, TV-friendly
    acq = t.apply(np.ascontiguousarray(x))
    start = diffcassi.metrics(x, np.zeros_like(x))["rmse"]
    est, rec = diffcassi.reconstruct(t, acq, iterations=40, accelerated=True)  # noiseless, same transport: the accelerated variant
    assert est.shape == x.shape and len(rec["residuals"]) == 40 and rec["final_residual"] < 0.1
    assert diffcassi.metrics(x, est)["rmse"] < 0.5 * start
    est2, rec2 = diffcassi.reconstruct(t.operator, acq.astype(np.float32), solver="admm-tv", iterations=10)
    assert rec2["config"]["solver"] == "admm-tv" and np.isfinite(est2).all()
    with pytest.raises(ValueError, match=r"iterations: expected an integer in 1\.\.=100000"):
        diffcassi.reconstruct(t, acq, iterations=0)
    with pytest.raises(ValueError, match="unknown solver"):
        diffcassi.reconstruct(t, acq, solver="nope")


@pytest.mark.parametrize("kind", ["mapping-nearest", "mapping-bilinear", "shift"])
def test_model_operators_export_to_scipy(kind):
    s = diffcassi.System.preset("sp")
    if kind == "shift":
        op = diffcassi.shift_operator(s, 8, 8, **SMALL)
    else:
        op = diffcassi.mapping_operator(s, 8, 8, interpolation=kind.split("-")[1], **SMALL)
    a = op.to_scipy()
    x = random_cube(8, 8, 4, seed=7)
    y = np.random.default_rng(8).random(op.image_shape, dtype=np.float32)
    ax, aty = op.apply(x), op.adjoint(y)
    assert np.abs(a @ x.ravel() - ax.ravel()).max() <= 1e-5 * np.abs(ax).max()
    assert np.abs(a.T @ y.ravel() - aty.ravel()).max() <= 1e-5 * np.abs(aty).max()


def test_sparse_export_has_no_column_limit():
    # 96×96×28 = 258 048 columns (the old column-by-column export refused more than 200 000).
    s = diffcassi.System.preset("sp")
    op = diffcassi.exact(s, 96, 96, planes=28, rays=1, airy=False)
    a = op.to_scipy(memory_gb=1.0)
    assert a.shape[1] == 96 * 96 * 28 > 200_000
    x = random_cube(96, 96, 28, seed=9)
    ax = op.apply(x)
    assert np.abs(a @ x.ravel() - ax.ravel()).max() <= 1e-5 * ax.max()
    shift = diffcassi.shift_operator(s, 96, 96, planes=28, rays=1)
    b = shift.to_scipy()
    assert np.abs(b @ x.ravel() - shift.apply(x).ravel()).max() <= 1e-5 * shift.apply(x).max()
