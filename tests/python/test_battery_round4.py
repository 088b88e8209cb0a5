"""What a second held-out battery (30 Nov 2026) found in the Python API, each now refused with a message naming the
argument (docs/robustness.md, "round 4"): acquisitions and cubes beyond the f32 sums' range (a NaN cube from
`reconstruct`, inf from `Operator.apply`), an unrolled network on the CSR table fed a NaN acquisition (an all-NaN
cube), a weights file whose metadata claims a huge network (gigabytes allocated before the tensors were compared),
`save_npz` given a folder (it wrote `folder.npz` beside it), `CassiDataset` on a scene outside the transport's bands
(its truth was the end band repeated), a fresh v1 training run into a folder holding another (replaced it), and
`RAYON_NUM_THREADS=100000` (hung at the first heavy call). Tiny sizes only."""
import os
import subprocess
import sys

import numpy as np
import pytest

import diffcassi
from conftest import ROOT, load_script

BANDS4 = [480.0, 520.0, 560.0, 600.0]


@pytest.fixture(scope="module")
def op():
    return diffcassi.exact(diffcassi.System.preset("sp"), 8, 8, bands_nm=BANDS4, planes=4, rays=1)


def test_values_beyond_the_f32_sums_are_refused(op):
    y = np.full(op.image_shape, 1e36, np.float32)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"acquisition: value 1e36 at index \[0, 0\] is beyond"):
        diffcassi.reconstruct(op, y, iterations=2)
    with pytest.raises(diffcassi.DiffcassiValueError, match="cube: value 3e38"):
        op.apply(np.full(op.cube_shape, 3e38, np.float32))
    with pytest.raises(diffcassi.DiffcassiValueError, match="image: value"):
        op.adjoint(np.full(op.image_shape, 3e38, np.float32))
    # At the limit's scale, finite.
    cube, _ = diffcassi.reconstruct(op, np.full(op.image_shape, 1e6, np.float32), iterations=2)
    assert np.isfinite(cube).all()


def test_save_npz_writes_the_path_given(op, tmp_path):
    folder = tmp_path / "npzdir"
    folder.mkdir()
    with pytest.raises(diffcassi.DiffcassiValueError, match="must end in .npz"):
        op.save_npz(folder)
    with pytest.raises(diffcassi.DiffcassiValueError, match="must end in .npz"):
        op.save_npz(tmp_path / "phi")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["npzdir"]
    op.save_npz(tmp_path / "phi.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["npzdir", "phi.npz"]
    with np.load(tmp_path / "phi.npz") as z:
        assert z["format"] == b"csr"


torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed")


def test_unrolled_networks_refuse_a_non_finite_acquisition(op):
    import diffcassi.torch as dt
    from diffcassi.unrolled import UnrolledDAUHST, UnrolledGAP
    phi = dt.CassiOperator.from_operator(op)  # the CSR table form
    y = torch.zeros(op.image_shape)
    y[1, 2] = float("nan")
    for cls in (UnrolledGAP, UnrolledDAUHST):
        net = cls(phi, stages=1, width=4)
        with pytest.raises(diffcassi.DiffcassiValueError, match=f"{cls.__name__}.forward: y holds NaN"):
            net(y)
        assert torch.isfinite(net(torch.zeros(op.image_shape))).all()


def test_weights_claiming_a_huge_network_are_refused_before_building_it(op, tmp_path):
    import time
    import diffcassi.torch as dt
    from safetensors.torch import load_file, save_file
    from diffcassi.unrolled import UnrolledGAP, load_unrolled, read_metadata, save_unrolled
    phi = dt.CassiOperator.from_operator(op, matrix_free=True)
    path = tmp_path / "w.safetensors"
    save_unrolled(UnrolledGAP(phi, stages=1, width=2), path, {"system": "sp"})
    meta, tensors = read_metadata(path), load_file(str(path))
    for key, value in (("stages", "20000"), ("width", "3000"), ("stages", "65")):
        bad = tmp_path / f"bad-{key}-{value}.safetensors"
        save_file(tensors, str(bad), metadata=dict(meta, **{key: value}))
        t = time.time()
        with pytest.raises(diffcassi.DiffcassiValueError, match="stages must be in 1..=64 and stages × width²"):
            load_unrolled(bad, phi)
        assert time.time() - t < 5.0
    load_unrolled(path, phi)  # the file as written still loads


def test_the_dataset_refuses_a_scene_outside_the_transport_bands():
    import diffcassi.torch as dt
    cube = np.full((16, 16, 4), 0.5, np.float32)
    ds = dt.CassiDataset([(cube, [1000.0, 1100.0, 1200.0, 1300.0])], "sp", 8, transport=dict(bands_nm=BANDS4, rays=1, planes=4))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"scene's bands \(1000 – 1300 nm\) lie outside the transport's"):
        ds[0]
    part = dt.CassiDataset([(cube, [480.0, 490.0, 500.0, 510.0])], "sp", 8, transport=dict(bands_nm=BANDS4, rays=1, planes=4))
    with pytest.warns(UserWarning, match="beyond the scene's"):
        part[0]


def test_a_fresh_v1_run_does_not_replace_another(tmp_path, capsys):
    train = load_script("train_unrolled")
    common = ["--system", "sp", "--size", "16", "--stages", "1", "--width", "2", "--planes", "4", "--rays", "1", "--bands", "4",
              "--threads", "1", "--warmup", "0", "--val-every", "1", "--steps", "1", "--batch", "1"]
    out = tmp_path / "tx"
    assert train.main(common + ["--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert train.main([c if c != "2" else "3" for c in common] + ["--out", str(out)]) == 2
    assert "already holds the checkpoint unrolled-sp-state.pt" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert train.main(common + ["--out", str(afile)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err and afile.read_text() == "x"


def test_a_huge_rayon_num_threads_is_refused_at_import():
    env = dict(os.environ, RAYON_NUM_THREADS="100000", PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", "import diffcassi"], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode != 0 and "RAYON_NUM_THREADS=100000: must be a whole number in 1..=1024" in r.stderr, r.stderr
