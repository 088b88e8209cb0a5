"""Issue 21 (reliability round 2), the Python part, by class: the CLI's limits at every entry point before
anything is allocated (sizes, memory, rays, planes, Airy, radiance, threads) with the CLI's messages;
integers out of range naming the argument (not a bare OverflowError); validated CSR imports (a tampered
.npz once crashed the interpreter in torch.sparse.mm); CassiDataset's wavelengths against its bands."""
import os
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

import diffcassi
from conftest import ROOT, SMALL, random_cube

WL = SMALL["bands_nm"]
HUGE = 2 ** 70


@pytest.fixture(scope="module")
def sp():
    return diffcassi.System.preset("sp")


# ------------------------------------------------------------------ threads
def test_set_num_threads_takes_the_cli_range():
    # In a subprocess with a timeout: before the fix set_num_threads(100000) never returned.
    code = ("import diffcassi\n"
            "for n in (100000, 1025, -1, 2**70, 2.5, True):\n"
            "    try:\n"
            "        diffcassi.set_num_threads(n)\n"
            "    except ValueError as e:\n"
            "        assert 'set_num_threads: n' in str(e) and '1024' in str(e), e\n"
            "    else:\n"
            "        raise SystemExit(f'accepted {n!r}')\n"
            "diffcassi.set_num_threads(3); assert diffcassi.get_num_threads() == 3\n"
            "diffcassi.set_num_threads(1024); assert diffcassi.get_num_threads() == 1024\n"
            "diffcassi.set_num_threads(0)\n"
            "print('ok')\n")
    try:
        r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("set_num_threads hung")
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stdout + r.stderr


# ------------------------------------------------------------------ integers out of range name the argument
@pytest.mark.parametrize("name, call", [
    ("height", lambda sp: diffcassi.synthetic_scene(HUGE, 4)),
    ("width", lambda sp: diffcassi.synthetic_scene(4, HUGE)),
    ("seed", lambda sp: diffcassi.synthetic_scene(4, 4, seed=-1)),
    ("height", lambda sp: diffcassi.Transport(sp, HUGE, 4, **SMALL)),
    ("width", lambda sp: diffcassi.exact(sp, 4, HUGE, **SMALL)),
    ("height", lambda sp: diffcassi.mapping_operator(sp, HUGE, 4, **SMALL)),
    ("width", lambda sp: diffcassi.shift_operator(sp, 4, -3, **SMALL)),
    ("height", lambda sp: diffcassi.mapping(sp, HUGE, 4, WL)),
    ("rays_per_wavelength", lambda sp: sp.seeded_rays(HUGE, WL, 0)),
    ("seed", lambda sp: sp.seeded_rays(4, WL, HUGE)),
    ("grid", lambda sp: diffcassi.distortion(sp, grid=HUGE)),
    ("iterations", lambda sp: diffcassi.reconstruct(diffcassi.exact(sp, 4, 4, **SMALL), np.zeros((4, 4), np.float32), iterations=HUGE)),
])
def test_out_of_range_integers_name_the_argument(sp, name, call):
    with pytest.raises(diffcassi.DiffcassiValueError, match=name):
        call(sp)


@pytest.mark.parametrize("name, call", [
    ("wavelength_nm: expected a number, got str 'abc'", lambda sp: diffcassi.spot(sp, [0.0, 0.0], "abc")),
    ("field_mm: expected two numbers", lambda sp: diffcassi.spot(sp, 3, 520.0)),
    ("field_mm: expected two numbers .* got 3", lambda sp: diffcassi.dispersion(sp, field_mm=[0.0, 1.0, 2.0])),
    ("wavelength_nm: expected a number", lambda sp: diffcassi.distortion(sp, wavelength_nm=[520.0])),
    ("half_width_mm: expected a number", lambda sp: diffcassi.distortion(sp, half_width_mm="2.5")),
])
def test_python_wrappers_name_the_argument(sp, name, call):
    with pytest.raises(diffcassi.DiffcassiValueError, match=name):
        call(sp)


def test_a_huge_memory_budget_is_no_overflow(sp):
    indptr, _, _, shape = diffcassi.exact(sp, 4, 4, **SMALL).to_csr_arrays(1e30)
    assert indptr.shape == (shape[0] + 1,)


# ------------------------------------------------------------------ limits before allocating
MEMORY = "needs an estimated .* of memory, over the budget"
RAYS = "rays to trace, over the budget"


