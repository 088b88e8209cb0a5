"""diffcassi.torch: the operator equals Rust, is differentiable (gradcheck), the dataset is deterministic."""
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="PyTorch not installed (DIFFCASSI_TORCH=skip)")
import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from conftest import SMALL, random_cube  # noqa: E402


@pytest.fixture(scope="module")
def transport():
    return diffcassi.Transport(diffcassi.System.preset("msp"), 8, 8, **SMALL)


def test_operator_equals_rust(transport, tmp_path):
    phi = dt.CassiOperator.from_operator(transport)
    x = random_cube(8, 8, 4, seed=7)
    xb = torch.from_numpy(np.stack([x, 0.5 * x])).permute(0, 3, 1, 2)  # (B, bands, H, W)
    y = phi(xb)
    ref = transport.operator.apply(x)
    assert y.shape == (2, *transport.detector_shape)
    assert float((y[0] - torch.from_numpy(ref)).abs().max()) <= 1e-5 * float(ref.max())
    yt = np.random.default_rng(1).random(transport.detector_shape, dtype=np.float32)
    adj = phi.adjoint(torch.from_numpy(yt))
    ref_adj = transport.operator.adjoint(yt).transpose(2, 0, 1)
    assert float((adj - torch.from_numpy(ref_adj)).abs().max()) <= 1e-5 * float(np.abs(ref_adj).max())
    transport.save_npz(tmp_path / "phi.npz")
    again = dt.CassiOperator.from_npz(tmp_path / "phi.npz", transport.operator.cube_shape, transport.detector_shape)
    assert torch.equal(again(xb), y)
    assert phi.double()(xb.double()).dtype == torch.float64


def test_gradcheck_float64():
    tiny = diffcassi.Transport(diffcassi.System.preset("sp"), 4, 4, bands_nm=[500.0, 540.0], planes=2, rays=2)
    phi = dt.CassiOperator.from_operator(tiny).double()
    x = torch.rand(1, 2, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(phi, (x,), eps=1e-6, atol=1e-6)
    y = torch.rand(1, *tiny.detector_shape, dtype=torch.float64, requires_grad=True)
    # The adjoint's input is the (larger) detector image: gradcheck's fast mode (random projections).
    assert torch.autograd.gradcheck(phi.adjoint, (y,), eps=1e-6, atol=1e-6, fast_mode=True)
    assert float(phi(x).abs().sum()) > 0


def _dataset():
    scenes = [diffcassi.synthetic_scene(20, 20, seed=s) for s in range(2)]
    return dt.CassiDataset(scenes, "sp", 12, length=4, seed=3, transport=dict(bands_nm=np.linspace(450, 650, 6), planes=6, rays=2))


@pytest.mark.parametrize("workers", [0, 2])
def test_dataset_is_deterministic_per_seed_index_epoch(workers):
    ds = _dataset()
    ref = [ds[i] for i in range(4)]
    acq, mask, truth, init = ref[0]
    assert acq.shape == ds.transport.detector_shape and mask.shape == (12, 12)
    assert truth.shape == (6, 12, 12) and init.shape == (6, 12, 12) and float(init.abs().sum()) > 0
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=workers)
    got = [item for batch in loader for item in zip(*batch)]
    for a, b in zip(ref, got):
        for u, v in zip(a, b):
            assert torch.equal(u, v)
    ds.set_epoch(1)
    assert not torch.equal(ds[0][2], ref[0][2]) or not torch.equal(ds[1][2], ref[1][2])
    ds.set_epoch(0)
    assert torch.equal(ds[0][0], ref[0][0])
