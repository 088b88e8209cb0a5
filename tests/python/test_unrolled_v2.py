"""Issue 43 items 1–3 on the CPU at tiny sizes: the v2 training data (diffcassi/training_data.py), the network
``unrolled-dauhst-v2`` (diffcassi/unrolled.py) and the short resumable runs of scripts/train_unrolled.py
(diffcassi/weights/UNROLLED.md). Seconds each; no training beyond a few steps at 8×8×3 bands."""
import builtins
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed (scripts/setup.sh installs it with torch)")
pytest.importorskip("colour", reason="colour-science not installed (scripts/setup.sh installs it with torch)")
pytest.importorskip("skimage", reason="scikit-image not installed (scripts/setup.sh installs it with torch)")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi import training_data as td  # noqa: E402
from diffcassi.unrolled import (ARCH, ARCH_V2, UnrolledDAUHST, UnrolledGAP, count_parameters, load_unrolled,  # noqa: E402
                                mask_sha256, read_metadata, save_unrolled, system_sha256)

from conftest import ROOT, load_script  # noqa: E402

WEIGHTS = ROOT / "diffcassi" / "weights"
BANDS3 = [450.0, 550.0, 650.0]  # = train_unrolled.py --bands 3
INIT = WEIGHTS / "unrolled-dauhst-v2-sp-init.pt"


@pytest.fixture(scope="module")
def train():
    return load_script("train_unrolled")


def _phi(system="sp", size=8, bands=BANDS3, seed=6):
    op = diffcassi.exact(diffcassi.System.preset(system), size, size, bands_nm=bands, planes=2 * len(bands), rays=1,
                         seed=seed)
    return dt.CassiOperator.from_operator(op, matrix_free=True)


def _gap(phi, y, k):
    d = phi(phi.adjoint(torch.ones(phi.image_shape)))
    dinv = torch.where(d > 1e-6 * d.max(), 1 / d, torch.zeros_like(d))
    x = phi.adjoint(y * dinv)
    for _ in range(k):
        x = x + phi.adjoint((y - phi(x)) * dinv)
    return x


# ------------------------------------------------------------------------------------------------- training data

def test_data_is_deterministic_per_seed_and_covers_every_kind():
    a, ia = td.sample(17, 8, BANDS3)
    b, ib = td.sample(17, 8, BANDS3)
    assert a.shape == (3, 8, 8) and a.dtype == np.float32 and np.array_equal(a, b) and ia == ib
    assert not np.array_equal(a, td.sample(18, 8, BANDS3)[0])
    assert abs(float(a.max()) - ia["exposure"]) < 1e-5 and 0.5 <= ia["exposure"] <= 1.0
    kinds = {td.sample(s, 8, BANDS3)[1]["kind"] for s in range(40)}
    assert kinds == set(td.KINDS)
    # The extended library holds the 99 CIE 2017 colour-fidelity samples beside deadleaves' sets.
    lib, sets = td.reflectance_library(BANDS3)
    assert sets.count("TCS CIE 2017") == 99 and lib.shape == (len(sets), 3) and 0 <= lib.min() and lib.max() <= 1
    # Sensor noise: drawn per sample (some clean, some noisy), deterministic per seed.
    draws = [td.draw_noise(s) for s in range(40)]
    assert any(d is None for d in draws) and any(d is not None for d in draws)
    noisy_seed = next(s for s, d in enumerate(draws) if d is not None)
    clean = np.random.default_rng(0).random((6, 9)) + 0.1
    n1, nz = td.noisy(clean, noisy_seed)
    assert nz == draws[noisy_seed] and np.array_equal(n1, td.noisy(clean, noisy_seed)[0]) and not np.allclose(n1, clean)
    with pytest.raises(td.TrainingDataError, match="seed: expected an integer ≥ 0, got int -1"):
        td.sample(-1, 8, BANDS3)
    with pytest.raises(td.TrainingDataError, match="size: expected an integer ≥ 4, got 2"):
        td.sample(1, 2, BANDS3)


