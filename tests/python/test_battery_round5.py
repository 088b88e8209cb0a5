"""What a fifth held-out battery found in the Python layer, each now refused or fixed: `CassiRenderer.temperature`
set to 0 or below after construction (NaN gradients, an inverted mask), `CassiDataset.set_epoch` not reaching
persistent DataLoader workers (every epoch the same), complex/bool/object cubes and non-integer indices in the
dataset, a one-band scene outside the transport's bands (rendered as if inside), `from_npz` given a wrongly
factored shape or a shape of 22.5 (scrambled or truncated silently), `save_npz` into a missing folder (an error
naming the stage file), and `denoise`/`reconstruct` errors that named neither the argument nor the value.
Tiny sizes only (8–16 px, few planes and rays)."""
import copy
import inspect
import re
import pickle
import warnings

import numpy as np
import pytest

import diffcassi

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi.torch as dt  # noqa: E402

BANDS4 = [480.0, 520.0, 560.0, 600.0]


@pytest.fixture(scope="module")
def op():
    return diffcassi.exact(diffcassi.System.preset("sp"), 8, 8, bands_nm=BANDS4, planes=4, rays=1)


# ------------------------------------------------------------------ 1: CassiRenderer.temperature
def test_renderer_temperature_is_checked_on_assignment():
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), 8, 8, rays=1, planes=2, bands_nm=[500.0, 540.0], temperature=0.5)
    keys = set(r.state_dict())
    for bad in (0.0, 0, -0.5, float("nan"), float("inf"), 10 ** 400):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiRenderer\.temperature = .*: must be a finite number > 0"):
            r.temperature = bad
    for bad in (True, np.bool_(True), "1", None, torch.tensor(0.5)):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiRenderer\.temperature = .*: must be a finite number > 0, got"):
            r.temperature = bad
    assert r.temperature == 0.5  # a refused value leaves the old one
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"^temperature = 0: must be a finite number > 0"):
        dt.CassiRenderer(diffcassi.System.preset("sp"), 8, 8, rays=1, planes=2, bands_nm=[500.0, 540.0], temperature=0)
    # Annealing as the docs teach: a number (NumPy's too) is used as given, the gradients stay finite.
    r.temperature = np.float32(0.25)
    assert type(r.temperature) is float and r.temperature == 0.25
    assert torch.equal(r.mask(), torch.sigmoid(r.mask_logits / 0.25))
    cube = torch.rand(1, 2, 8, 8, dtype=torch.float64)
    r(cube).sum().backward()
    assert torch.isfinite(r.mask_logits.grad).all() and float(r.mask_logits.grad.abs().sum()) > 0
    # Since round 6 the temperature is saved with the state (`_extra_state`): a restored renderer renders alike.
    assert set(r.state_dict()) == keys == {"mask_logits", "theta", "_extra_state"}
    # (since round 9 with θ's free parameters and the system's prescription: a state of another renderer is refused)
    assert r.state_dict()["_extra_state"] == {"temperature": 0.25, "free": list(r.names),
                                              "system_sha256": diffcassi.System.preset("sp").prescription_sha256()}


# ------------------------------------------------------------------ 2: set_epoch and persistent workers
def _epoch_dataset():
    cube = np.random.default_rng(4).random((16, 16, 3), dtype=np.float32)
    return dt.CassiDataset([(cube, [450.0, 550.0, 650.0])], "sp", 8, length=2,
                           transport=dict(rays=1, planes=4, bands_nm=[450.0, 550.0, 650.0]))


def _items(ds, epoch):
    ds.set_epoch(epoch)
    return [ds[i] for i in range(len(ds))]


def _loaded(loader, ds, epoch):
    ds.set_epoch(epoch)
    return [item for batch in loader for item in zip(*batch)]


def _assert_same(got, ref):
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        for u, v in zip(a, b):
            assert torch.equal(u, v)


def test_set_epoch_reaches_persistent_workers():
    ds = _epoch_dataset()
    ref = {e: _items(ds, e) for e in (0, 1)}
    assert not torch.equal(ref[0][0][2], ref[1][0][2]) or not torch.equal(ref[0][1][2], ref[1][1][2])
    # batch_size 1: each of the two workers renders an item; the same workers serve every epoch.
    loader = torch.utils.data.DataLoader(ds, batch_size=1, num_workers=2, persistent_workers=True)
    for epoch in (0, 1, 0, 1):
        _assert_same(_loaded(loader, ds, epoch), ref[epoch])
    ds.epoch = 0  # assigning the attribute is set_epoch (checked the same)
    assert ds.epoch == 0
    _assert_same(_loaded(loader, ds, 0), ref[0])
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiDataset: epoch: expected an integer in 0\.\.=9223372036854775807, got 1180591620717411303424"):
        ds.set_epoch(2 ** 70)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiDataset: epoch: expected an integer ≥ 0, got float 1.5"):
        ds.epoch = 1.5


