"""The unrolled network (diffcassi/unrolled.py, diffcassi/weights/UNROLLED.md): shapes, the untrained graph is plain
GAP, gradients reach every stage, a few training steps lower the loss, the training script resumes exactly and
never reads the evaluation scenes, the committed weights load and give finite output, and bad weights files give
clear errors. Tiny sizes only (the suite stays fast)."""
import builtins
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed (scripts/setup.sh installs it with torch)")
pytest.importorskip("colour", reason="colour-science not installed (scripts/setup.sh installs it with torch)")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi import deadleaves  # noqa: E402
from diffcassi.unrolled import ARCH, UnrolledGAP, load_unrolled, mask_sha256, read_metadata, save_unrolled  # noqa: E402

from conftest import ROOT, load_script  # noqa: E402
WEIGHTS = ROOT / "diffcassi" / "weights"
BANDS4 = [480.0, 520.0, 560.0, 600.0]


@pytest.fixture(scope="module")
def train():
    return load_script("train_unrolled")


def _phi(system="sp", size=16, bands=BANDS4, seed=6):
    op = diffcassi.exact(diffcassi.System.preset(system), size, size, bands_nm=bands, planes=2 * len(bands), rays=2, seed=seed)
    return dt.CassiOperator.from_operator(op, matrix_free=True)


@pytest.fixture(scope="module")
def tiny():
    """(acquisition transport of seed 5, matrix-free operator of seed 6, acquisitions, cubes): SP, 16×16×4."""
    torch.set_num_threads(1)
    t = diffcassi.Transport(diffcassi.System.preset("sp"), 16, 16, bands_nm=BANDS4, planes=8, rays=2, seed=5)
    phi = _phi()
    cubes = np.stack([deadleaves.dead_leaves(s, 16, BANDS4) for s in (1, 2)])
    acq = np.stack([t.apply(np.ascontiguousarray(c.transpose(1, 2, 0))) for c in cubes]).astype(np.float32)
    return t, phi, torch.from_numpy(acq), torch.from_numpy(cubes)


def test_forward_shapes_and_untrained_graph_is_plain_gap(tiny):
    _, phi, acq, cubes = tiny
    net = UnrolledGAP(phi, stages=3, width=4)
    out = net(acq)
    assert out.shape == cubes.shape and out.dtype == torch.float32
    assert net(acq[0]).shape == cubes.shape[1:]
    # Untrained (the linear path and the tails start at zero): exactly three plain GAP steps from Φᵀ(y/d).
    d = phi(phi.adjoint(torch.ones(phi.image_shape)))
    dinv = torch.where(d > 1e-6 * d.max(), 1 / d, torch.zeros_like(d))
    x = phi.adjoint(acq * dinv)
    for _ in range(3):
        x = x + phi.adjoint((acq - phi(x)) * dinv)
    assert torch.allclose(out, x, rtol=1e-5, atol=1e-6 * float(x.abs().max()))
    # Positively homogeneous: N(a·y) = a·N(y) (the scale is taken from x₀).
    torch.manual_seed(0)
    for p in net.denoisers.parameters():
        torch.nn.init.normal_(p, std=0.1)
    with torch.no_grad():
        assert torch.allclose(net(3.0 * acq), 3.0 * net(acq), rtol=1e-4, atol=1e-5 * float(net(acq).abs().max()))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"expected shape \(batch, "):
        net(torch.zeros(2, 5, 5))
    with pytest.raises(TypeError, match="floating-point"):
        net(acq.to(torch.int32))
    with pytest.raises(diffcassi.DiffcassiValueError, match="stages: expected an integer ≥ 1"):
        UnrolledGAP(phi, stages=0)


def test_gradients_reach_every_stage(tiny):
    _, phi, acq, cubes = tiny
    net = UnrolledGAP(phi, stages=3, width=4)
    (net(acq) - cubes).abs().mean().backward()
    # At the start (zero tails) the tails, the linear paths and the steps of every stage get a gradient ...
    for k, den in enumerate(net.denoisers):
        for name in ("linear", "tail"):
            assert float(getattr(den, name).weight.grad.abs().max()) > 0, (k, name)
    assert (net.steps.grad.abs() > 0).all()
    # ... and once the tails are non-zero, every parameter of every stage does.
    torch.manual_seed(1)
    for den in net.denoisers:
        torch.nn.init.normal_(den.tail.weight, std=0.05)
    net.zero_grad()
    (net(acq) - cubes).abs().mean().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and float(p.grad.abs().max()) > 0, name