def test_sensor_noise_is_the_library_model():
    sp = diffcassi.System.preset("sp")
    cube = np.ascontiguousarray(td.sample(3, 8, BANDS3)[0].transpose(1, 2, 0))
    kw = dict(bands_nm=BANDS3, planes=6, rays=2, seed=0)
    clean, _ = diffcassi.render(sp, cube, BANDS3, **kw)
    # The ADC step (exposure, gain, rounding, clamping, back to acquisition units): bit for bit the library's.
    adc, _ = diffcassi.render(sp, cube, BANDS3, noise={"noise": "adc", "full_well_e": 5000, "adc_bits": 6}, **kw)
    assert np.array_equal(td.sensor_noise(clean, None, 5000.0, 0.0, 6, shot=False), adc)
    # Shot and read noise: standardised residuals of a flat image have mean 0 and variance 1 (5 standard errors).
    flat = np.full((300, 300), 0.5)
    fw, read = 2000.0, 3.0
    out = td.sensor_noise(flat, np.random.default_rng(1), fw, read)
    k = fw / 0.5
    z = (out - flat) * k / np.sqrt(k * 0.5 + read ** 2)
    se = 1 / np.sqrt(z.size)
    assert abs(z.mean()) < 5 * se and abs(z.var() - 1) < 5 * np.sqrt(2) * se
    with pytest.raises(td.TrainingDataError, match="full_well_e: expected a finite number > 0, got 0.0"):
        td.sensor_noise(flat, None, 0.0)


def test_textures_only_from_the_allowed_list_and_never_the_evaluation_scenes(monkeypatch):
    scenes = {p.stem for p in (ROOT / "data/scenes").glob("*.png")}
    assert scenes == set(td.EVALUATION_SCENES), "the evaluation scenes are data/scenes/*.png"
    assert not scenes & set(td.TEXTURES) and sorted(td.TEXTURES) == sorted(
        ["brick", "grass", "gravel", "camera", "moon", "coins", "text", "page", "clock", "motorcycle_left",
         "motorcycle_right"])
    for name in td.EVALUATION_SCENES:
        with pytest.raises(td.TrainingDataError, match=f"texture '{name}' is an evaluation photograph"):
            td.texture_image(name)
    with pytest.raises(td.TrainingDataError, match="texture 'horse' is not one of the allowed images"):
        td.texture_image("horse")
    # Every file opened while cubes are made is an allowed image of the installed scikit-image's data folder.
    td.reflectance_library(BANDS3)  # colour-science's tables, once (cached)
    td.texture_image.cache_clear()
    opened = []
    real_open = builtins.open

    def spy(file, *args, **kwargs):
        opened.append(os.path.realpath(os.fspath(file)) if isinstance(file, (str, os.PathLike)) else repr(file))
        return real_open(file, *args, **kwargs)
    monkeypatch.setattr(builtins, "open", spy)
    for mod, name in ((np, "load"), (diffcassi, "load_scene"), (diffcassi, "read_exr")):
        monkeypatch.setattr(mod, name, lambda *a, **k: pytest.fail(f"a file was read while making training data: {a[:1]}"))
    textures = {td.sample(s, 8, BANDS3)[1].get("texture") for s in range(80)} - {None}
    monkeypatch.setattr(builtins, "open", real_open)
    data_dir = os.path.realpath(td.skimage_data_dir())
    allowed = {os.path.join(data_dir, f) for f in td.TEXTURES.values()}
    assert textures and textures <= set(td.TEXTURES) and opened
    assert set(opened) <= allowed, sorted(set(opened) - allowed)
    assert not any(str(ROOT / "data") in p for p in opened)
    # The manifest lists the sources and licences, and no evaluation scene.
    man = td.manifest(BANDS3)
    assert [t["name"] for t in man["textures"]] == list(td.TEXTURES) and all(t["source_licence"] for t in man["textures"])
    assert man["evaluation_scenes_used"] == [] and not any(f"{s}." in json.dumps(man["image_files"]) for s in scenes)
    assert {s["name"] for s in man["spectral_sets"]} >= {"TCS CIE 2017", "ColorChecker N Ohta", "VS NIST CQS 9.0"}


def test_a_missing_shipped_image_is_a_clear_error(monkeypatch, tmp_path):
    td.texture_image.cache_clear()
    monkeypatch.setattr(td, "skimage_data_dir", lambda: str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"texture 'brick': .*brick.png is missing from the installed scikit-image"):
        td.texture_image("brick")
    td.texture_image.cache_clear()


# ------------------------------------------------------------------------------------------------------ network