def test_set_epoch_reaches_a_spawned_persistent_worker():
    # spawn pickles the dataset to the worker: the epoch travels as a shared-memory handle (torch's reductions).
    ds = _epoch_dataset()
    ref = {e: _items(ds, e) for e in (0, 1)}
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=1, persistent_workers=True,
                                         multiprocessing_context="spawn")
    for epoch in (1, 0, 1):
        _assert_same(_loaded(loader, ds, epoch), ref[epoch])


def test_copies_of_the_dataset_have_their_own_epoch():
    ds = _epoch_dataset()
    ref = {e: _items(ds, e) for e in (0, 2)}
    ds.set_epoch(2)
    for make in (copy.copy, copy.deepcopy, lambda d: pickle.loads(pickle.dumps(d))):
        c = make(ds)
        assert c.epoch == 2 and c._epoch.is_shared()
        _assert_same([c[i] for i in range(len(c))], ref[2])
        c.set_epoch(0)
        assert ds.epoch == 2 and c.epoch == 0
        _assert_same([c[i] for i in range(len(c))], ref[0])
        ds.set_epoch(2)
        assert c.epoch == 0


# ------------------------------------------------------------------ 3: dtypes and indices
@pytest.mark.parametrize("cube, dtype", [
    (np.full((16, 16, 3), 0.5, np.float32).astype(np.complex64) + 1j, "complex64"),
    (np.ones((16, 16, 3), bool), "bool"),
    (np.full((16, 16, 3), 0.5, np.float32).astype(object), "object"),
    (np.full((16, 16, 3), "0.5"), "<U3"),
    (torch.ones(16, 16, 3, dtype=torch.complex64), "complex64"),
])
def test_the_dataset_refuses_non_real_cubes(cube, dtype):
    good = (np.full((16, 16, 3), 0.5, np.float32), [450.0, 550.0, 650.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning first: refused before any cast
        with pytest.raises(diffcassi.DiffcassiValueError, match=rf"CassiDataset: scenes\[1\]: cube dtype {dtype} is not real"):
            dt.CassiDataset([good, (cube, [450.0, 550.0, 650.0])], "sp", 8)
    # Real integer cubes are still converted.
    ds = dt.CassiDataset([(np.full((16, 16, 3), 2, np.uint8), [450.0, 550.0, 650.0])], "sp", 8,
                         transport=dict(rays=1, planes=4, bands_nm=[450.0, 550.0, 650.0]))
    assert float(ds[0][2].min()) == 2.0


def test_dataset_indices_are_integers_in_range():
    ds = _epoch_dataset()
    ref = ds[1]
    for same in (np.int64(1), np.uint8(1), torch.tensor(1)):
        _assert_same([ds[same]], [ref])
    for bad in (1.5, np.float64(1.0), True, np.bool_(True), "1", None, torch.tensor(1.0), torch.tensor([1])):
        with pytest.raises(TypeError, match=r"CassiDataset: index: expected an integer .*, got "):
            ds[bad]
    with pytest.raises(TypeError, match=r"got float 1.5"):
        ds[1.5]
    for bad in (2, -1, 10 ** 30):
        with pytest.raises(IndexError, match=rf"CassiDataset: index {bad} is out of range for a dataset of length 2"):
            ds[bad]
    assert len(list(ds)) == 2  # iteration still stops at the IndexError


# ------------------------------------------------------------------ 4: one-band scenes
def test_a_one_band_scene_outside_the_transport_bands_is_refused():
    cube = np.full((16, 16, 1), 0.5, np.float32)
    t = dict(bands_nm=BANDS4, rays=1, planes=4)
    for band in (5000.0, 300.0, 479.0, 601.0):
        ds = dt.CassiDataset([(cube, [band])], "sp", 8, transport=t)
        with pytest.raises(diffcassi.DiffcassiValueError,
                           match=rf"CassiDataset: the scene's band \({band:g} nm\) lies outside the transport's \(480 – 600 nm\)"):
            ds[0]
    # Inside (the ends included): a flat spectrum, the band at every transport band, without a warning.
    for band in (480.0, 530.0, 600.0):
        ds = dt.CassiDataset([(cube, [band])], "sp", 8, transport=t)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            truth = ds[0][2]
        assert truth.shape == (4, 8, 8) and torch.equal(truth, torch.full((4, 8, 8), 0.5))
    # Multi-band scenes: as before.
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"scene's bands \(5000 – 5100 nm\) lie outside the transport's"):
        dt.CassiDataset([(np.full((16, 16, 2), 0.5, np.float32), [5000.0, 5100.0])], "sp", 8, transport=t)[0]


# ------------------------------------------------------------------ 5: from_npz shapes, save_npz's folder
def test_save_npz_records_the_shapes_and_from_npz_checks_them(op, tmp_path):
    scipy_sparse = pytest.importorskip("scipy.sparse")
    path = tmp_path / "phi.npz"
    op.save_npz(path)
    with np.load(path) as z:
        assert z["cube_shape"].tolist() == list(op.cube_shape) and z["image_shape"].tolist() == list(op.image_shape)
        assert z["cube_shape"].dtype == np.int64
        arrays = {k: z[k] for k in z.files}
    a = scipy_sparse.load_npz(path)  # SciPy ignores the extra keys
    cube = np.random.default_rng(2).random(op.cube_shape, dtype=np.float32)
    ref = op.apply(cube)
    assert a.shape == (ref.size, cube.size)
    assert np.abs(a @ cube.ravel() - ref.ravel()).max() <= 1e-5 * ref.max()
    h, w = op.image_shape
    H, W, B = op.cube_shape
    assert h != w and H * W * B == W * H * B
    with pytest.raises(diffcassi.DiffcassiValueError,
                       match=rf"phi.npz: image_shape \({w}, {h}\) given, but the file was written for image_shape \({h}, {w}\)"):
        dt.CassiOperator.from_npz(path, op.cube_shape, (w, h))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"cube_shape \(8, 4, 8\) given, but the file was written for cube_shape \(8, 8, 4\)"):
        dt.CassiOperator.from_npz(path, (8, 4, 8), op.image_shape)
    phi = dt.CassiOperator.from_npz(path, op.cube_shape, op.image_shape)
    y = phi(torch.from_numpy(cube).permute(2, 0, 1))
    assert float((y - torch.from_numpy(ref)).abs().max()) <= 1e-5 * float(ref.max())
    # Non-integer entries: refused, not truncated (in the matrix shape and in the recorded shapes).
    for key, value, message in (("shape", np.array([h * w + 0.5, H * W * B + 0.5]), r"shape: expected 2 integers ≥ 0, got"),
                                ("shape", np.array([float(h * w), float(H * W * B)]), r"shape: expected 2 integers ≥ 0, got"),
                                ("image_shape", np.array([h + 0.5, w + 0.5]), r"image_shape \(in the file\): expected 2 integers ≥ 1"),
                                ("cube_shape", np.array([8, 8]), r"cube_shape \(in the file\): expected 3 integers ≥ 1")):
        bad = tmp_path / f"bad-{key}.npz"
        np.savez(bad, **dict(arrays, **{key: value}))
        with pytest.raises(diffcassi.DiffcassiValueError, match=message):
            dt.CassiOperator.from_npz(bad, op.cube_shape, op.image_shape)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"from_scipy: matrix: shape: expected 2 integers"):
        dt.CassiOperator(a.indptr, a.indices, a.data, (h * w + 0.5, H * W * B), op.cube_shape, op.image_shape,
                         _source="from_scipy: matrix")
    # A file without the record (SciPy's own save_npz, an older diffcassi): the products are all it can check.
    old = tmp_path / "old.npz"
    scipy_sparse.save_npz(old, a)
    assert torch.equal(dt.CassiOperator.from_npz(old, op.cube_shape, op.image_shape)(y.new_ones(B, H, W)),
                       phi(y.new_ones(B, H, W)))


