"""Round 17 of the held-out battery (2 Dec 2026): what its metamorphic prober found in the operators and solvers
from Python (docs/robustness.md, "round 17"): unevenly spaced bands, dark bands, the TV weight's scale, and the
denoiser loader's sizes before allocation."""
import warnings

import numpy as np
import pytest

import diffcassi


def _per_band_sensitivity(op):
    return op.adjoint(np.ones(op.image_shape, np.float32)).mean((0, 1))


def test_a_band_no_plane_samples_is_refused_naming_it():
    """450, 451, 650 nm with 6 planes 50 nm apart: band 450 nm got no plane, so the acquisition was blind to it
    and its reconstruction exactly 0, with exit 0 and no warning."""
    sp = diffcassi.System.preset("sp")
    wl = [450.0, 451.0, 650.0]
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"band 0 \(450 nm\) gets no render plane.*at least 300 planes"):
        diffcassi.exact(sp, 4, 4, bands_nm=wl, planes=6, rays=2)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"band 2 \(650 nm\) gets no render plane"):
        diffcassi.render(sp, np.ones((4, 4, 3), np.float32), [450.0, 640.0, 650.0], bands_nm=[450.0, 640.0, 650.0], planes=6, rays=2)


@pytest.mark.parametrize("wl,planes", [([450.0, 451.0, 650.0], 600), ([450.0, 460.0, 470.0, 650.0], 200)])
def test_the_chief_ray_models_weigh_uneven_bands_as_the_exact_operator(wl, planes):
    """The render and the exact operator integrate the spectrum over evenly spread planes, so a band weighs its
    spectral support; mapping and shift weighed every band 1 (450, 451, 650 nm: exact 0.01 / 1.0 / 1.99,
    mapping 1 / 1 / 1): a mapping reconstruction of such a render was biased band by band."""
    sp = diffcassi.System.preset("sp")
    settings = dict(bands_nm=wl, planes=planes, opening=1.0)
    exact = _per_band_sensitivity(diffcassi.exact(sp, 8, 8, rays=4, **settings))
    support = np.array([wl[1] - wl[0]] + [(wl[k + 1] - wl[k - 1]) / 2 for k in range(1, len(wl) - 1)] + [wl[-1] - wl[-2]])
    want = support / support.mean()
    assert np.allclose(exact, want, rtol=0.02), (exact, want)
    for op in (diffcassi.mapping_operator(sp, 8, 8, **settings), diffcassi.shift_operator(sp, 8, 8, **settings)):
        got = _per_band_sensitivity(op)
        assert np.allclose(got, want, rtol=1e-5), (got, want)
    # Evenly spaced bands keep weight 1 exactly (f32), so every earlier result is unchanged.
    even = _per_band_sensitivity(diffcassi.mapping_operator(sp, 8, 8, planes=28, opening=1.0))
    assert np.all(even == np.float32(1.0)), even


def test_an_operator_with_dark_bands_warns_and_its_reconstruction_says_so():
    """ddsp at 3×3: render warned that the planes pass no light, exact / mapping_operator were built silently
    (zero in every band, or in all but one)."""
    dd = diffcassi.System.preset("ddsp")
    wl = [450.0, 520.0, 600.0, 650.0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        op = diffcassi.mapping_operator(dd, 3, 3, bands_nm=wl, planes=4, opening=1.0)
    text = [str(w.message) for w in caught if "seen by no detector pixel" in str(w.message)]
    assert len(text) == 1 and "3 of 4 bands (450 nm, 600 nm, 650 nm)" in text[0], [str(w.message) for w in caught]
    y = op.apply(np.ones((3, 3, 4), np.float32))
    assert y.sum() > 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est, record = diffcassi.reconstruct(op, y, iterations=3)
    assert np.all(est[:, :, [0, 2, 3]] == 0)
    said = [str(w.message) for w in caught if "seen by no detector pixel" in str(w.message)]
    assert said and "index 0, 2, 3" in said[0], [str(w.message) for w in caught]
    # An operator that sees every band says nothing.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        diffcassi.mapping_operator(diffcassi.System.preset("sp"), 8, 8, bands_nm=wl, planes=4)
    assert not [w for w in caught if "seen by no detector pixel" in str(w.message)]


def test_a_tv_weight_far_from_the_cubes_scale_is_warned():
    """The TV weight is absolute (cube units; the default 0.1 tuned for peaks ≈ 1): a scene ×100 reconstructed
    at 0.1 moved by 0.55 of its peak, without a word."""
    sp = diffcassi.System.preset("sp")
    wl = list(np.linspace(450.0, 650.0, 4))
    cube = diffcassi.synthetic_scene(12, 12, 1, wl)[0]
    op = diffcassi.mapping_operator(sp, 12, 12, bands_nm=wl, planes=4)

    def tv_warnings(scale):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            diffcassi.reconstruct(op, op.apply(cube * np.float32(scale)), iterations=5)
        return [str(w.message) for w in caught if "TV weight" in str(w.message)]

    assert not tv_warnings(1.0)
    big = tv_warnings(1000.0)
    assert big and "barely regularised" in big[0], big
    small = tv_warnings(1e-3)
    assert small and "smoothed towards a constant" in small[0], small


def test_the_denoiser_loader_refuses_a_width_before_allocating_it(tmp_path):
    """A 4 MB file whose metadata said width 99999999 asked torch for 47 GB before any shape check; a width of
    4000 would have been allocated (gigabytes) before its tensors were compared."""
    torch = pytest.importorskip("torch")  # noqa: F841
    from safetensors import safe_open
    from safetensors.torch import save_file

    import diffcassi.denoiser as dn
    from pathlib import Path

    src = Path(diffcassi.__file__).resolve().parent.parent / "src/recon/prior/weights/spectral-unet-v2-28.safetensors"
    if not src.exists():
        pytest.skip("the repository's denoiser weights are not beside this package")
    with safe_open(str(src), framework="pt") as f:
        meta, tensors = dict(f.metadata()), {k: f.get_tensor(k) for k in f.keys()}
    for width, match in (("99999999", "each must be ≤ 4096"), ("4000", r"expected \(4000,\)")):
        path = tmp_path / f"w{width}.safetensors"
        save_file(tensors, str(path), metadata={**meta, "width": width})
        with pytest.raises(ValueError, match=match):
            dn.load_weights(path)
    assert dn.load_weights(src) is not None
