"""The matrix-free torch operator (`CassiOperator.from_operator(op, matrix_free=True)`): the Rust operator's
apply/adjoint on CPU tensors in place, equal to the CSR form, differentiable (gradcheck), batched, layout
(B, bands, H, W) ↔ (B, h, w), any float dtype, clear errors."""
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from conftest import SMALL  # noqa: E402


@pytest.fixture(scope="module")
def transport():
    return diffcassi.Transport(diffcassi.System.preset("msp"), 8, 10, **SMALL)


@pytest.fixture(scope="module")
def forms(transport):
    return dt.CassiOperator.from_operator(transport, matrix_free=True), dt.CassiOperator.from_operator(transport)


def test_is_a_module_with_the_csr_interface(forms, transport):
    mf, csr = forms
    assert isinstance(mf, dt.MatrixFreeCassiOperator) and isinstance(mf, torch.nn.Module)
    assert mf.cube_shape == csr.cube_shape == transport.operator.cube_shape == (8, 10, 4)
    assert mf.image_shape == csr.image_shape == transport.detector_shape
    assert "matrix-free" in repr(mf)


def test_equals_the_csr_form_and_rust(forms, transport):
    mf, csr = forms
    x = torch.rand(3, 4, 8, 10, generator=torch.Generator().manual_seed(0))
    # The CSR form evaluated in float64 (the exported matrix summed exactly) is the reference: the float32
    # CSR form's own rounding (torch.sparse.mm) reaches ~1e-6 of the peak on the adjoint, the Rust
    # operator's stays ≤ ~3e-7 (measured over 5 seeds).
    y_mf, y_csr = mf(x), csr(x.double())
    assert y_mf.shape == (3, *transport.detector_shape) and y_mf.dtype == torch.float32
    peak = float(y_csr.abs().max())
    assert float((y_mf.double() - y_csr).abs().max()) <= 1e-6 * peak
    # Each batch item is the Rust operator's apply of that cube ((H, W, bands) layout), bit for bit.
    for b in range(3):
        ref = transport.operator.apply(np.ascontiguousarray(x[b].permute(1, 2, 0).numpy()))
        assert np.array_equal(y_mf[b].numpy(), ref)
    img = torch.rand(2, *transport.detector_shape, generator=torch.Generator().manual_seed(1))
    a_mf, a_csr = mf.adjoint(img), csr.adjoint(img.double())
    assert a_mf.shape == (2, 4, 8, 10)
    assert float((a_mf.double() - a_csr).abs().max()) <= 1e-6 * float(a_csr.abs().max())
    assert np.array_equal(a_mf[1].permute(1, 2, 0).numpy(), transport.operator.adjoint(img[1].numpy()))
    # Unbatched layouts (bands, H, W) → (h, w) and back.
    assert torch.equal(mf(x[0]), y_mf[0]) and torch.equal(mf.adjoint(img[0]), a_mf[0])


def test_channels_last_input_and_adjoint_identity(forms):
    mf, _ = forms
    t = torch.rand(2, 8, 10, 4, generator=torch.Generator().manual_seed(2))  # (B, H, W, bands) contiguous
    x = t.permute(0, 3, 1, 2)  # the (B, bands, H, W) view: passed to Rust without a copy
    assert torch.equal(mf(x), mf(x.contiguous()))
    y = torch.rand(2, *mf.image_shape, generator=torch.Generator().manual_seed(3))
    lhs = float((mf(x).double() * y.double()).sum())
    rhs = float((x.double() * mf.adjoint(y).double()).sum())
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)


def test_backward_is_the_adjoint(forms):
    mf, csr = forms
    x = torch.rand(2, 4, 8, 10, requires_grad=True)
    g = torch.rand(2, *mf.image_shape)
    (mf(x) * g).sum().backward()
    assert float((x.grad - mf.adjoint(g)).abs().max()) == 0.0
    y = torch.rand(2, *mf.image_shape, requires_grad=True)
    gx = torch.rand(2, 4, 8, 10)
    (mf.adjoint(y) * gx).sum().backward()
    assert torch.equal(y.grad, mf(gx))


