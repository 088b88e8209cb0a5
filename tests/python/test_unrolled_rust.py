"""The Rust inference of the unrolled network (``reconstruct --solver unrolled``, src/recon/unrolled.rs and
src/recon/prior/unrolled.rs) against the PyTorch definition (``diffcassi.unrolled.UnrolledGAP``) in float64, on
the same exact operator: random-but-seeded weights of a tiny network (odd sizes, so the edge-replication padding
to multiples of 4 and the crop are exercised) and the committed SP/mSP weights at 16×16. Tolerance: max |Rust −
PyTorch| ≤ 1e-5 × the reference's peak (measured 2–4e-7: Rust runs in float32, PyTorch here in float64 with the same operator
table); the measured differences are printed (pytest -s)."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed (scripts/setup.sh installs it with torch)")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi import _native  # noqa: E402
from diffcassi.unrolled import UnrolledGAP, load_unrolled, mask_sha256, save_unrolled  # noqa: E402

from conftest import ROOT  # noqa: E402

TOLERANCE = 1e-5
BANDS4 = [480.0, 520.0, 560.0, 600.0]
BANDS28 = list(np.linspace(450.0, 650.0, 28))


def _smooth_cube(h, w, bands, seed):
    """A seeded cube (H, W, B) float32 in [0.05, 0.95]: smooth blobs with spectral variation."""
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    cube = np.zeros((h, w, bands))
    for _ in range(4):
        r0, c0, s = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(2, 6)
        spec = rng.uniform(0.1, 1.0, bands)
        cube += np.exp(-((r - r0) ** 2 + (c - c0) ** 2) / (2 * s * s))[..., None] * spec
    cube = 0.05 + 0.9 * cube / cube.max()
    return np.ascontiguousarray(cube, dtype=np.float32)


def _reference(net_path, op, y, system=None):
    """UnrolledGAP in float64 around the sparse (tabulated) form of ``op``, loaded from ``net_path``."""
    phi = dt.CassiOperator.from_operator(op)
    net = load_unrolled(net_path, phi, system=system).to(torch.float64)
    with torch.no_grad():
        out = net(torch.from_numpy(y.astype(np.float64)))
    return out.numpy().transpose(1, 2, 0)  # (bands, H, W) → (H, W, bands)


def _compare(rust, ref, label):
    peak = float(np.abs(ref).max())
    err = float(np.abs(rust.astype(np.float64) - ref).max())
    print(f"{label}: max |Rust − PyTorch float64| = {err:.3e}, peak {peak:.3e}, relative {err / peak:.2e}")
    assert rust.shape == ref.shape and np.isfinite(rust).all()
    assert err <= TOLERANCE * peak, (label, err, peak)


@pytest.mark.parametrize("size", [(14, 18), (16, 16)])
def test_rust_forward_equals_pytorch_on_random_weights(tmp_path, size):
    torch.set_num_threads(1)
    h, w = size
    t = diffcassi.Transport(diffcassi.System.preset("sp"), h, w, bands_nm=BANDS4, planes=8, rays=2, seed=5)
    op = diffcassi.exact(diffcassi.System.preset("sp"), h, w, bands_nm=BANDS4, planes=8, rays=2, seed=6)
    y = np.ascontiguousarray(t.apply(_smooth_cube(h, w, 4, 3)), dtype=np.float32)
    # Random-but-seeded weights with the v1 metadata (every layer non-zero, steps away from 1).
    torch.manual_seed(11)
    net = UnrolledGAP(dt.CassiOperator.from_operator(op, matrix_free=True), stages=3, width=4)
    with torch.no_grad():
        for p in net.denoisers.parameters():
            torch.nn.init.normal_(p, std=0.15)
        net.steps.copy_(torch.tensor([0.7, 1.3, 0.9]))
    path = tmp_path / "w.safetensors"
    save_unrolled(net, path, {"system": "sp", "bands_nm": BANDS4, "planes": 8, "rays": 2, "operator_seed": 6,
                              "acquisition_seed": 5, "mask_sha256": mask_sha256(t.mask), "height": h, "width_px": w})
    rust, record = _native._unrolled(op, y, str(path), "sp")
    record = json.loads(record)
    assert record["network"]["metadata"]["stages"] == 3 and len(record["residuals"]) == 3
    _compare(rust, _reference(path, op, y, system="sp"), f"random weights {h}×{w}×4, 3 stages, width 4")
    # Positively homogeneous, as the graph: N(a·y) = a·N(y).
    rust3, _ = _native._unrolled(op, np.ascontiguousarray(3 * y), str(path), "sp")
    assert np.allclose(rust3, 3 * rust, rtol=1e-4, atol=1e-5 * float(np.abs(rust).max()))
    # Weights for another system are refused.
    with pytest.raises(diffcassi.DiffcassiValueError, match="trained for system `sp`, not `msp`"):
        _native._unrolled(op, y, str(path), "msp")
    # A preset name stands for the preset's prescription: weights recorded for another prescription named "sp"
    # are refused (the library's check, naming both hashes).
    edited = tmp_path / "edited.safetensors"
    save_unrolled(net, edited, {"system": "sp", "system_sha256": "0" * 64, "bands_nm": BANDS4, "planes": 8, "rays": 2,
                                "mask_sha256": mask_sha256(t.mask)})
    with pytest.raises(diffcassi.DiffcassiFileError, match=r"prescription of SHA-256 000000000000…, and the acquisition's system `sp` is another"):
        _native._unrolled(op, y, str(edited), "sp")


@pytest.mark.parametrize("system", ["sp", "msp"])
def test_rust_forward_equals_pytorch_with_the_committed_weights(system):
    torch.set_num_threads(1)
    path = ROOT / "diffcassi" / "weights" / f"unrolled-gap-v1-{system}.safetensors"
    t = diffcassi.Transport(diffcassi.System.preset(system), 16, 16, bands_nm=BANDS28, planes=28, rays=1, seed=0)
    op = diffcassi.exact(diffcassi.System.preset(system), 16, 16, bands_nm=BANDS28, planes=28, rays=1, seed=1)
    y = np.ascontiguousarray(t.apply(_smooth_cube(16, 16, 28, 4)), dtype=np.float32)
    rust, record = _native._unrolled(op, y, None, system)  # the embedded copy of the committed file
    record = json.loads(record)
    import zlib
    assert record["network"]["weights_crc32"] == zlib.crc32(path.read_bytes())
    _compare(rust, _reference(path, op, y, system=system), f"committed {system} weights 16×16×28, 6 stages, width 16")


@pytest.mark.parametrize("size", [(14, 18), (16, 16)])
def test_rust_forward_equals_pytorch_for_v2_on_random_weights(tmp_path, size):
    """``unrolled-dauhst-v2`` (src/recon/prior/unrolled_v2.rs): estimators, spectral-attention U-Nets, the
    learned per-sample step and noise level, against ``UnrolledDAUHST`` in float64; the estimates (μ_k, σ_k)
    too."""
    from diffcassi.unrolled import UnrolledDAUHST, system_sha256
    torch.set_num_threads(1)
    h, w = size
    sp = diffcassi.System.preset("sp")
    t = diffcassi.Transport(sp, h, w, bands_nm=BANDS4, planes=8, rays=2, seed=5)
    op = diffcassi.exact(sp, h, w, bands_nm=BANDS4, planes=8, rays=2, seed=6)
    y = np.ascontiguousarray(t.apply(_smooth_cube(h, w, 4, 3)), dtype=np.float32)
    torch.manual_seed(12)
    net = UnrolledDAUHST(dt.CassiOperator.from_operator(op, matrix_free=True), stages=2, width=4)
    with torch.no_grad():
        for name, p in net.named_parameters():
            if name.endswith("temperature"):
                p.uniform_(0.5, 2.0)
            elif ".n1." in name or ".n2." in name:
                p.normal_(1.0 if name.endswith("weight") else 0.0, 0.1)
            else:
                torch.nn.init.normal_(p, std=0.1)
        # Keep the learned step and noise level in a plausible range (softplus of ~0.5 and ~-2).
        for est in net.estimators:
            est.mlp[2].weight.mul_(0.1)
            est.mlp[2].bias.copy_(torch.tensor([0.5, -2.0]))
    path = tmp_path / "v2.safetensors"
    save_unrolled(net, path, {"system": "sp", "bands_nm": BANDS4, "planes": 8, "rays": 2, "operator_seed": 6,
                              "acquisition_seed": 5, "mask_sha256": mask_sha256(t.mask), "height": h, "width_px": w,
                              "system_sha256": system_sha256(sp)})
    rust, record = _native._unrolled(op, y, str(path), "sp")
    record = json.loads(record)
    assert record["network"]["name"] == "unrolled-dauhst-v2" and record["network"]["metadata"]["stages"] == 2
    assert len(record["residuals"]) == 2 and len(record["estimates"]) == 2
    phi = dt.CassiOperator.from_operator(op)
    ref_net = load_unrolled(path, phi, system=sp, mask=t.mask).to(torch.float64)
    with torch.no_grad():
        ref, (mus, sigmas) = ref_net(torch.from_numpy(y.astype(np.float64)), return_estimates=True)
    ref = ref.numpy().transpose(1, 2, 0)
    est = np.array([[e["mu"], e["sigma"]] for e in record["estimates"]])
    print(f"v2 estimates Rust {est.tolist()} PyTorch {torch.stack([mus[:, 0], sigmas[:, 0]], 1).tolist()}")
    assert np.allclose(est, torch.stack([mus[:, 0], sigmas[:, 0]], 1).numpy(), rtol=1e-4, atol=1e-6)
    assert not np.allclose(est[:, 0], 1.0), "the learned steps are exercised (not GAP's 1)"
    _compare(rust, ref, f"v2 random weights {h}×{w}×4, 2 stages, width 4")
    # Positively homogeneous, as the graph: N(a·y) = a·N(y).
    rust3, _ = _native._unrolled(op, np.ascontiguousarray(3 * y), str(path), "sp")
    assert np.allclose(rust3, 3 * rust, rtol=1e-4, atol=1e-5 * float(np.abs(rust).max()))