@pytest.mark.parametrize("message, call", [
    (MEMORY, lambda sp: diffcassi.synthetic_scene(100_000, 100_000)),
    (MEMORY, lambda sp: diffcassi.mapping(sp, 100_000, 100_000, WL)),
    (MEMORY, lambda sp: diffcassi.Transport(sp, 200_000, 200_000, **SMALL)),
    (MEMORY, lambda sp: diffcassi.exact(sp, 4, 10 ** 10, **SMALL)),           # a rectangle: its own pixel count
    (MEMORY, lambda sp: diffcassi.mapping_operator(sp, 10 ** 10, 4, **SMALL)),
    (RAYS, lambda sp: diffcassi.Transport(sp, 2000, 2000, planes=112, rays=100_000)),
    (RAYS, lambda sp: diffcassi.exact(sp, 1000, 4000, planes=112, rays=100_000)),
    (RAYS, lambda sp: sp.seeded_rays(10 ** 12, WL, 0)),
    (RAYS, lambda sp: diffcassi.distortion(sp, grid=10 ** 6)),
    ("planes 1000000: must be in 1..=100000", lambda sp: diffcassi.render(sp, random_cube(8, 8, 4), WL, planes=10 ** 6)),
    ("airy_diameter_px 1000000: must be in", lambda sp: diffcassi.render(sp, random_cube(8, 8, 4), WL, airy_diameter_px=1e6)),
    ("half_width_mm", lambda sp: diffcassi.distortion(sp, half_width_mm=float("inf"))),
    ("pitch_mm", lambda sp: diffcassi.mapping(sp, 4, 4, WL, pitch_mm=0.0)),
    ("wavelengths_nm: 0 values", lambda sp: diffcassi.synthetic_scene(4, 4, wavelengths_nm=[])),
    ("wavelengths_nm: 1e9 nm is outside", lambda sp: diffcassi.synthetic_scene(4, 4, wavelengths_nm=[500.0, 1e9])),
])
def test_limits_before_allocating(sp, message, call):
    with pytest.raises(diffcassi.DiffcassiValueError, match=message):
        call(sp)