def test_v2_parameter_count_at_the_issue_config():
    phi = _phi(bands=[float(b) for b in np.linspace(450, 650, 28)], size=8)
    net = UnrolledDAUHST(phi)  # the defaults: 3 stages, width 24
    assert (net.stages, net.width) == (3, 24)
    assert 1_000_000 <= count_parameters(net) <= 2_000_000, count_parameters(net)
    assert 1_000_000 <= count_parameters(UnrolledDAUHST(phi, stages=2, width=32)) <= 2_000_000
    assert dt.UnrolledDAUHST is UnrolledDAUHST  # re-exported by diffcassi.torch


@pytest.mark.parametrize("size", [8, 10])
def test_v2_untrained_is_plain_gap_any_size_and_homogeneous(size):
    torch.set_num_threads(1)
    phi = _phi(size=size)
    net = UnrolledDAUHST(phi, stages=2, width=4)
    y = torch.rand(2, *phi.image_shape)
    out, (mu, sigma) = net(y, return_estimates=True)
    assert out.shape == (2, 3, size, size) and net(y[0]).shape == (3, size, size)
    assert mu.shape == sigma.shape == (2, 2) and torch.allclose(mu, torch.ones(2, 2))
    x = _gap(phi, y, 2)
    assert torch.allclose(out, x, rtol=1e-5, atol=1e-6 * float(x.abs().max()))
    torch.manual_seed(0)
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.1)
    with torch.no_grad():
        o = net(y)
        assert torch.isfinite(o).all() and not torch.allclose(o, x)
        assert torch.allclose(net(2.5 * y), 2.5 * o, rtol=1e-4, atol=1e-5 * float(o.abs().max()))
    (net(y) - x).abs().mean().backward()
    assert all(p.grad is not None and float(p.grad.abs().max()) > 0 for p in net.parameters())
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"expected shape \(batch, "):
        net(torch.zeros(2, 3, 3))
    with pytest.raises(TypeError, match="floating-point"):
        net(y.to(torch.int32))


def test_v2_weights_load_with_checks_and_refuse_another_system(tmp_path):
    t = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, bands_nm=BANDS3, planes=6, rays=1, seed=5)
    phi = _phi()
    torch.manual_seed(3)
    net = UnrolledDAUHST(phi, stages=2, width=4)
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.05)
    path = tmp_path / "w.safetensors"
    with pytest.raises(diffcassi.DiffcassiValueError, match="must record the training mask's mask_sha256"):
        save_unrolled(net, path, {"system": "sp"})
    assert not path.exists()
    sp = diffcassi.System.preset("sp")
    save_unrolled(net, path, {"system": "sp", "mask_sha256": mask_sha256(t.mask), "system_sha256": system_sha256(sp)})
    assert read_metadata(path)["arch"] == ARCH_V2
    y = torch.rand(1, *phi.image_shape)
    for system in ("sp", sp):
        back = load_unrolled(path, phi, system=system, mask=t.mask)
        assert isinstance(back, UnrolledDAUHST) and not back.training and torch.equal(back(y), net.eval()(y))
    # The operator names the system it was built from (round 15): taken when none is given; an operator that
    # names none (its table given as arrays) needs the system named.
    assert torch.equal(load_unrolled(path, phi, mask=t.mask)(y), net.eval()(y))
    op = phi.op
    table = dt.CassiOperator(*op.to_csr_arrays(4.0), op.cube_shape, op.image_shape)
    with pytest.raises(diffcassi.DiffcassiValueError, match="name the system of the acquisition"):
        load_unrolled(path, table)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"trained for system 'sp', not 'msp' \(refused\)"):
        load_unrolled(path, phi, system="msp")
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"trained for system 'sp', not 'msp' \(refused\)"):
        load_unrolled(path, phi, system=diffcassi.System.preset("msp"))
    with pytest.raises(diffcassi.DiffcassiValueError, match="the network is for 3 bands, the operator has 4"):
        load_unrolled(path, _phi(bands=[450.0, 500.0, 550.0, 650.0]), system="sp")
    with pytest.raises(diffcassi.DiffcassiValueError, match="another mask"):
        load_unrolled(path, phi, system="sp", mask=1 - t.mask)
    from safetensors.torch import load_file, save_file
    tensors, meta = load_file(path), read_metadata(path)
    save_file(dict(tensors, **{"priors.0.linear.weight": torch.full((3, 3, 1, 1), float("nan"))}),
              tmp_path / "nan.safetensors", metadata=meta)
    with pytest.raises(diffcassi.DiffcassiValueError, match="tensor priors.0.linear.weight has NaN"):
        load_unrolled(tmp_path / "nan.safetensors", phi, system="sp")
    # A preset name stands for the preset's prescription: weights recorded for an edited "sp" are refused under
    # system="sp"; a name that is no preset is checked by name only (the System itself carries its prescription).
    save_file(tensors, tmp_path / "edited.safetensors", metadata=dict(meta, system_sha256="0" * 64))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"another prescription of system 'sp' \(system SHA-256 0{64}, this one "
                       + system_sha256(sp)):
        load_unrolled(tmp_path / "edited.safetensors", phi, system="sp", mask=t.mask)
    save_file(tensors, tmp_path / "mine.safetensors", metadata=dict(meta, system="my_relay", system_sha256="0" * 64))
    assert isinstance(load_unrolled(tmp_path / "mine.safetensors", table, system="my_relay"), UnrolledDAUHST)
    # An operator that names its system refuses another name (round 15: it ran the network on sp's operator).
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"system='my_relay' is not the system the operator was built from \('sp'; refused\)"):
        load_unrolled(tmp_path / "mine.safetensors", phi, system="my_relay")
    save_file(tensors, tmp_path / "shape.safetensors", metadata=dict(meta, width="8"))
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"has shape .* expected .*width=8"):
        load_unrolled(tmp_path / "shape.safetensors", phi, system="sp")
    # v1 files still load, as UnrolledGAP.
    v1 = load_unrolled(WEIGHTS / "unrolled-gap-v1-sp.safetensors",
                       _phi(bands=[float(b) for b in np.linspace(450, 650, 28)]), system="sp")
    assert isinstance(v1, UnrolledGAP)