def test_three_training_steps_lower_the_loss(tiny):
    _, phi, acq, cubes = tiny
    torch.manual_seed(0)
    net = UnrolledGAP(phi, stages=2, width=4)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for _ in range(4):
        loss = (net(acq) - cubes).abs().mean()
        losses.append(float(loss.detach()))
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert losses[3] < losses[0], losses


def test_weights_round_trip_and_bad_files(tiny, tmp_path):
    t, phi, acq, _ = tiny
    torch.manual_seed(2)
    net = UnrolledGAP(phi, stages=2, width=4)
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.05)
    path = tmp_path / "w.safetensors"
    save_unrolled(net, path, {"system": "sp", "mask_sha256": mask_sha256(t.mask), "planes": 8})
    meta = read_metadata(path)
    assert meta["arch"] == ARCH and meta["system"] == "sp" and meta["stages"] == "2" and meta["planes"] == "8"
    back = load_unrolled(path, phi, system="sp", mask=t.mask)
    assert not back.training and torch.equal(back(acq), net.eval()(acq))
    # A missing file, another system, another band count, another mask.
    with pytest.raises(diffcassi.DiffcassiFileError, match="no such file"):
        load_unrolled(tmp_path / "none.safetensors", phi)
    with pytest.raises(diffcassi.DiffcassiValueError, match="trained for system 'sp', not 'msp'"):
        load_unrolled(path, phi, system="msp")
    with pytest.raises(diffcassi.DiffcassiValueError, match="the network is for 4 bands, the operator has 3"):
        load_unrolled(path, _phi(bands=BANDS4[:3]))
    with pytest.raises(diffcassi.DiffcassiValueError, match="another mask"):
        load_unrolled(path, phi, mask=1 - t.mask)
    # Not safetensors; another architecture; a tensor missing; NaN; a wrong shape.
    (tmp_path / "junk.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json}")
    with pytest.raises(diffcassi.DiffcassiValueError, match="not a valid safetensors file"):
        load_unrolled(tmp_path / "junk.safetensors", phi)
    from safetensors.torch import load_file, save_file
    tensors = load_file(path)
    save_file(tensors, tmp_path / "arch.safetensors", metadata=dict(meta, arch="spectral-unet-v1"))
    with pytest.raises(diffcassi.DiffcassiValueError, match="metadata arch is 'spectral-unet-v1'"):
        load_unrolled(tmp_path / "arch.safetensors", phi)
    save_file({k: v for k, v in tensors.items() if k != "steps"}, tmp_path / "miss.safetensors", metadata=meta)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"missing tensors \['steps'\]"):
        load_unrolled(tmp_path / "miss.safetensors", phi)
    bad = dict(tensors, steps=torch.tensor([1.0, float("nan")]))
    save_file(bad, tmp_path / "nan.safetensors", metadata=meta)
    with pytest.raises(diffcassi.DiffcassiValueError, match="tensor steps has NaN"):
        load_unrolled(tmp_path / "nan.safetensors", phi)
    save_file(dict(tensors, steps=torch.ones(3)), tmp_path / "shape.safetensors", metadata=meta)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"tensor steps has shape \(3,\), expected \(2,\)"):
        load_unrolled(tmp_path / "shape.safetensors", phi)
    # Non-finite weights are refused and nothing is written.
    with torch.no_grad():
        net.steps[0] = float("inf")
    with pytest.raises(diffcassi.DiffcassiValueError, match="non-finite"):
        save_unrolled(net, tmp_path / "inf.safetensors", {"system": "sp"})
    assert not (tmp_path / "inf.safetensors").exists() and sorted(p.name for p in tmp_path.glob("*.tmp*")) == []


@pytest.mark.parametrize("system", ["sp", "msp"])
def test_committed_weights_load_and_give_finite_output(system):
    path = WEIGHTS / f"unrolled-gap-v1-{system}.safetensors"
    meta = read_metadata(path)
    assert path.stat().st_size <= 5_000_000
    assert meta["system"] == system and int(meta["bands"]) == 28 and int(meta["height"]) == 128
    assert int(meta["planes"]) == 112 and int(meta["rays"]) == 20 and meta["acquisition_seed"] != meta["operator_seed"]
    # The network is convolutional: a small operator of the same system and bands is enough to run it.
    phi = _phi(system, size=16, bands=list(deadleaves.BANDS_NM), seed=1)
    net = load_unrolled(path, phi, system=system)
    cube = deadleaves.dead_leaves(3, 16)
    t = diffcassi.Transport(diffcassi.System.preset(system), 16, 16, planes=56, rays=2, seed=0)
    y = torch.from_numpy(t.apply(np.ascontiguousarray(cube.transpose(1, 2, 0))).astype(np.float32))
    out = net(y)
    assert out.shape == (28, 16, 16) and torch.isfinite(out).all()
    other = {"sp": "msp", "msp": "sp"}[system]
    with pytest.raises(diffcassi.DiffcassiValueError, match=f"trained for system '{system}', not '{other}'"):
        load_unrolled(path, phi, system=other)
    with pytest.raises(diffcassi.DiffcassiValueError, match="the network is for 28 bands, the operator has 4"):
        load_unrolled(path, _phi(system), system=system)


