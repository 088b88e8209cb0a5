"""A held-out battery, round 16: the torch module (frozen masks, in-place cubes, half-precision unrolled networks,
'meta' tensors, a raising backward, the overflow messages, empty inputs)."""
import copy
import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402


def renderer(**kw):
    return dt.CassiRenderer(diffcassi.System.preset("msp"), 4, 4, free=["prism_tilt_x"], rays=2, planes=2,
                            bands_nm=[500, 540], **kw)


@pytest.fixture(scope="module")
def transport():
    return diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, rays=2, planes=4, bands_nm=[500, 520, 540, 560])


# ---- 1. a frozen mask renders (no mask gradient), fresh, frozen with the module, under no_grad, after copies
def test_frozen_mask_renders_and_gets_no_gradient():
    r = renderer()
    r.mask_logits.requires_grad_(False)
    y = r(torch.rand(1, 2, 4, 4, dtype=torch.float64))  # raised "cannot register a hook on a tensor …"
    y.sum().backward()
    assert r.mask_logits.grad is None and r.theta.grad is not None and bool(torch.isfinite(r.theta.grad).all())
    # Unfrozen again: the mask gets its gradient (and its range-checking hook).
    r.mask_logits.requires_grad_(True)
    r(torch.rand(1, 2, 4, 4, dtype=torch.float64)).sum().backward()
    assert r.mask_logits.grad is not None


def test_frozen_module_no_grad_and_copies_render():
    x = torch.rand(1, 2, 4, 4, dtype=torch.float64)
    r = renderer()
    r.requires_grad_(False)
    ref = r(x)
    with torch.no_grad():
        r2 = renderer()
        r2.mask_logits.requires_grad_(False)
        assert torch.equal(r2(x), ref)
    r3 = renderer()
    r3(x)  # the hook is registered on the first forward, the mask frozen after it
    r3.mask_logits.requires_grad_(False)
    for c in (copy.deepcopy(r3), pickle.loads(pickle.dumps(r3))):
        assert torch.equal(c(x), ref)


# ---- 2. a cube modified in place between forward and backward: torch's error, not 3× the gradients
def test_inplace_modified_cube_is_refused_in_backward():
    r = renderer()
    x = torch.rand(1, 2, 4, 4, dtype=torch.float64)
    y = r(x)
    with torch.no_grad():
        x.mul_(3.0)
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        y.sum().backward()
    assert r.theta.grad is None and r.mask_logits.grad is None
    # Unmodified, the gradients are those of a fresh render of the same cube.
    x2 = x.clone()
    r(x2).sum().backward()
    g1 = r.theta.grad.clone()
    r.zero_grad()
    r(x.clone()).sum().backward()
    assert torch.equal(r.theta.grad, g1)


# ---- 3. half-precision unrolled networks work as bfloat16 does (D⁻¹ kept in float32)
@pytest.mark.parametrize("cls,kw", [(dt.UnrolledGAP, dict(stages=1, width=4)), (dt.UnrolledDAUHST, dict(stages=1, width=8))])
def test_unrolled_half_runs(transport, cls, kw):
    torch.manual_seed(0)
    op = dt.CassiOperator.from_operator(transport, matrix_free=True)
    net = cls(op, **kw)
    y = torch.rand(1, *op.image_shape)
    ref = net(y).detach()
    for dtype in (torch.float16, torch.bfloat16):
        h = copy.deepcopy(net).to(dtype)
        assert h.dinv.dtype == torch.float32 and float(h.dinv.max()) > 65504  # beyond float16's range
        out = h(y.to(dtype))  # every input was refused: "adjoint: y: value inf at index …"
        assert out.dtype == dtype and bool(torch.isfinite(out).all())
        rel = float((out.detach().float() - ref).norm() / ref.norm())
        assert rel < 0.05, (dtype, rel)
    assert copy.deepcopy(net).half().float().dinv.dtype == torch.float32
    assert copy.deepcopy(net).double().dinv.dtype == torch.float64


# ---- 4. 'meta': messages that advise nothing refused; to_empty(device="meta") refused
def test_meta_inputs_named_without_refused_advice(transport):
    for op in (dt.CassiOperator.from_operator(transport), dt.CassiOperator.from_operator(transport, matrix_free=True)):
        for f, shape in ((op, (1, 4, 8, 8)), (op.adjoint, (1, *op.image_shape))):
            with pytest.raises(diffcassi.DiffcassiValueError, match="a 'meta' tensor holds no values") as e:
                f(torch.zeros(shape, device="meta"))
            assert ".to('meta')" not in str(e.value) and ".to(device)" not in str(e.value), str(e.value)
    r = renderer()
    with pytest.raises(diffcassi.DiffcassiValueError, match="cube is on meta.*a 'meta' tensor holds no values") as e:
        r(torch.zeros(1, 2, 4, 4, device="meta"))
    assert ".to(device)" not in str(e.value), str(e.value)


def test_to_empty_meta_is_refused(transport):
    r = renderer()
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"CassiRenderer\.to_empty: device 'meta'"):
        r.to_empty(device="meta")
    assert r.theta.device.type == "cpu" and r.mask_logits.device.type == "cpu"
    assert r(torch.rand(1, 2, 4, 4, dtype=torch.float64)).shape[0] == 1  # still usable
    mf = dt.CassiOperator.from_operator(transport, matrix_free=True)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"MatrixFreeCassiOperator\.to_empty: device 'meta'"):
        mf.to_empty(device="meta")


# ---- 5. a raising backward leaves every .grad as it was
def test_raising_backward_writes_no_gradient():
    r = renderer()
    x = torch.rand(1, 2, 4, 4, dtype=torch.float64, requires_grad=True)
    y = r(x)
    with pytest.raises(diffcassi.DiffcassiValueError, match="mask_logits") as e:
        y.backward(torch.full_like(y, 1e300))
    assert "scale the loss" in str(e.value)  # the upstream gradient is the cause, not the cube
    assert r.theta.grad is None and x.grad is None and r.mask_logits.grad is None


# ---- 6. overflow messages name the actual cause
def test_overflow_messages_name_the_cause():
    r = renderer()
    x = torch.full((1, 2, 4, 4), 1e29, dtype=torch.float32, requires_grad=True)
    y = r(x)
    with pytest.raises(diffcassi.DiffcassiValueError, match="float32's range") as e:
        y.backward(torch.full_like(y, 1e10))
    msg = str(e.value)
    assert "pass a float32" not in msg and "float64 cube" in msg and "scale the cube down" in msg, msg
    assert "the cube at 1e+29" in msg
    assert r.theta.grad is None and x.grad is None
    # The upstream gradient the larger factor: the loss is named.
    r2 = renderer()
    x2 = torch.full((1, 2, 4, 4), 1.0, dtype=torch.float32, requires_grad=True)
    y2 = r2(x2)
    with pytest.raises(diffcassi.DiffcassiValueError, match="mask gradient") as e:
        y2.backward(torch.full_like(y2, 3.4e38))
    assert "scale the loss (the upstream gradient) down" in str(e.value) and "scale the cube" not in str(e.value)


# ---- 7. empty inputs say what is wrong
def test_empty_inputs_named():
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"batch is empty \(N = 0"):
        renderer()(torch.zeros(0, 2, 4, 4))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"height, width and bands must each be ≥ 1"):
        diffcassi.denoise(np.zeros((0, 16, 28), np.float32), 0.1)