# --------------------------------------------------------------------------------------------------- training

COMMON = ["--arch", ARCH_V2, "--system", "sp", "--size", "8", "--bands", "3", "--stages", "2", "--width", "4",
          "--planes", "6", "--rays", "1", "--steps", "4", "--batch", "2", "--warmup", "1", "--val-every", "2"]
NM = {"w": f"{ARCH_V2}-sp.safetensors", "log": f"{ARCH_V2}-sp-log.jsonl", "man": f"{ARCH_V2}-sp-manifest.json",
      "ck": f"{ARCH_V2}-sp-checkpoint.pt"}


@pytest.fixture(scope="module")
def runs(train, tmp_path_factory):
    """A straight 4-step run (a) and 2 steps + a resume (b)."""
    root = tmp_path_factory.mktemp("v2runs")
    a, b = root / "a", root / "b"
    assert train.main(COMMON + ["--out", str(a)]) == 0
    assert train.main(COMMON + ["--out", str(b), "--stop-at", "2"]) == 0
    first = json.loads((b / NM["man"]).read_text())
    assert train.main(["--resume", str(b / NM["ck"]), "--out", str(b), "--val-every", "2"]) == 0
    return a, b, first


def test_tiny_v2_run_writes_weights_log_manifest(runs):
    a, _, _ = runs
    assert sorted(p.name for p in a.iterdir()) == sorted(NM.values())
    meta = read_metadata(a / NM["w"])
    assert meta["arch"] == ARCH_V2 and meta["training_step"] == "4" and meta["system"] == "sp"
    net = load_unrolled(a / NM["w"], _phi(seed=1), system="sp")
    assert isinstance(net, UnrolledDAUHST)
    log = [json.loads(line) for line in (a / NM["log"]).read_text().splitlines()]
    assert [r["step"] for r in log if "val_psnr_db" in r] == [0, 2, 4] and log[-1]["event"] == "stop"
    man = json.loads((a / NM["man"]).read_text())
    assert man["steps"] == 4 and [(r["steps_from"], r["steps_to"]) for r in man["runs"]] == [(0, 4)]
    assert man["config"]["acquisition_seed"] != man["config"]["operator_seed"] and man["evaluation_scenes_used"] == []
    assert man["runs"][0]["device"] == "cpu" and man["runs"][0]["start_utc"] <= man["runs"][0]["end_utc"]


