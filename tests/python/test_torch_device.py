"""The torch modules' device path (issue 41 items 3–4), run on the CPU: the exact operator as deterministic gather
tables (`diffcassi._gather`, the code CUDA tensors run) equals the exported matrix and the Rust operator, is its
own adjoint's transpose, bit-reproducible, differentiable; devices are checked (`.to`, `device=`); the matrix-free
operator's device table; `CassiRenderer`'s table path equals the Rust render; `UnrolledGAP` follows its operator's
device and dtype; the GPU check script runs at a tiny size on the CPU."""
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi import _gather, _gpu_check  # noqa: E402
from conftest import SMALL  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
U = 2.0 ** -24  # float32 unit roundoff
NO_CUDA = not torch.cuda.is_available()


@pytest.fixture(scope="module")
def transport():
    return diffcassi.Transport(diffcassi.System.preset("sp"), 8, 10, **SMALL)


@pytest.fixture(scope="module")
def csr(transport):
    return transport.operator.to_csr_arrays()


@pytest.fixture(scope="module")
def phi(transport):
    return dt.CassiOperator.from_operator(transport)


def _exact(csr, x64, absolute=False):
    """The exported matrix (columns [row][col][band]) applied in float64 to cubes x (N, bands, H, W): (N, rows)."""
    indptr, indices, data, (rows, cols) = csr
    a = np.abs(data.astype(np.float64)) if absolute else data.astype(np.float64)
    xs = x64.permute(0, 2, 3, 1).reshape(x64.shape[0], -1).numpy()
    row = np.repeat(np.arange(rows), np.diff(indptr))
    out = np.zeros((x64.shape[0], rows))
    for n in range(x64.shape[0]):
        np.add.at(out[n], row, a * xs[n, indices])
    return torch.from_numpy(out)


def test_gather_equals_the_exported_matrix_and_rust(phi, csr, transport):
    x = torch.rand(3, 4, 8, 10, generator=torch.Generator().manual_seed(0))
    ref = _exact(csr, x.double())
    # float64: the table holds the export's float32 values exactly and sums in float64.
    y64 = phi(x.double()).reshape(3, -1)
    assert float((y64 - ref).abs().max()) <= 1e-12 * float(ref.abs().max())
    # float32: each output is a float32 dot product of the row's n entries, so |error| ≤ γ_(n+1)·(|A||x|)_row
    # (Higham's bound for products and a sum in any order, γ_k = k·u/(1 − k·u)): asserted row by row.
    y32 = phi(x).reshape(3, -1).double()
    n = torch.from_numpy(np.diff(csr[0])).double() + 1
    bound = (n * U / (1 - n * U)) * _exact(csr, x.double(), absolute=True)
    assert bool(((y32 - ref).abs() <= bound).all())
    # The Rust operator (its own float32 evaluation of the same Φ): within 1e-6 of the peak (measured 3.1e-7;
    # the export itself is within 3.4e-7 of it, docs/python.md).
    for b in range(3):
        r = torch.from_numpy(transport.operator.apply(np.ascontiguousarray(x[b].permute(1, 2, 0).numpy())))
        assert float((phi(x[b]) - r).abs().max()) <= 1e-6 * float(r.abs().max())
    img = torch.rand(2, *transport.detector_shape, generator=torch.Generator().manual_seed(1))
    a = phi.adjoint(img)
    assert a.shape == (2, 4, 8, 10)
    for b in range(2):
        r = torch.from_numpy(transport.operator.adjoint(img[b].numpy())).permute(2, 0, 1)
        assert float((a[b] - r).abs().max()) <= 1e-6 * float(r.abs().max())