def test_save_npz_into_a_missing_folder_names_the_target(op, tmp_path):
    target = tmp_path / "nodir" / "op.npz"
    with pytest.raises(diffcassi.DiffcassiFileError, match=r"save_npz: cannot write .*nodir/op\.npz: its folder .*nodir does not exist") as e:
        op.save_npz(target)
    assert "stage" not in str(e.value)
    (tmp_path / "afile").write_text("x")
    with pytest.raises(diffcassi.DiffcassiFileError, match=r"its folder .*afile is not a folder"):
        op.save_npz(tmp_path / "afile" / "op.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


# ------------------------------------------------------------------ 6: denoise's sigma, reconstruct's keywords
def test_denoise_names_sigma():
    x = np.random.default_rng(0).random((8, 8, 28), dtype=np.float32)
    for bad, shown in (("a", "str 'a'"), (None, "NoneType None"), (True, "bool True"), ([0.1, 0.2], r"list \[0.1, 0.2\]")):
        with pytest.raises(diffcassi.DiffcassiValueError, match=rf"^sigma: expected a number .*, got {shown}"):
            diffcassi.denoise(x, bad)
    ref = diffcassi.denoise(x, 0.05)
    for same in (np.float32(0.05), np.float64(0.05), torch.tensor(0.05, dtype=torch.float64), np.array(0.05)):
        assert np.array_equal(diffcassi.denoise(x, same), ref)
    with pytest.raises(diffcassi.DiffcassiValueError, match="sigma = -1"):
        diffcassi.denoise(x, -1)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"sigma = 1e300: must be finite, ≥ 0 and ≤ 3\.403e29"):
        diffcassi.denoise(x, 1e300)  # named as given, not as the inf of its f32 cast


