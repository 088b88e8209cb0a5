"""Round 17 (prober C, file formats), seen from Python: ``load_scene``'s hints name its own keyword, a
symbolic-link loop is said as such, an integer NPY cube is checked against ``set_limits`` from its element
count (the file + 4 bytes per element; "4× its file size" let an 8-bit cube peak 3× over the budget), a
float64 value beyond float32 is named, and ``read_exr`` reads own EXRs of 201 bands back bit for bit."""
import os
import shutil
import subprocess

import numpy as np
import pytest

import diffcassi


@pytest.fixture
def default_limits():
    yield
    diffcassi.set_limits()


def test_missing_wavelength_list_names_the_python_keyword(tmp_path):
    np.save(tmp_path / "c.npy", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(diffcassi.DiffcassiFileError) as e:
        diffcassi.load_scene(str(tmp_path / "c.npy"))
    assert "wavelengths_nm" in str(e.value) and "scene_wavelengths" not in str(e.value), e.value


def test_symlink_loop_is_not_called_missing(tmp_path):
    p = tmp_path / "loop.npy"
    os.symlink(p, p)
    with pytest.raises(diffcassi.DiffcassiFileError) as e:
        diffcassi.load_scene(str(p))
    assert "symbolic links" in str(e.value) and "no such file" not in str(e.value), e.value


def test_integer_npy_is_checked_from_its_element_count(tmp_path, default_limits):
    # 10 MB of uint8 = 50 MB once read (file + 4 B per element): refused under 30 MB, read under 80 MB.
    cube = (np.arange(1000 * 1000 * 10) % 251).astype(np.uint8).reshape(1000, 1000, 10)
    np.save(tmp_path / "u8.npy", cube)
    np.save(tmp_path / "u8_wavelengths_nm.npy", np.linspace(450.0, 650.0, 10))
    diffcassi.set_limits(max_memory_gb=0.03)
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.load_scene(str(tmp_path / "u8.npy"))
    assert "'|u1'" in str(e.value) and "max_memory_gb" in str(e.value), e.value
    diffcassi.set_limits(max_memory_gb=0.08)
    c, wl = diffcassi.load_scene(str(tmp_path / "u8.npy"))
    assert c.dtype == np.float32 and np.array_equal(c, cube.astype(np.float32))


def test_float64_beyond_float32_is_named(tmp_path):
    a = np.full((3, 3, 3), 0.5)
    a[2, 2, 2] = 1e39
    np.save(tmp_path / "b.npy", a)
    np.save(tmp_path / "b_wavelengths_nm.npy", np.array([450.0, 550.0, 650.0]))
    with pytest.raises(diffcassi.DiffcassiValueError) as e:
        diffcassi.load_scene(str(tmp_path / "b.npy"))
    assert "1e39" in str(e.value) and "float32 range" in str(e.value), e.value


def test_many_band_exr_reads_back_bit_for_bit(tmp_path):
    # make-scene writes `band_200_3500nm`; the index 200 was read back as the wavelength.
    exe = shutil.which("diffcassi") or os.path.join(os.path.dirname(diffcassi.__file__), "..", "target", "release", "diffcassi")
    if not os.path.exists(exe):
        pytest.skip("the CLI is not built")
    wl = np.array([400.0 + k for k in range(200)] + [3500.0])
    out = tmp_path / "s.exr"
    r = subprocess.run([exe, "make-scene", "--synthetic", "1", "--size", "4", "--bands", ",".join(str(w) for w in wl), "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    c, back = diffcassi.load_scene(str(out))
    assert np.array_equal(np.asarray(back).view(np.uint64), wl.view(np.uint64)), back[:3]
    assert "band_200_3500nm" in [n for n, _ in diffcassi.read_exr(str(out))]