def test_adjoint_identity_and_bit_identical_runs(phi, csr):
    g = torch.Generator().manual_seed(2)
    x = torch.rand(2, 4, 8, 10, generator=g)
    y = torch.rand(2, *phi.image_shape, generator=g)
    lhs = float((phi(x).double() * y.double()).sum())
    rhs = float((x.double() * phi.adjoint(y).double()).sum())
    assert abs(lhs - rhs) <= 1e-6 * abs(lhs)
    assert torch.equal(phi(x), phi(x)) and torch.equal(phi.adjoint(y), phi.adjoint(y))
    # Built and applied under torch's deterministic-algorithms mode (no op it refuses; the GPU check does the same
    # on CUDA, where the refused set is larger), with the same bits.
    ip, ix, dv, shape = csr
    torch.use_deterministic_algorithms(True)
    try:
        a, at = _gather.pair_from_csr(torch.from_numpy(ip), torch.from_numpy(ix), torch.from_numpy(dv), shape,
                                      torch.device("cpu"), band_major=(80, 4))
        assert torch.equal(a.matmul(x.reshape(2, -1)), phi(x).reshape(2, -1))
        assert torch.equal(at.matmul(y.reshape(2, -1)), phi.adjoint(y).reshape(2, -1))
    finally:
        torch.use_deterministic_algorithms(False)
    # Batched and unbatched layouts agree (the same rows reduced; float32 rounding at most).
    assert phi(x).shape == (2, *phi.image_shape) and phi(x[1]).shape == phi.image_shape
    assert torch.allclose(phi(x)[1], phi(x[1]), rtol=1e-6, atol=0)
    assert torch.allclose(phi.adjoint(y)[0], phi.adjoint(y[0]), rtol=1e-6, atol=0)


def test_backward_is_the_adjoint_and_gradcheck(phi):
    x = torch.rand(2, 4, 8, 10, requires_grad=True)
    gy = torch.rand(2, *phi.image_shape)
    (phi(x) * gy).sum().backward()
    assert torch.equal(x.grad, phi.adjoint(gy))
    y = torch.rand(2, *phi.image_shape, requires_grad=True)
    gx = torch.rand(2, 4, 8, 10)
    (phi.adjoint(y) * gx).sum().backward()
    assert torch.equal(y.grad, phi(gx))
    # float64 inputs are computed in float64 (the float32 table values exactly): gradcheck at its default
    # tolerances, in fast mode (random projections of the Jacobian: 1804 rows would take ~40 s one by one).
    xs = torch.rand(1, 4, 8, 10, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: phi(t), (xs,), fast_mode=True)
    ys = torch.rand(1, *phi.image_shape, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: phi.adjoint(t), (ys,), fast_mode=True)
    assert torch.autograd.gradgradcheck(lambda t: phi.adjoint(t), (ys,), fast_mode=True)


def test_table_layout_padding_and_dtype_safety(phi):
    for t in (phi.phi_table, phi.adjoint_table):
        assert 1.0 <= t.padding < 1.25 and t.nnz == phi.nnz
        assert all(b.dtype in (torch.int32, torch.int64) for b in t.buffers())  # values kept as float32 bits
    # The ladder: exact up to 8, then < 1.25·c, 4 widths per octave.
    c = torch.arange(1, 5000)
    w = _gather.ladder_widths(c)
    assert torch.equal(w[:8], c[:8]) and bool((w >= c).all()) and bool((w < 1.25 * c).all())
    assert len(torch.unique(w[(c > 512) & (c <= 1024)])) == 4
    x = torch.rand(1, 4, 8, 10)
    y = phi(x)
    # .to(dtype) does not round the table; a float64 module still computes float32 inputs as before.
    phi64 = dt.CassiOperator.from_operator(diffcassi.Transport(diffcassi.System.preset("sp"), 8, 10, **SMALL)).to(torch.float16)
    assert torch.equal(phi64(x), y)


def test_device_arguments_and_round_trips(transport, phi):
    x = torch.rand(2, 4, 8, 10)
    y = phi(x)
    for m in (phi.to("cpu"), phi.cpu(), phi.to(torch.device("cpu")),
              dt.CassiOperator.from_operator(transport, device="cpu"),
              dt.CassiOperator.from_operator(transport, device=torch.device("cpu"))):
        assert m.device == torch.device("cpu") and torch.equal(m(x), y)
    mf = dt.CassiOperator.from_operator(transport, matrix_free=True, device="cpu")
    assert mf.device == torch.device("cpu") and mf.phi_table is None and mf.to("cpu") is mf
    for bad, msg in (("meta", "device 'meta': the operator runs on 'cpu' or 'cuda'"),
                     ("npu", "device"), (3.5, "device: expected 'cpu', 'cuda' or 'cuda:N', got float 3.5")):
        with pytest.raises(diffcassi.DiffcassiValueError, match=msg):
            dt.CassiOperator.from_operator(transport, device=bad)
        with pytest.raises(diffcassi.DiffcassiValueError, match=msg):
            dt.CassiOperator.from_operator(transport, matrix_free=True, device=bad)
    for m in (phi, mf):
        with pytest.raises(diffcassi.DiffcassiValueError, match=r"\.to: device 'meta'"):
            m.to("meta")
        assert m.device == torch.device("cpu") and torch.equal(m(x), y if m is phi else mf(x))  # unchanged
    with pytest.raises(ValueError, match="x is on meta but the operator on cpu"):
        phi(torch.empty(1, 4, 8, 10, device="meta"))
    with pytest.raises(ValueError, match="x is on meta: the matrix-free operator is on the CPU"):
        mf(torch.empty(1, 4, 8, 10, device="meta"))


