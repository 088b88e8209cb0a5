"""The learned denoiser's Rust inference (``diffcassi.denoise``) against its PyTorch definition
(``diffcassi.denoiser.SpectralUNet``) with the same committed weights: equal within 1e-4 of the peak, on a size
that needs padding; thread-count independence; clear errors. Also the PnP solvers from Python."""
import numpy as np
import pytest

import diffcassi

from conftest import ROOT

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
st = pytest.importorskip("safetensors.torch", reason="safetensors not installed (scripts/setup.sh installs it)")

WEIGHTS = ROOT / "src" / "recon" / "prior" / "weights" / "spectral-unet-v2-28.safetensors"


def torch_net():
    from diffcassi.denoiser import SpectralUNet
    meta = __import__("safetensors").safe_open(str(WEIGHTS), "pt").metadata()
    assert meta["arch"] == "spectral-unet-v2"
    net = SpectralUNet(bands=int(meta["bands"]), width=int(meta["width"]), latent=int(meta["latent"]))
    net.load_state_dict(st.load_file(str(WEIGHTS)))
    return net.eval()


def natural_cube(h, w, b, seed=1):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    base = 0.5 + 0.3 * np.sin(6 * xx + 3 * yy)[..., None] * np.linspace(0.5, 1.0, b)[None, None, :]
    return np.clip(base + 0.05 * rng.standard_normal((h, w, b)), 0, 1).astype(np.float32)


@pytest.mark.parametrize("sigma", [0.02, 0.1])
def test_rust_inference_equals_pytorch(sigma):
    from diffcassi.denoiser import denoise as torch_denoise
    net = torch_net()
    cube = natural_cube(30, 26, net.bands)  # not multiples of 4: the padding path
    with torch.no_grad():
        want = torch_denoise(net, torch.from_numpy(cube).permute(2, 0, 1)[None], sigma)[0].permute(1, 2, 0).numpy()
    got = diffcassi.denoise(cube, sigma)
    assert got.shape == cube.shape and got.dtype == np.float32
    err = np.abs(got - want).max() / np.abs(want).max()
    assert err <= 1e-4, err
    # The user-file path gives the same as the embedded weights.
    assert np.array_equal(diffcassi.denoise(cube, sigma, weights=str(WEIGHTS)), got)


@pytest.mark.parametrize("neutral,ensemble", [(True, False), (False, True), (True, True)])
def test_rust_inference_options_equal_pytorch(neutral, ensemble):
    """Mean-colour neutralisation and the self-ensemble (8 dihedral transforms, on a non-square size that needs
    padding), alone and together, equal PyTorch's to 1e-4 of the peak, as the default (neither) does."""
    from diffcassi.denoiser import denoise as torch_denoise
    net = torch_net()
    cube = natural_cube(14, 22, net.bands, seed=4)
    with torch.no_grad():
        want = torch_denoise(net, torch.from_numpy(cube).permute(2, 0, 1)[None], 0.05, neutral=neutral,
                             ensemble=ensemble)[0].permute(1, 2, 0).numpy()
    got = diffcassi.denoise(cube, 0.05, neutral=neutral, ensemble=ensemble)
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()
    assert np.abs(got - diffcassi.denoise(cube, 0.05)).max() > 1e-3  # each option changes the result


def test_rust_inference_of_another_latent_width_and_bypass(tmp_path):
    """The whole v2 graph (latent K < bands, a non-zero bypass G, another width) from a user's file."""
    from diffcassi.denoiser import SpectralUNet, denoise as torch_denoise, save_weights
    torch.manual_seed(5)
    net = SpectralUNet(bands=28, width=8, latent=6)
    with torch.no_grad():
        for p in (net.lat_enc.weight, net.lat_dec.weight, net.bypass.weight):
            p.normal_(std=0.2)
    path = tmp_path / "k6.safetensors"
    save_weights(net, path)
    cube = natural_cube(13, 18, 28, seed=2)
    with torch.no_grad():
        want = torch_denoise(net.eval(), torch.from_numpy(cube).permute(2, 0, 1)[None], 0.07)[0].permute(1, 2, 0).numpy()
    got = diffcassi.denoise(cube, 0.07, weights=str(path))
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()
    assert np.abs(want - cube).max() > 0.01  # the comparison is not trivial


