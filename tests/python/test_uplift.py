"""`diffcassi.uplift_srgb`: Smits' RGB → reflectance uplift of the library (src/scene/natural.rs), the one
`load_scene` applies to a PNG photograph and the dead-leaves generator to its RGB leaves (issue 40: one
implementation; the NumPy twin `diffcassi/smits.py` is gone). Needs no torch."""
import struct
import zlib

import numpy as np
import pytest

import diffcassi

BANDS = list(np.linspace(450, 650, 28))


def _write_png(path, rgb8):
    """A minimal 8-bit RGB PNG writer (zlib + struct; no imaging package needed)."""
    h, w, _ = rgb8.shape
    raw = b"".join(b"\x00" + rgb8[y].tobytes() for y in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_uplift_equals_load_scene_of_the_png(tmp_path):
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    # Every branch of Smits' case analysis, ties, black, white and the sRGB curve's linear segment.
    img[0, :9] = [[0, 0, 0], [255, 255, 255], [10, 10, 10], [200, 50, 50], [50, 200, 50], [50, 50, 200],
                  [200, 200, 50], [50, 200, 200], [200, 50, 200]]
    _write_png(tmp_path / "rgb.png", img)
    for bands in (BANDS, list(np.linspace(400, 700, 31))):
        want, wl = diffcassi.load_scene(tmp_path / "rgb.png", bands)
        got = diffcassi.uplift_srgb((img / 255.0).astype(np.float32), bands)
        assert got.dtype == np.float32 and got.shape == (20, 30, len(bands)) and wl == bands
        assert np.array_equal(got, want)
    # The default bands are load_scene's (28 bands 450–650 nm).
    assert np.array_equal(diffcassi.uplift_srgb((img / 255.0).astype(np.float32)), diffcassi.load_scene(tmp_path / "rgb.png")[0])


def test_uplift_values():
    got = diffcassi.uplift_srgb(np.array([[[1, 1, 1], [0, 0, 0], [1, 0, 0], [0, 0, 1]]], np.float32), BANDS)[0]
    assert (got[0] > 0.99).all() and np.ptp(got[0]) < 0.002  # Smits' white × 0.94: flat, ≈ 1
    assert (got[1] == 0).all()
    assert got[2, -1] > 0.9 > 0.2 > got[2, 0]  # red: long wavelengths
    assert got[3, 0] > 0.9 > 0.2 > got[3, -1]  # blue: short wavelengths
    assert ((got >= 0) & (got <= 1)).all()


@pytest.mark.parametrize("srgb, bands, match", [
    (np.zeros((2, 2, 3), np.float64), BANDS, "srgb: expected dtype float32"),
    (np.zeros((2, 2, 4), np.float32), BANDS, r"srgb: expected shape \(H, W, 3\)"),
    (np.zeros((2, 3), np.float32), BANDS, "srgb: expected 3 dimensions"),
    (np.zeros((0, 2, 3), np.float32), BANDS, r"srgb: expected shape \(H, W, 3\) with H, W ≥ 1"),
    (np.full((2, 2, 3), 1.5, np.float32), BANDS, r"srgb: value 1.5 at index \[0, 0, 0\] is outside \[0, 1\]"),
    (np.full((2, 2, 3), np.nan, np.float32), BANDS, "srgb: value NaN at index .* is not finite"),
    (np.zeros((2, 2, 3), np.float32), [370.0, 500.0], "370 nm is outside the 380–720 nm range of the Smits"),
    (np.zeros((2, 2, 3), np.float32), [], "wavelengths_nm: 0 values"),
    (np.zeros((2, 2, 3), np.float32), [500.0, float("inf")], "wavelengths_nm: value inf"),
])
def test_uplift_bad_input(srgb, bands, match):
    with pytest.raises(diffcassi.DiffcassiValueError, match=match):
        diffcassi.uplift_srgb(srgb, bands)
    with pytest.raises(ValueError):  # also a ValueError
        diffcassi.uplift_srgb(srgb, bands)


def test_uplift_memory_limit():
    try:
        diffcassi.set_limits(max_memory_gb=1e-6)
        with pytest.raises(diffcassi.DiffcassiValueError, match="max_memory_gb"):
            diffcassi.uplift_srgb(np.zeros((64, 64, 3), np.float32), BANDS)
    finally:
        diffcassi.set_limits()