def test_training_data_never_touches_the_evaluation_scenes(train, monkeypatch):
    # By name: the committed manifests list no image file and no evaluation scene.
    scenes = {p.stem for p in (ROOT / "data/scenes").glob("*.png")}
    assert scenes, "the evaluation scenes are data/scenes/*.png"
    for system in ("sp", "msp"):
        man = json.loads((WEIGHTS / f"unrolled-{system}-manifest.json").read_text())
        assert man["image_files"] == [] and man["evaluation_scenes_used"] == []
        assert not any(s in json.dumps(man).lower() for s in scenes)
        assert man["config"]["acquisition_seed"] != man["config"]["operator_seed"]
    # By construction: train seeds and validation seeds are disjoint, half of each kind ...
    seen = {s for step in list(range(300)) + [10**6] for s in train.train_seeds(step, 2)}
    assert min(seen) >= train.TRAIN_SEED_BASE > max(train.val_seeds())
    kinds = [train.seed_kind(s) for s in train.train_seeds(7, 4)]
    assert kinds.count("rgb") == kinds.count("spectral") == 2
    # ... and making a training batch opens no file: every file reader fails, the batch is still made.
    deadleaves.dead_leaves(0, 8), deadleaves.dead_leaves(0, 8, kind="rgb")  # the spectral tables, once
    t = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, planes=28, rays=1, seed=1000)

    def refuse(*args, **kwargs):
        raise AssertionError(f"a file was read while making training data: {args[:1]}")
    for mod, name in ((builtins, "open"), (np, "load"), (diffcassi, "load_scene"), (diffcassi, "read_exr")):
        monkeypatch.setattr(mod, name, refuse)
    acq, cube = train.render_batch(t, train.train_seeds(0, 2), 8)
    assert acq.shape[0] == cube.shape[0] == 2 and torch.isfinite(acq).all()


def test_tiny_training_run_resumes_exactly(train, tmp_path, capsys):
    common = ["--system", "sp", "--size", "16", "--stages", "2", "--width", "4", "--planes", "28", "--rays", "1",
              "--threads", "1", "--warmup", "1", "--val-every", "2", "--steps", "4", "--batch", "2"]
    a, b = tmp_path / "a", tmp_path / "b"
    assert train.main(common + ["--out", str(a)]) == 0
    log = [json.loads(line) for line in (a / "unrolled-sp-log.jsonl").read_text().splitlines()]
    vals = [r for r in log if "val_psnr_db" in r]
    assert [r["step"] for r in vals] == [0, 2, 4] and all(np.isfinite(r["train_l1"]) for r in vals[1:])
    phi = _phi(size=16, bands=list(deadleaves.BANDS_NM), seed=1)
    net = load_unrolled(a / "unrolled-gap-v1-sp.safetensors", phi, system="sp")
    meta = read_metadata(a / "unrolled-gap-v1-sp.safetensors")
    assert meta["training_step"] == "4" and meta["stages"] == "2" and meta["height"] == "16"
    assert all(torch.isfinite(p).all() for p in net.parameters())
    capsys.readouterr()
    assert train.main(["--system", "sp", "--out", str(a), "--summary", "2"]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("| step |") and [t.split("|")[1].strip() for t in table[2:]] == ["0", "2", "4"]
    # Two steps, then a resume for the rest: the same weights as four steps at once, bit for bit.
    assert train.main(common + ["--out", str(b), "--stop-at", "2"]) == 0
    assert train.main(common + ["--out", str(b), "--resume", str(b / "unrolled-sp-state.pt")]) == 0
    sa, sb = torch.load(a / "unrolled-sp-state.pt"), torch.load(b / "unrolled-sp-state.pt")
    assert sa["step"] == sb["step"] == 4
    for k in sa["model"]:
        assert torch.equal(sa["model"][k], sb["model"][k]), k
    # A resume with other settings, or of a missing state, is refused.
    assert train.main([c if c != "4" else "6" for c in common] + ["--out", str(b), "--resume", str(b / "unrolled-sp-state.pt")]) == 2
    assert train.main(common + ["--out", str(b), "--resume", str(b / "none.pt")]) == 1
    with pytest.raises(SystemExit):
        train.main(common[:-2] + ["--out", str(b), "--acquisition-seed", "1", "--operator-seed", "1"])