def test_reconstruct_names_an_unknown_keyword_and_the_valid_ones(op):
    y = np.zeros(op.image_shape, np.float32)
    native = [k for k in inspect.signature(diffcassi._native._reconstruct).parameters][4:]
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"^reconstruct: unexpected keyword `bogus` \(valid: (.*)\)$") as e:
        diffcassi.reconstruct(op, y, bogus=1)
    assert str(e.value).split("(valid: ")[1].rstrip(")").split(", ") == native
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"unexpected keyword `iteration` \(valid: iterations, "):
        diffcassi.reconstruct(op, y, iteration=2)
    # The keywords the Python layer checks and the docstring names are all the native solve's (no drift).
    documented = {"iterations", "step", "tv_weight", "tv_iterations", "tv_coupling", "accelerated", "admm_eta", "discrepancy",
                  "noise_norm", "tolerance", "tv_warmup", "sigma_max", "sigma_min", "sigma_auto", "denoiser", "equivariant",
                  "equivariant_seed", "noise_twin", "noise_factor"}
    assert set(diffcassi._SOLVER_INTS) <= set(native) and documented <= set(native)
    cube, record = diffcassi.reconstruct(op, y, iterations=1)
    assert cube.shape == op.cube_shape


# ------------------------------------------------------------------ the unrolled network at scale 0
def test_the_unrolled_network_reconstructs_a_dark_frame_as_zero():
    """s = mean|x₀|: a zero acquisition gives a zero cube (a scale of 1 there let the stages' biases through: a
    cube of mean 0.25 from a black frame), in PyTorch and in Rust alike; N(a·y) = a·N(y) down to a = 0."""
    T = diffcassi.Transport(diffcassi.System.preset("sp"), 16, 16, rays=1, planes=28)
    phi = dt.CassiOperator.from_operator(T, matrix_free=True)
    net = dt.load_unrolled(str(diffcassi.__path__[0]) + "/weights/unrolled-gap-v1-sp.safetensors", phi, system="sp")
    y = torch.from_numpy(T.apply(np.random.default_rng(0).random((16, 16, 28)).astype(np.float32)).astype(np.float32))
    with torch.no_grad():
        assert torch.count_nonzero(net(torch.zeros_like(y))) == 0
        big, tiny = net(y), net(1e-30 * y)
        assert torch.allclose(1e-30 * big, tiny, rtol=1e-3, atol=0)
        assert torch.isfinite(net(-y)).all()
    # The Rust network (`reconstruct --solver unrolled`): tests/recon_unrolled.rs, zero_denoisers_give_plain_gap….