@pytest.mark.skipif(not NO_CUDA, reason="a CUDA device is present")
def test_cuda_without_cuda_is_one_clear_error(transport, phi):
    msg = r"device 'cuda(:0)?': no CUDA device is available to torch \(torch .*torch.cuda.is_available\(\) is False\); use device='cpu'"
    mf = dt.CassiOperator.from_operator(transport, matrix_free=True)
    for call in (lambda: phi.to("cuda"), lambda: phi.cuda(), lambda: mf.to("cuda"), lambda: mf.cuda(0),
                 lambda: dt.CassiOperator.from_operator(transport, device="cuda"),
                 lambda: dt.CassiOperator.from_operator(transport, matrix_free=True, device="cuda"),
                 lambda: dt.UnrolledGAP(mf, stages=1, width=2).to("cuda")):
        with pytest.raises(diffcassi.DiffcassiValueError, match=msg):
            call()


def test_matrix_free_device_table_on_the_cpu(transport, phi):
    # The table a CUDA move builds, built here on the CPU: the CUDA path's code, equal to the CSR form's tables.
    mf = dt.CassiOperator.from_operator(transport, matrix_free=True)
    x = torch.rand(2, 4, 8, 10)
    y = torch.rand(2, *phi.image_shape)
    rust_y, rust_x = mf(x), mf.adjoint(y)
    mf._build_table(torch.device("cpu"))
    assert mf.phi_table is not None and "table on cpu" in repr(mf)
    assert torch.equal(mf(x), phi(x)) and torch.equal(mf.adjoint(y), phi.adjoint(y))
    assert float((mf(x) - rust_y).abs().max()) <= 1e-6 * float(rust_y.abs().max())
    assert float((mf.adjoint(y) - rust_x).abs().max()) <= 1e-6 * float(rust_x.abs().max())
    xg = x.clone().requires_grad_(True)
    (mf(xg) * y).sum().backward()
    assert torch.equal(xg.grad, mf.adjoint(y))
    assert mf(x.double()).dtype == torch.float64 and mf(x.half()).dtype == torch.float16
    mf.to("cpu")  # moving to the CPU drops the table: the Rust operator again
    assert mf.phi_table is None and torch.equal(mf(x), rust_y)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"memory_gb = 1e-06 .*matrix_free=True, memory_gb="):
        dt.MatrixFreeCassiOperator(transport, memory_gb=1e-6)._build_table(torch.device("cpu"))
    with pytest.raises(diffcassi.DiffcassiValueError, match="memory_gb"):
        dt.MatrixFreeCassiOperator(transport, memory_gb=-1)