def test_gradcheck_float32_operator_through_a_float64_wrapper():
    # The Rust operator is float32: gradcheck runs on float64 inputs cast to float32 inside the module (the
    # float64 wrapper) with a float32-appropriate step: Φ is linear, so central differences with eps = 1e-2
    # are exact up to float32 rounding of the outputs (~1e-7 relative / 2·eps), hence atol 1e-4, rtol 1e-3.
    tiny = diffcassi.Transport(diffcassi.System.preset("sp"), 4, 4, bands_nm=[500.0, 540.0], planes=2, rays=2)
    mf = dt.CassiOperator.from_operator(tiny, matrix_free=True)
    x = torch.rand(2, 2, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(mf, (x,), eps=1e-2, atol=1e-4, rtol=1e-3)
    y = torch.rand(1, *tiny.detector_shape, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(mf.adjoint, (y,), eps=1e-2, atol=1e-4, rtol=1e-3, fast_mode=True)
    # Second derivatives exist (the backward is itself the Rust operator), zero for a linear map.
    assert torch.autograd.gradgradcheck(mf, (x,), eps=1e-2, atol=1e-4, rtol=1e-3, fast_mode=True)
    assert float(mf(x).detach().abs().sum()) > 0


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float64])
def test_other_float_dtypes_computed_in_float32(forms, dtype):
    mf, csr = forms
    x = torch.rand(1, 4, 8, 10, generator=torch.Generator().manual_seed(4))
    for op in (mf, csr):
        y = op(x.to(dtype))
        assert y.dtype == dtype
        ref = mf(x.to(dtype).to(torch.float32))
        tol = {torch.float16: 1e-3, torch.bfloat16: 1e-2, torch.float64: 1e-6}[dtype]
        assert float((y.float() - ref).abs().max()) <= tol * float(ref.abs().max())
        assert op.adjoint(y).dtype == dtype


def test_bad_inputs(forms):
    mf, _ = forms
    with pytest.raises(TypeError, match="x: expected a floating-point tensor.*torch.int64"):
        mf(torch.ones(1, 4, 8, 10, dtype=torch.int64))
    with pytest.raises(TypeError, match="x: expected a torch.Tensor, got ndarray"):
        mf(np.ones((1, 4, 8, 10), np.float32))
    with pytest.raises(ValueError, match=r"x: expected shape \(batch, 4, 8, 10\).*got \(1, 3, 8, 10\)"):
        mf(torch.ones(1, 3, 8, 10))
    with pytest.raises(ValueError, match="y: expected shape"):
        mf.adjoint(torch.ones(1, 5, 5))
    # The index is the tensor's own (batch, band, row, col): the Rust check named the operator's (N, H, W, B) layout.
    with pytest.raises(ValueError, match=r"x: value nan at index \[0, 3, 1, 2\] is not finite"):
        x = torch.ones(1, 4, 8, 10)
        x[0, 3, 1, 2] = float("nan")
        mf(x)
    with pytest.raises(TypeError, match="matrix_free: expected True or False"):
        dt.CassiOperator.from_operator(mf.op, matrix_free="yes")
    with pytest.raises(TypeError, match="op: expected a diffcassi.Operator"):
        dt.CassiOperator.from_operator("sp", matrix_free=True)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_tensor_is_refused(forms):
    mf, _ = forms
    with pytest.raises(ValueError, match="runs the Rust operator on the CPU.*move the operator with .to"):
        mf(torch.ones(1, 4, 8, 10, device="cuda"))


def test_batch_entry_points_check_the_output(transport):
    op = transport.operator
    x = np.zeros((2, 8, 10, 4), np.float32)
    with pytest.raises(ValueError, match="out: expected shape"):
        op._apply_batch(x, np.zeros((1, *transport.detector_shape), np.float32))
    with pytest.raises(ValueError, match="out: expected a float32"):
        op._apply_batch(x, np.zeros((2, *transport.detector_shape), np.float64))
    ro = np.zeros((2, *transport.detector_shape), np.float32)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="out: cannot borrow the array for writing"):
        op._apply_batch(x, ro)