def test_trained_v2_weights_run_in_rust_as_in_pytorch(runs):
    """What the training writes is what `reconstruct --solver unrolled` reads: the Rust inference accepts the
    file's metadata (system and prescription, bands, mask) and gives PyTorch's output (float64 reference)."""
    from diffcassi import _native
    a, _, _ = runs
    op = diffcassi.exact(diffcassi.System.preset("sp"), 8, 8, bands_nm=BANDS3, planes=6, rays=1, seed=6)
    y = np.ascontiguousarray(np.random.default_rng(4).uniform(0.2, 1.0, op.image_shape), dtype=np.float32)
    rust, record = _native._unrolled(op, y, str(a / NM["w"]), "sp")
    assert json.loads(record)["network"]["name"] == ARCH_V2
    net = load_unrolled(a / NM["w"], dt.CassiOperator.from_operator(op), system="sp").to(torch.float64)
    with torch.no_grad():
        ref = net(torch.from_numpy(y.astype(np.float64))).numpy().transpose(1, 2, 0)
    assert np.abs(rust - ref).max() <= 1e-5 * np.abs(ref).max(), float(np.abs(rust - ref).max() / np.abs(ref).max())


def test_resume_continues_the_steps_and_appends_a_run(runs):
    a, b, first = runs
    assert [(r["steps_from"], r["steps_to"]) for r in first["runs"]] == [(0, 2)]
    man = json.loads((b / NM["man"]).read_text())
    assert man["steps"] == 4 and [(r["steps_from"], r["steps_to"]) for r in man["runs"]] == [(0, 2), (2, 4)]
    assert man["runs"][1]["resumed_from"] == NM["ck"]
    assert [r["train_seeds"] for r in man["runs"]] == [[5_000_000, 5_000_003], [5_000_004, 5_000_007]]
    sa, sb = torch.load(a / NM["ck"]), torch.load(b / NM["ck"])
    assert sa["step"] == sb["step"] == 4
    for k in sa["model"]:
        assert torch.equal(sa["model"][k], sb["model"][k]), k  # the same weights as the straight run, bit for bit


def test_resume_may_lower_the_learning_rate_and_records_it(train, tmp_path):
    """The optimiser's settings may change on a resume (a lower --lr after a divergence): the run records
    them under "changed"; the checkpoint and the weights carry the new values; other settings stay refused."""
    c = tmp_path / "c"
    assert train.main(COMMON + ["--out", str(c), "--stop-at", "2"]) == 0
    assert train.main(["--resume", str(c / NM["ck"]), "--out", str(c), "--lr", "5e-4", "--clip", "0.5"]) == 0
    man = json.loads((c / NM["man"]).read_text())
    assert [(r["steps_from"], r["steps_to"]) for r in man["runs"]] == [(0, 2), (2, 4)]
    assert man["runs"][0].get("changed") is None and man["runs"][1]["changed"] == {"lr": [1e-3, 5e-4], "clip": [1.0, 0.5]}
    assert man["config"]["lr"] == 5e-4 and torch.load(c / NM["ck"])["config"]["clip"] == 0.5
    log = [json.loads(line) for line in (c / NM["log"]).read_text().splitlines()]
    assert max(r["lr"] for r in log if r.get("step", 0) > 2 and "lr" in r) <= 5e-4
    # The checkpoint's --lr-min (2e-5) above a new --lr is a usage error, before anything is written.
    before = {p.name: p.read_bytes() for p in c.iterdir()}
    with pytest.raises(SystemExit) as e:
        train.main(["--resume", str(c / NM["ck"]), "--out", str(c), "--lr", "1e-5"])
    assert e.value.code == 2 and {p.name: p.read_bytes() for p in c.iterdir()} == before


def test_worker_processes_make_the_same_batches(train, runs, tmp_path):
    a, _, _ = runs
    w = tmp_path / "w"
    assert train.main(COMMON + ["--out", str(w), "--workers", "2"]) == 0
    sa, sw = torch.load(a / NM["ck"]), torch.load(w / NM["ck"])
    assert sw["step"] == 4 and all(torch.equal(sa["model"][k], sw["model"][k]) for k in sa["model"])