def test_renderer_table_path_equals_the_rust_render():
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), 8, 8, free=["prism_tilt_x"], rays=4, planes=8, seed=3,
                         bands_nm=[480.0, 520.0, 560.0, 600.0])
    cube = torch.rand(2, 4, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    g = torch.rand(2, *r.image_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    grads = []
    for table in (False, True):
        r.table_on_cpu = table
        r.zero_grad()
        c = cube.clone().requires_grad_(True)
        y = r(c)
        (y * g).sum().backward()
        grads.append((y.detach(), c.grad, r.mask_logits.grad.clone(), r.theta.grad.clone()))
    (y0, gc0, gm0, gt0), (y1, gc1, gm1, gt1) = grads
    # The table holds float32 entries of non-negative weights (mask open, cube ≥ 0): each rounded once in the
    # library's export and once in the footprint it is made of (≤ 2u relative each), so every acquisition pixel
    # is within 4u of the float64 render, relative to itself (measured 2.6e-8 of the peak).
    assert bool(((y1 - y0).abs() <= 4 * U * y0.abs()).all())
    assert float((gc1 - gc0).abs().max()) <= 4 * U * float(gc0.abs().max())
    assert float((gm1 - gm0).abs().max()) <= 4 * U * float(gm0.abs().max())
    assert torch.equal(gt1, gt0)  # θ's gradient: the same Rust VJP
    # float32 cubes: computed in float32 (≤ 1e-6 of the peak; measured 1.0e-7).
    y32 = r(cube.float()).detach()
    assert y32.dtype == torch.float32 and float((y32.double() - y0).abs().max()) <= 1e-6 * float(y0.abs().max())
    # A new θ: a new table (cached per θ), still the Rust render's acquisition.
    with torch.no_grad():
        r.theta += 0.5
    before = r._tables[0]
    r.table_on_cpu = True
    y_t = r(cube)
    assert r._tables[0] != before
    r.table_on_cpu = False
    y_r = r(cube)
    assert bool(((y_t - y_r).abs() <= 4 * U * y_r.abs()).all())
    with pytest.raises(diffcassi.DiffcassiValueError, match="device 'meta'"):
        r.to("meta")


def test_unrolled_follows_the_operator_device_and_dtype(transport, phi):
    mf = dt.CassiOperator.from_operator(transport, matrix_free=True)
    y = phi(torch.rand(2, 4, 8, 10))
    for op in (phi, mf):
        net = dt.UnrolledGAP(op, stages=2, width=4)
        assert net.device == torch.device("cpu")
        assert all(t.device == torch.device("cpu") for t in list(net.parameters()) + list(net.buffers()))
        out32 = net(y).detach()
        net64 = net.to(torch.float64)
        out64 = net64(y).detach()
        assert out32.dtype == torch.float32 and out64.dtype == torch.float64
        assert all(p.dtype == torch.float64 for p in net64.parameters())
        assert float((out64 - out32.double()).abs().max()) <= 1e-5 * float(out32.abs().max())
        with pytest.raises(ValueError, match="y is on meta but the network on cpu"):
            net(torch.empty(1, *op.image_shape, device="meta"))
        with pytest.raises(diffcassi.DiffcassiValueError, match="device 'meta'"):
            net.to("meta")


def test_training_step_check_runs_on_the_cpu():
    out = _gpu_check.unrolled_step("cpu", size=8, bands=4, planes=4, rays=2, stages=1, width=2)
    assert out["device"] == "cpu" and np.isfinite(out["loss"]) and out["copies"] is None
    assert out["loss"] <= out["loss_first"] * 1.5  # one Adam step from a finite loss stays finite and sane


def test_memcpy_trace_parser(tmp_path):
    import json
    p = tmp_path / "t.json"
    p.write_text(json.dumps({"traceEvents": [
        {"name": "Memcpy HtoD (Pageable -> Device)", "cat": "gpu_memcpy", "args": {"bytes": 65536}},
        {"name": "Memcpy DtoD (Device -> Device)", "cat": "gpu_memcpy", "args": {"bytes": 9}},
        {"name": "Memcpy DtoH (Device -> Pageable)", "cat": "gpu_memcpy", "args": {}},
        {"name": "void at::native::index_kernel", "cat": "kernel"}]}))
    copies, kernels = _gpu_check._memcpys(str(p))
    assert copies == [("Memcpy HtoD (Pageable -> Device)", 65536), ("Memcpy DtoH (Device -> Pageable)", None)]
    assert kernels == 1


def test_gpu_check_script_runs_on_the_cpu():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "gpu" / "torch_check.py"), "--cpu", "--size", "16", "--bands", "4", "--planes", "4",
                        "--unrolled-size", "8", "--renderer-size", "8", "--inference-size", "8", "--inference-planes", "4",
                        "--inference-rays", "1", "--reps", "3", "--threads", "1"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "| check |" in p.stdout and "FAIL" not in p.stdout and "all checks passed" in p.stdout
    assert "UnrolledDAUHST inference sp 8²×28" in p.stdout