# ------------------------------------------------------------------ values beyond the operators' f32 range
def test_operator_modules_refuse_values_beyond_the_f32_range(op):
    """The torch operators refuse, on CPU tensors, what Operator.apply refuses (|v| > f32 max / 1e9): 3e38
    gave inf, 1e36 through an unrolled network NaN; float64 1e300 is named as given, not as inf."""
    mf = dt.CassiOperator.from_operator(op, matrix_free=True)
    csr = dt.CassiOperator.from_operator(op)
    H, W, B = op.cube_shape
    for module in (mf, csr):
        name = type(module).__name__
        for v, dtype in ((3e38, torch.float32), (1e35, torch.float32), (1e300, torch.float64), (float("nan"), torch.float32)):
            with pytest.raises(diffcassi.DiffcassiValueError, match=rf"{name}\.forward: x: value .* at index \[0, 0, 0, 0\] is not finite or beyond"):
                module(torch.full((1, B, H, W), v, dtype=dtype))
            with pytest.raises(diffcassi.DiffcassiValueError, match=rf"{name}\.adjoint: y: value .* is not finite or beyond"):
                module.adjoint(torch.full((1, *op.image_shape), v, dtype=dtype))
        ok = module(torch.full((1, B, H, W), 1e29))  # within the limit: finite
        assert torch.isfinite(ok).all()
    # The numpy paths: a float64 value float32 cannot hold is named as given.
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"acquisition: value 1(\.0+)?e\+?300 at index \[0, 0\]"):
        diffcassi.reconstruct(op, np.full(op.image_shape, 1e300))
    T = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, bands_nm=BANDS4, planes=4, rays=1)
    for v in (3.4e38, 1e300):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"image: value .* beyond"):
            T.adjoint(np.full(T.detector_shape, v))


def test_unrolled_networks_refuse_values_beyond_the_f32_range():
    T = diffcassi.Transport(diffcassi.System.preset("sp"), 16, 16, rays=1, planes=28)
    phi = dt.CassiOperator.from_operator(T)
    net = dt.load_unrolled(str(diffcassi.__path__[0]) + "/weights/unrolled-gap-v1-sp.safetensors", phi, system="sp")
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"UnrolledGAP\.forward: y holds .* values beyond"):
        net(torch.full(phi.image_shape, 1e36))


# ------------------------------------------------------------------ pickling a System
def test_a_system_pickles_and_copies_bit_for_bit():
    s = diffcassi.System.preset("gsp")
    for c in (pickle.loads(pickle.dumps(s)), copy.copy(s), copy.deepcopy(s)):
        assert c.to_json() == s.to_json() and c.prescription_sha256() == s.prescription_sha256()
        fields = np.array([[0.0, 0.0], [1.0, -2.0]])
        o, d, w = s.chief_rays(fields, 520.0)
        assert all(np.array_equal(a, b) for a, b in zip(c.chief_rays(fields, 520.0), (o, d, w)))


def test_an_empty_batch_goes_both_ways(op):
    """A batch of 0 through the adjoint (a bare torch reshape error before: `-1` is ambiguous for 0 elements)."""
    csr = dt.CassiOperator.from_operator(op)
    H, W, B = op.cube_shape
    assert csr.adjoint(torch.zeros(0, *op.image_shape)).shape == (0, B, H, W)
    assert csr(torch.zeros(0, B, H, W)).shape == (0, *op.image_shape)


def test_the_python_writers_never_write_over_a_pipe_a_link_or_a_folder(op, tmp_path):
    """`save_npz`, `save_weights` and `save_unrolled` go through one staged writer (diffcassi._files), which refuses
    what the command line's output policy refuses: a named pipe or a device (renamed over, the node was replaced),
    a symbolic link (written in its place, the link was replaced), a folder, a missing folder."""
    import os
    from diffcassi.denoiser import SpectralUNet, save_weights
    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    (tmp_path / "real.npz").write_bytes(b"keep")
    os.symlink("real.npz", tmp_path / "link.npz")
    (tmp_path / "dir.npz").mkdir()
    for bad, says in ((fifo, "is a named pipe"), (tmp_path / "link.npz", "is a symbolic link (to real.npz)"), (tmp_path / "dir.npz", "is a folder")):
        with pytest.raises(diffcassi.DiffcassiFileError, match=rf"save_npz: .*{re.escape(says)}"):
            op.save_npz(bad)
    assert os.path.islink(tmp_path / "link.npz") and (tmp_path / "real.npz").read_bytes() == b"keep"
    import stat
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    with pytest.raises(diffcassi.DiffcassiFileError, match=r"save_weights: .*is a named pipe"):
        save_weights(SpectralUNet(bands=4, width=4), fifo)
    save_weights(SpectralUNet(bands=4, width=4), tmp_path / "w.safetensors")  # a regular path still writes
    assert (tmp_path / "w.safetensors").stat().st_size > 0 and not list(tmp_path.glob(".*stage*"))