def test_bad_resumes_are_refused_and_write_nothing(train, runs, tmp_path, capsys):
    a, _, _ = runs
    ck = a / NM["ck"]
    # A v1 checkpoint resumed as v2.
    v1 = tmp_path / "v1"
    assert train.main(["--system", "sp", "--size", "8", "--bands", "3", "--stages", "1", "--width", "2", "--planes",
                       "6", "--rays", "1", "--steps", "1", "--warmup", "0", "--val-every", "1", "--out", str(v1)]) == 0
    v1ck = v1 / "unrolled-sp-state.pt"
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(ck.read_bytes()[: ck.stat().st_size // 2])
    cases = [
        (v1ck, ["--arch", ARCH_V2], dict(arch=ARCH_V2), "checkpoint of architecture 'unrolled-gap-v1', not --arch 'unrolled-dauhst-v2'"),
        (ck, ["--arch", ARCH], dict(arch=ARCH), "checkpoint of architecture 'unrolled-dauhst-v2', not --arch 'unrolled-gap-v1'"),
        (ck, ["--system", "msp"], dict(system="msp"), "checkpoint trained for system 'sp', not --system 'msp'"),
        (ck, ["--bands", "4"], dict(bands=4), "checkpoint for 3 bands, not --bands 4"),
        (truncated, [], {}, "not a readable checkpoint \\(truncated"),
    ]
    for path, args, kw, msg in cases:
        with pytest.raises(train.CheckpointError, match=msg):
            train.read_checkpoint(path, **kw)
        out = tmp_path / f"out-{len(args)}-{path.name}"
        capsys.readouterr()
        assert train.main(["--resume", str(path), "--out", str(out)] + args) == 2
        err = capsys.readouterr().err
        assert "nothing written" in err and any(m in err for m in (msg.replace("\\", ""),)), err
        assert not out.exists(), f"{out} was written"
    # Another setting given with another value than the checkpoint's; a missing checkpoint.
    out = tmp_path / "out-steps"
    assert train.main(["--resume", str(ck), "--out", str(out), "--steps", "9"]) == 2
    assert "other settings" in capsys.readouterr().err and not out.exists()
    assert train.main(["--resume", str(tmp_path / "none.pt"), "--out", str(out)]) == 1
    assert not out.exists()
    # A fresh run into a folder that holds a checkpoint would overwrite another training: refused, untouched.
    before = {p.name: p.read_bytes() for p in a.iterdir()}
    assert train.main(COMMON + ["--out", str(a)]) == 2
    assert "already holds the checkpoint" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in a.iterdir()} == before
    with pytest.raises(FileNotFoundError, match="no such file"):
        train.read_checkpoint(tmp_path / "none.pt")


def test_time_budget_stops_cleanly_and_saves(train, tmp_path):
    out = tmp_path / "budget"
    args = list(COMMON[:-2])
    args[args.index("--steps") + 1] = "100000"
    args += ["--val-every", "1000", "--time-budget-s", "3"]
    assert train.main(args + ["--out", str(out)]) == 0
    log = [json.loads(line) for line in (out / NM["log"]).read_text().splitlines()]
    assert log[-1]["event"] == "stop" and log[-1]["reason"] == "time budget"
    step = read_metadata(out / NM["w"])["training_step"]
    assert 1 <= int(step) < 100000
    man = json.loads((out / NM["man"]).read_text())
    assert man["runs"][-1]["steps_to"] == int(step) and man["runs"][-1]["time_budget_s"] == 3


def test_committed_initial_checkpoint_resumes(train):
    assert INIT.stat().st_size <= 8_000_000
    ck = train.read_checkpoint(INIT, arch=ARCH_V2, system="sp", bands=28)
    cfg = ck["config"]
    assert (cfg["size"], cfg["planes"], cfg["rays"], cfg["stages"], cfg["width"]) == (128, 112, 20, 3, 24)
    assert cfg["acquisition_seed"] != cfg["operator_seed"] and cfg["system_sha256"] == system_sha256(diffcassi.System.preset("sp"))
    assert tuple(ck["mask"].shape) == (128, 128) and mask_sha256(ck["mask"].numpy()) == cfg["mask_sha256"]
    paper = ROOT.parent / "shared" / "reference" / "paper_mask_512.npy"
    if paper.is_file():  # the training mask is the paper's, centre-cropped (the study's rule)
        assert cfg["mask_sha256"] == mask_sha256(train.load_mask(paper, 128))
    runs = json.loads(ck["runs"])
    assert runs and runs[-1]["steps_to"] == ck["step"]
    net = UnrolledDAUHST(_phi(bands=[float(b) for b in np.linspace(450, 650, 28)]), stages=3, width=24)
    net.load_state_dict(ck["model"], strict=False)
    assert not set(ck["model"]) ^ {k for k in net.state_dict() if not k.startswith("phi.")}


def test_gpu_run_script_is_valid_bash():
    script = ROOT / "scripts" / "gpu" / "train_run.sh"
    assert script.is_file()
    subprocess.run(["bash", "-n", str(script)], check=True)
    text = script.read_text()
    assert "unrolled-dauhst-v2-sp-init.pt" in text and "DEVICE:-cuda" in text and "$OUT" in text