def _png_header(path, width, height):
    """A PNG whose IHDR announces width × height (no image data: refused before decoding)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk)
    return path


def test_load_scene_checks_the_png_header_before_decoding(tmp_path):
    with pytest.raises(diffcassi.DiffcassiValueError, match=f"big.png .*20000×20000 pixels.*{MEMORY}"):
        diffcassi.load_scene(_png_header(tmp_path / "big.png", 20000, 20000))
    stack = tmp_path / "stack"
    stack.mkdir()
    for k in range(31):
        _png_header(stack / f"band_{400 + 10 * k}nm.png", 30000, 30000)
    with pytest.raises(diffcassi.DiffcassiValueError, match=f"stack .*30000×30000 pixels × 31 bands.*{MEMORY}"):
        diffcassi.load_scene(stack)


# ------------------------------------------------------------------ render: the CLI's radiance limits
@pytest.mark.parametrize("value", [-1.0, 1e30, 3.5e29])
def test_render_applies_the_cli_radiance_limits(sp, value):
    cube = random_cube(8, 8, 4)
    cube[2, 3, 1] = value
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"scene: scene value .* at pixel \(2, 3\), band 1: radiances must be finite, ≥ 0"):
        diffcassi.render(sp, cube, WL, **SMALL)
    t = diffcassi.Transport(sp, 8, 8, **SMALL)
    with pytest.raises(diffcassi.DiffcassiValueError, match="radiances must be"):
        t.apply(cube)
    cube[2, 3, 1] = 3.0e29  # the largest accepted: ≤ f32::MAX / 1e9
    acq, _ = diffcassi.render(sp, cube, WL, **SMALL)
    assert np.isfinite(acq).all()


# ------------------------------------------------------------------ torch: CSR validation, dataset
torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi.torch as dt  # noqa: E402


@pytest.fixture(scope="module")
def npz(tmp_path_factory):
    t = diffcassi.Transport(diffcassi.System.preset("sp"), 6, 6, **SMALL)
    path = tmp_path_factory.mktemp("npz") / "phi.npz"
    t.save_npz(path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    return t, arrays


def _tampered(tmp_path, arrays, **changes):
    a = dict(arrays)
    a.update(changes)
    a = {k: v for k, v in a.items() if v is not None}
    path = tmp_path / "tampered.npz"
    np.savez(path, **a)
    return path


def _decreasing(indptr):
    ip = indptr.copy()
    k = int(np.argmax(ip > 1)) + 1  # the first row after one with entries
    ip[k] = ip[k - 1] - 2
    return ip


@pytest.mark.parametrize("change, message", [
    (lambda a: dict(indices=np.where(np.arange(a["indices"].size) == 3, 10 ** 8, a["indices"]).astype(np.int32)),
     r"indices\[3\] = 100000000 is outside the 144 columns"),
    (lambda a: dict(indices=np.where(np.arange(a["indices"].size) == 0, -5, a["indices"]).astype(np.int32)),
     r"indices\[0\] = -5 is outside"),
    (lambda a: dict(indptr=a["indptr"][::-1].copy()), r"indptr\[0\] = \d+, expected 0"),
    (lambda a: dict(indptr=_decreasing(a["indptr"])), r"indptr is not non-decreasing: indptr\[\d+\] = \d+ > indptr"),
    (lambda a: dict(indptr=np.concatenate([a["indptr"][:-1], a["indptr"][-1:] + 7])), r"indptr\[-1\] = \d+, expected nnz"),
    (lambda a: dict(indptr=a["indptr"][:-2]), "indptr: expected .* entries"),
    (lambda a: dict(data=a["data"][:-1]), "data: .* values but .* indices"),
    (lambda a: dict(data=np.where(np.arange(a["data"].size) == 2, np.inf, a["data"]).astype(np.float32)), r"data\[2\] = inf is not finite"),
    (lambda a: dict(indices=a["indices"].astype(np.float32)), "indices: expected an integer dtype, got float32"),
    (lambda a: dict(shape=np.array([3, 3])), r"matrix shape \(3, 3\) does not match"),
    (lambda a: dict(indices=None), "missing indices"),
    (lambda a: dict(format=np.array(b"coo")), "format 'coo', expected 'csr'"),
])
def test_from_npz_validates_before_building_tensors(npz, tmp_path, change, message):
    t, arrays = npz
    path = _tampered(tmp_path, arrays, **change(arrays))
    with pytest.raises(diffcassi.DiffcassiValueError, match=message) as e:
        dt.CassiOperator.from_npz(path, t.operator.cube_shape, t.detector_shape)
    assert "tampered.npz" in str(e.value)


def test_from_npz_file_errors_and_shapes(npz, tmp_path):
    t, arrays = npz
    with pytest.raises(diffcassi.DiffcassiFileError, match="no such file"):
        dt.CassiOperator.from_npz(tmp_path / "missing.npz", t.operator.cube_shape, t.detector_shape)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(diffcassi.DiffcassiFileError, match="junk.npz"):
        dt.CassiOperator.from_npz(tmp_path / "junk.npz", t.operator.cube_shape, t.detector_shape)
    good = _tampered(tmp_path, arrays)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"cube_shape: expected a tuple of 3 integers ≥ 1, got \(6, 6\)"):
        dt.CassiOperator.from_npz(good, (6, 6), t.detector_shape)
    with pytest.raises(diffcassi.DiffcassiValueError, match="image_shape: expected a tuple of 2 integers"):
        dt.CassiOperator.from_npz(good, t.operator.cube_shape, "ab")
    phi = dt.CassiOperator.from_npz(good, t.operator.cube_shape, t.detector_shape)
    assert phi(torch.ones(1, 4, 6, 6)).shape == (1, *t.detector_shape)


def test_from_scipy_validates(npz):
    sparse = pytest.importorskip("scipy.sparse")
    t, arrays = npz
    m = sparse.csr_matrix((arrays["data"].copy(), arrays["indices"].copy(), arrays["indptr"].copy()), shape=tuple(arrays["shape"]))
    m.indices[1] = 10 ** 7  # tampered after construction (SciPy checks only at construction)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"from_scipy: matrix: indices\[1\] = 10000000 is outside"):
        dt.CassiOperator.from_scipy(m, t.operator.cube_shape, t.detector_shape)
    with pytest.raises(TypeError, match="matrix: expected a scipy.sparse matrix, got list"):
        dt.CassiOperator.from_scipy([[1.0]], t.operator.cube_shape, t.detector_shape)


def test_csr_form_errors_name_the_argument(npz, tmp_path):
    t, arrays = npz
    phi = dt.CassiOperator.from_npz(_tampered(tmp_path, arrays), t.operator.cube_shape, t.detector_shape)
    with pytest.raises(TypeError, match=r"CassiOperator.forward: x: expected a floating-point tensor .* got torch.int32"):
        phi(torch.ones(1, 4, 6, 6, dtype=torch.int32))
    with pytest.raises(TypeError, match="CassiOperator.adjoint: y: expected a torch.Tensor, got list"):
        phi.adjoint([[0.0]])
    for dtype in (torch.float16, torch.bfloat16):  # NotImplementedError before: "any float dtype" is documented
        assert phi(torch.ones(2, 4, 6, 6, dtype=dtype)).dtype == dtype
        assert phi.adjoint(torch.ones(t.detector_shape, dtype=dtype)).dtype == dtype


def test_dataset_checks_wavelengths_against_bands():
    cube, wl = diffcassi.synthetic_scene(16, 16, seed=0, wavelengths_nm=np.linspace(450, 650, 5))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"scenes\[0\]: 5 bands .* but 2 wavelengths_nm"):
        dt.CassiDataset([(cube, wl[:2])], "sp", 8)
    with pytest.raises(diffcassi.DiffcassiValueError, match="strictly increasing"):
        dt.CassiDataset([(cube, wl[::-1])], "sp", 8)
    with pytest.raises(diffcassi.DiffcassiValueError, match="size: expected an integer ≥ 1, got int 0"):
        dt.CassiDataset([(cube, wl)], "sp", 0)
    with pytest.raises(diffcassi.DiffcassiValueError, match="length: expected an integer ≥ 0, got int -1"):
        dt.CassiDataset([(cube, wl)], "sp", 8, length=-1)
    with pytest.raises(diffcassi.DiffcassiValueError, match="the list is empty"):
        dt.CassiDataset([], "sp", 8)
    assert len(dt.CassiDataset([(cube, wl)], "sp", 8, length=3)) == 3