def test_thread_count_does_not_change_the_result():
    cube = natural_cube(20, 24, 28, seed=3)
    try:
        diffcassi.set_num_threads(1)
        a = diffcassi.denoise(cube, 0.05)
        diffcassi.set_num_threads(2)
        b = diffcassi.denoise(cube, 0.05)
    finally:
        diffcassi.set_num_threads(0)
    assert np.array_equal(a, b)


def test_bad_input_is_a_clear_error(tmp_path):
    with pytest.raises(diffcassi.DiffcassiError, match="28 bands, the cube has 5"):
        diffcassi.denoise(natural_cube(8, 8, 5), 0.1)
    with pytest.raises(diffcassi.DiffcassiValueError, match="sigma"):
        diffcassi.denoise(natural_cube(8, 8, 28), float("nan"))
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"junk")
    with pytest.raises(diffcassi.DiffcassiError, match="bad.safetensors"):
        diffcassi.denoise(natural_cube(8, 8, 28), 0.1, weights=str(bad))


def test_pnp_solvers_from_python():
    sp = diffcassi.System.preset("sp")
    settings = dict(bands_nm=list(np.linspace(450, 650, 28)), planes=28, rays=1)
    truth = natural_cube(16, 16, 28, seed=5)
    op = diffcassi.shift_operator(sp, 16, 16, **settings)
    acq = op.apply(truth)
    for solver in ("pnp-gap", "pnp-admm"):
        cube, record = diffcassi.reconstruct(op, acq, solver, iterations=3, tv_warmup=1)
        assert cube.shape == truth.shape and np.isfinite(cube).all()
        assert record["config"]["solver"] == solver and len(record["sigmas"]) == record["iterations_run"]
    with pytest.raises(diffcassi.DiffcassiError, match="σ min"):
        diffcassi.reconstruct(op, acq, "pnp-gap", sigma_min=-1.0)


def test_equivariant_pnp_from_python():
    """``equivariant=True``: the record lists one transform per network call, those of
    ``diffcassi.denoiser.dihedral_draw`` (the Rust stream's twin); the same seed gives the same cube, another
    seed or ``equivariant=False`` another; bad values are clear errors naming the keyword."""
    from diffcassi.denoiser import DIHEDRAL, dihedral_draw
    sp = diffcassi.System.preset("sp")
    settings = dict(bands_nm=list(np.linspace(450, 650, 28)), planes=28, rays=1)
    truth = natural_cube(16, 16, 28, seed=5)
    op = diffcassi.shift_operator(sp, 16, 16, **settings)
    acq = op.apply(truth)
    run = lambda **kw: diffcassi.reconstruct(op, acq, "pnp-gap", iterations=5, tv_warmup=1, **kw)
    a, ra = run(equivariant=True, equivariant_seed=11)
    b, _ = run(equivariant=True, equivariant_seed=11)
    assert np.array_equal(a, b)
    names = ["r%d%s" % (k, "+flip" if f else "") for k, f in (dihedral_draw(11, j, True) for j in range(1, 5))]
    eq = ra["denoiser"]["equivariant"]
    assert eq["on"] and eq["seed"] == 11 and eq["transforms"] == names
    assert ra["config"]["equivariant"] is True
    assert sorted(set(dihedral_draw(5, j, True) for j in range(200))) == sorted(DIHEDRAL)
    off, roff = run(equivariant=False)
    assert roff["denoiser"]["equivariant"] == {"on": False}
    assert not np.array_equal(a, off)
    other, _ = run(equivariant=True, equivariant_seed=12)
    assert not np.array_equal(a, other)
    with pytest.raises(diffcassi.DiffcassiError, match="equivariant_seed"):
        run(equivariant=True, equivariant_seed=-1)
    with pytest.raises(diffcassi.DiffcassiError, match="equivariant"):
        run(equivariant=1)
    with pytest.raises(diffcassi.DiffcassiError, match="pnp-gap and pnp-admm only"):
        diffcassi.reconstruct(op, acq, "gap-tv", equivariant=True)
