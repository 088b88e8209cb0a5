"""The PnP fine-tuning's artefact pairs (scripts/make_pnp_pairs.py) and their use by scripts/train_denoiser.py
(src/recon/prior/MODEL.md, round 4): the identity network returns its input (so ``pnp-gap`` with it hands back
the iterate the network is given), a tiny pairs file is consistent (inputs scaled to peak 1, ``err`` the RMSE
against the target), the pair seeds are disjoint from every other seed of the denoiser's data, a training run
with pairs resumes exactly and keeps the selection rule, and bad pair files give clear errors. Tiny sizes only."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed (scripts/setup.sh installs it with torch)")
pytest.importorskip("colour", reason="colour-science not installed (scripts/setup.sh installs it with torch)")

import diffcassi  # noqa: E402
from diffcassi.denoiser import ARCH, denoise, load_weights  # noqa: E402

from conftest import load_script  # noqa: E402


@pytest.fixture(scope="module")
def pairs_script():
    return load_script("make_pnp_pairs")


@pytest.fixture(scope="module")
def train():
    return load_script("train_denoiser")


@pytest.fixture(scope="module")
def pairs_file(pairs_script, tmp_path_factory):
    out = tmp_path_factory.mktemp("pairs") / "pairs.npz"
    assert pairs_script.main(["--out", str(out), "--count", "2", "--size", "16"]) == 0
    return out


def test_identity_network_returns_its_input(pairs_script, tmp_path):
    path = tmp_path / "id.safetensors"
    pairs_script.identity_weights(path, 28)
    net = load_weights(path, bands=28)
    x = torch.rand(1, 28, 10, 14)
    assert torch.allclose(denoise(net, x, 0.3), x, atol=1e-6)
    cube = np.random.default_rng(0).random((10, 14, 28)).astype(np.float32)
    assert np.abs(diffcassi.denoise(cube, 0.3, weights=str(path)) - cube).max() < 1e-5


def test_pairs_file_is_consistent(pairs_file, train):
    with np.load(pairs_file) as z:
        x, t, err, stage, preset, peak = (z[k] for k in ("inputs", "targets", "err", "stage", "preset", "peak"))
        manifest = json.loads(str(z["manifest"]))
    assert x.shape == t.shape == (8, 28, 16, 16) and x.dtype == np.float32
    assert np.allclose(x.reshape(8, -1).max(1), 1.0)  # the pairs' normalisation: the iterate's peak
    assert np.allclose(err, np.sqrt(((x - t) ** 2).reshape(8, -1).mean(1)), rtol=1e-4)
    assert 0 < err.min() and err.max() < 1 and (peak > 0).all()
    assert list(stage) == [0, 1, 0, 1] * 2 and list(preset) == [0, 0, 1, 1] * 2
    assert manifest["image_files"] == [] and manifest["evaluation_scenes_used"] == []
    # The truth is the scene's dead-leaves cube (peak 1) over the iterate's peak.
    from diffcassi.deadleaves import dead_leaves
    seed = int(np.load(pairs_file)["scene_seed"][0])
    assert np.allclose(t[0] * peak[0], dead_leaves(seed, 16, kind="rgb"), atol=1e-6)
    loaded = train.load_pairs(pairs_file)
    assert loaded["sigma"].tolist() == pytest.approx([train.PAIR_SIGMA[s] for s in stage])


def test_pair_seeds_disjoint_from_the_other_denoiser_seeds(pairs_script, train):
    ev = load_script("eval_pnp")
    train_pairs = {pairs_script.PAIR_SEED_BASE + i for i in range(100_000)}
    val_pairs = {pairs_script.PAIR_VAL_SEED_BASE + i for i in range(100_000)}
    eval_val = {ev.EVAL_VAL_SEED_BASE + i for i in range(100_000)}
    others = set(train.val_seeds()) | set(train.sel_seeds())
    assert not train_pairs & val_pairs and not (train_pairs | val_pairs) & eval_val
    assert not (train_pairs | val_pairs | eval_val) & others
    # The Gaussian training seeds stay below the pair seeds for 1.9 M steps (round 3 ran 4 457).
    assert max(train.train_seeds(1_900_000)) < pairs_script.PAIR_SEED_BASE


def test_training_with_pairs_resumes_exactly_and_logs_the_pnp_score(train, pairs_file, tmp_path):
    common = ["--patch", "16", "--threads", "1", "--warmup", "1", "--val-every", "2", "--width", "4", "--latent", "6",
              "--pairs", str(pairs_file), "--pairs-val", str(pairs_file), "--pair-batch", "2"]
    a, b = tmp_path / "a", tmp_path / "b"
    assert train.main(common + ["--steps", "4", "--out", str(a)]) == 0
    assert train.main(common + ["--steps", "2", "--out", str(b)]) == 0
    assert train.main(common + ["--steps", "4", "--out", str(b), "--resume", str(b / "train-state.pt")]) == 0
    sa, sb = torch.load(a / "train-state.pt"), torch.load(b / "train-state.pt")
    for k in sa["model"]:
        assert torch.equal(sa["model"][k], sb["model"][k]), k
    vals = [json.loads(line) for line in (a / "train-log.jsonl").read_text().splitlines()]
    vals = [r for r in vals if "val_psnr_db" in r]
    assert all({"stop", "stop_input", "half", "half_input"} <= set(r["pnp_val_psnr_db"]) for r in vals)
    # The rule: the best stop-stage PSNR among checkpoints within --sel-tolerance of step 0's selection score.
    ok = [r for r in vals if r["sel_score_db"] >= vals[0]["sel_score_db"] - 0.2]
    best = max(ok, key=lambda r: r["pnp_val_psnr_db"]["stop"])
    from safetensors import safe_open
    with safe_open(str(a / f"{ARCH}-28.safetensors"), framework="pt") as f:
        meta = f.metadata()
    assert meta["training_step"] == str(best["step"]) and "pnp_val_psnr_db" in meta
    man = json.loads((a / "train-manifest.json").read_text())
    assert man["artefact_pairs"]["count"] == 8 and man["artefact_pairs"]["per_step"] == 2
    # Another pairs file does not resume this state.
    other = tmp_path / "other.npz"
    with np.load(pairs_file) as z:
        d = {k: z[k] for k in z.files}
    d["targets"] = d["targets"] * 0.5
    np.savez(other, **d)
    bad = [x if x != str(pairs_file) else str(other) for x in common]
    assert train.main(bad + ["--steps", "6", "--out", str(b), "--resume", str(b / "train-state.pt")]) == 2


def test_bad_pairs_files_give_clear_errors(train, pairs_file, tmp_path, capsys):
    common = ["--patch", "16", "--threads", "1", "--steps", "1", "--width", "4", "--latent", "6", "--out", str(tmp_path / "o")]
    assert train.main(common + ["--pairs", str(tmp_path / "none.npz")]) == 1
    assert "none.npz: no such file" in capsys.readouterr().err
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert train.main(common + ["--pairs", str(tmp_path / "junk.npz")]) == 1
    assert "not a make_pnp_pairs.py file" in capsys.readouterr().err
    with np.load(pairs_file) as z:
        d = {k: z[k] for k in z.files}
    d["inputs"] = d["inputs"].copy()
    d["inputs"][0, 0, 0, 0] = np.nan
    np.savez(tmp_path / "nan.npz", **d)
    assert train.main(common + ["--pairs", str(tmp_path / "nan.npz")]) == 1
    assert "must be finite" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        train.main(common[:-4] + ["--patch", "32", "--out", str(tmp_path / "o"), "--pairs", str(pairs_file)])
    assert e.value.code == 2
    assert not (tmp_path / "o" / f"{ARCH}-28.safetensors").exists()


def test_round4_manifest_uses_no_image_and_no_evaluation_scene():
    from conftest import ROOT
    man = json.loads((ROOT / "src/recon/prior/weights/train-manifest-round4.json").read_text())
    assert man["image_files"] == [] and man["evaluation_scenes_used"] == []
    for key in ("artefact_pairs", "artefact_pairs_val"):
        assert man[key]["manifest"]["image_files"] == [] and man[key]["manifest"]["evaluation_scenes_used"] == []
    assert man["artefact_pairs"]["sha256"] != man["artefact_pairs_val"]["sha256"]
    assert man["artefact_pairs"]["manifest"]["seed_base"] != man["artefact_pairs_val"]["manifest"]["seed_base"]


# ---- round 6: pairs from a multi-call schedule, the PnP-stage network ----

def test_schedule_rollout_equals_the_rust_pnp_gap(pairs_script):
    """The NumPy/PyTorch rollout of ``pnp-gap``'s network phase (what the round-6 pairs and ``eval_pnp.py roll:``
    use) equals the Rust solver with the same network and σ schedule, 2 calls, to 1e-4 of the peak."""
    weights = str(pairs_script.ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors")
    assert pairs_script.check_rollout(weights, pairs_script.sigma_schedule(0.3, 0.1, 2), size=16) < 1e-4


def test_equivariant_rollout_equals_the_rust_pnp_gap(pairs_script):
    """Equivariant PnP: the rollout with ``dihedral_draw``'s transforms (what ``eval_pnp.py roll:…:eq=SEED`` uses)
    equals the Rust solver's ``equivariant=True`` run, 3 calls, to 1e-4 of the peak — so the Python twin draws
    the same transforms and inverts them as the Rust solver does; without the transforms it does not."""
    from diffcassi.denoiser import dihedral_draw
    weights = str(pairs_script.ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors")
    sig = pairs_script.sigma_schedule(0.2, 0.05, 3)
    assert any(dihedral_draw(1, j, True) != (0, False) for j in (1, 2, 3))
    assert pairs_script.check_rollout(weights, sig, size=16, equivariant_seed=1) < 1e-4


def test_network_scale_is_the_solvers():
    """``network_scale`` = ``recon::solver::NetworkScale``: the maximum without outliers, the largest inlier
    (≤ 1.5 × the 0.999 quantile) with one."""
    ps = load_script("make_pnp_pairs")
    x = np.linspace(0.0, 1.0, 5000, dtype=np.float32)
    assert ps.network_scale(x) == pytest.approx(1.0)
    x[7] = 100.0
    assert ps.network_scale(x) == pytest.approx(1.0)
    assert ps.network_scale(np.zeros(10, np.float32)) == 1.0
    assert ps.sigma_schedule(0.3, 0.1, 3) == pytest.approx([0.3, 0.3 * (1 / 3) ** 0.5, 0.1])


@pytest.fixture(scope="module")
def schedule_pairs(pairs_script, tmp_path_factory):
    out = tmp_path_factory.mktemp("pairs6") / "pairs.npz"
    assert pairs_script.main(["--out", str(out), "--count", "1", "--size", "16", "--schedule", "2:0.3:0.1"]) == 0
    return out


def test_schedule_pairs_file_is_consistent(schedule_pairs, train, pairs_script):
    with np.load(schedule_pairs) as z:
        x, t, err, stage, preset, sigma = (z[k] for k in ("inputs", "targets", "err", "stage", "preset", "sigma"))
        manifest = json.loads(str(z["manifest"]))
    assert x.shape == t.shape == (4, 28, 16, 16)
    assert list(stage) == [0, 1, 0, 1] and list(preset) == [0, 0, 1, 1]
    assert sigma.tolist() == pytest.approx([0.3, 0.1] * 2)
    assert np.allclose(err, np.sqrt(((x - t) ** 2).reshape(4, -1).mean(1)), rtol=1e-4)
    assert manifest["stages"] == ["call1", "call2"] and manifest["schedule"]["calls"] == 2
    assert manifest["image_files"] == [] and manifest["evaluation_scenes_used"] == []
    assert manifest["seed_base"] == pairs_script.PAIR_SEED_BASE
    loaded = train.load_pairs(schedule_pairs)
    assert loaded["stage_names"] == ["call1", "call2"] and loaded["sigma"].tolist() == pytest.approx(sigma.tolist())


def test_stage_net_training_writes_a_pnp_stage_file(train, schedule_pairs, tmp_path, capsys):
    out = tmp_path / "s"
    args = ["--patch", "16", "--threads", "1", "--warmup", "1", "--val-every", "2", "--width", "4", "--latent", "6",
            "--pairs", str(schedule_pairs), "--pairs-val", str(schedule_pairs), "--pair-batch", "2", "--stage-net",
            "--steps", "4", "--out", str(out)]
    assert train.main(args) == 0
    w = out / f"{ARCH}-28.safetensors"
    net = load_weights(w, bands=28)
    assert net.stage == "pnp"
    vals = [json.loads(line) for line in (out / "train-log.jsonl").read_text().splitlines()]
    vals = [r for r in vals if "pnp_val_psnr_db" in r]
    assert all({"call1", "call2", "call1_input", "call2_input"} <= set(r["pnp_val_psnr_db"]) for r in vals)
    # The rule: the best mean over the calls.
    best = max(vals, key=lambda r: (r["pnp_val_psnr_db"]["call1"] + r["pnp_val_psnr_db"]["call2"]) / 2)
    from safetensors import safe_open
    with safe_open(str(w), framework="pt") as f:
        meta = f.metadata()
    assert meta["stage"] == "pnp" and meta["training_step"] == str(best["step"])
    assert json.loads(meta["pnp_schedule"])["calls"] == 2
    # A Gaussian denoiser's loader (Rust) refuses it; the PnP solvers take it.
    cube = np.random.default_rng(0).random((8, 8, 28)).astype(np.float32)
    with pytest.raises(diffcassi.DiffcassiError, match="stage"):
        diffcassi.denoise(cube, 0.1, weights=str(w))
    # --stage-net without validation pairs is a usage error.
    with pytest.raises(SystemExit) as e:
        train.main([a for a in args if a not in ("--pairs-val", str(schedule_pairs))] + ["--pairs", str(schedule_pairs)])
    assert e.value.code == 2


def test_round6_manifest_uses_no_image_and_no_evaluation_scene():
    from conftest import ROOT
    man = json.loads((ROOT / "src/recon/prior/weights/train-manifest-round6.json").read_text())
    assert man["image_files"] == [] and man["evaluation_scenes_used"] == []
    for key in ("artefact_pairs", "artefact_pairs_val"):
        assert man[key]["manifest"]["image_files"] == [] and man[key]["manifest"]["evaluation_scenes_used"] == []
    assert man["artefact_pairs"]["sha256"] != man["artefact_pairs_val"]["sha256"]
    assert man["artefact_pairs"]["manifest"]["seed_base"] != man["artefact_pairs_val"]["manifest"]["seed_base"]
    assert man["artefact_pairs"]["stage_net"] is True


def test_eval_pnp_metrics_and_sam_diagnosis_match_the_project_metrics():
    """Round 7: eval_pnp's PSNR/SSIM/SAM are ``diffcassi.metrics``'s, and ``--diagnose``'s per-pixel angles are
    the same SAM split by truth brightness (equal quartiles here: the mean of the four is the SAM); clipping at 0
    changes SAM only where the estimate is negative, and the share of negatives is counted."""
    ev = load_script("eval_pnp")
    rng = np.random.default_rng(7)
    truth = rng.random((16, 16, 28)).astype(np.float32)
    est = (truth + 0.2 * rng.standard_normal(truth.shape)).astype(np.float32)
    m = ev.project_metrics(truth, est)
    ref = diffcassi.metrics(truth, est)
    assert (m["psnr"], m["ssim"], m["sam"]) == (ref["psnr_db"], ref["ssim"], ref["sam_deg"])
    d = ev.sam_diagnosis(truth, est)
    assert np.mean([d[f"sam_q{i}"] for i in range(1, 5)]) == pytest.approx(ref["sam_deg"], abs=1e-9)
    assert d["sam_q1"] > d["sam_q4"]  # the same absolute noise is a larger angle on dark spectra
    assert d["neg"] == pytest.approx(float((est < 0).mean())) and d["neg"] > 0
    assert d["sam_clip0"] != pytest.approx(ref["sam_deg"], abs=1e-6)
    pos = np.abs(est)
    assert ev.sam_diagnosis(truth, pos)["sam_clip0"] == pytest.approx(diffcassi.metrics(truth, pos)["sam_deg"], abs=1e-9)


def test_eval_pnp_oracle_operator_reproduces_the_acquisition():
    """``eval_pnp.py --operator-seed 0`` (MODEL.md round 8) rests on the exact operator traced with the
    acquisition's own Monte-Carlo seed reproducing the acquisition (no model mismatch, so δ = 0 is right), while
    the realistic setting's operator (another seed) does not. Tiny size: 16², 28 planes, 4 rays."""
    ev = load_script("eval_pnp")
    from diffcassi.deadleaves import BANDS_NM, dead_leaves
    size = 16
    truth = np.ascontiguousarray(dead_leaves(7, size, BANDS_NM, kind="rgb").transpose(1, 2, 0))
    mask = (np.random.default_rng(3).random((size, size)) > 0.5).astype(np.float32)
    system = diffcassi.System.preset("sp")
    y, _ = diffcassi.render(system, truth, list(BANDS_NM), mask, rays=4, planes=28, seed=ev.ACQUISITION_SEED)
    y = np.asarray(y, dtype=np.float64)
    rel = {}
    for seed in (ev.ACQUISITION_SEED, ev.OPERATOR_SEED):
        op = diffcassi.exact(system, size, size, mask, rays=4, planes=28, seed=seed)
        rel[seed] = np.linalg.norm(op.apply(truth) - y) / np.linalg.norm(y)
    assert rel[ev.ACQUISITION_SEED] < 1e-5, rel
    assert rel[ev.OPERATOR_SEED] > 1e-3, rel


def test_eval_pnp_refuses_a_negative_operator_seed(capsys):
    """``--operator-seed`` below 0 is a usage error (exit 2, the option named) before anything is rendered."""
    ev = load_script("eval_pnp")
    with pytest.raises(SystemExit) as e:
        ev.main(["--operator-seed", "-1"])
    assert e.value.code == 2
    assert "--operator-seed" in capsys.readouterr().err


# ---- session 15: half-size stop-only pairs, the GPU training's options ----

def test_stop_only_float16_pairs_load_as_float32(pairs_script, train, tmp_path):
    out = tmp_path / "half.npz"
    assert pairs_script.main(["--out", str(out), "--count", "1", "--size", "16", "--stop-only", "--float16"]) == 0
    with np.load(out) as z:
        assert z["inputs"].dtype == z["targets"].dtype == np.float16 and z["inputs"].shape == (2, 28, 16, 16)
        assert list(z["stage"]) == [0, 0] and list(z["preset"]) == [0, 1]
        assert json.loads(str(z["manifest"]))["stages"] == ["stop"]
        x16 = z["inputs"]
    loaded = train.load_pairs(out)
    assert loaded["inputs"].dtype == torch.float32 and np.array_equal(loaded["inputs"].numpy(), x16.astype(np.float32))
    assert loaded["stage_names"] == ["stop"] and loaded["sigma"].tolist() == pytest.approx([train.PAIR_SIGMA[0]] * 2)


def test_sel_floor_no_checkpoint_passing_is_an_error_and_writes_no_weights(train, pairs_file, tmp_path, capsys):
    out = tmp_path / "floor"
    common = ["--patch", "16", "--threads", "1", "--warmup", "1", "--val-every", "2", "--steps", "2", "--width", "8",
              "--pairs", str(pairs_file), "--pairs-val", str(pairs_file), "--pair-batch", "2"]
    assert train.main(common + ["--out", str(out), "--sel-floor", "99"]) == 1
    assert "no checkpoint met the selection rule" in capsys.readouterr().err
    assert not (out / f"{ARCH}-28.safetensors").exists()
    # A reachable floor: the file holds the best stop-stage score among the checkpoints over it.
    assert train.main(common + ["--out", str(tmp_path / "ok"), "--sel-floor", "0"]) == 0
    log = [json.loads(line) for line in (tmp_path / "ok" / "train-log.jsonl").read_text().splitlines()][1:]
    best = max(log, key=lambda r: r["pnp_val_psnr_db"]["stop"])
    from safetensors import safe_open
    with safe_open(str(tmp_path / "ok" / f"{ARCH}-28.safetensors"), framework="pt") as f:
        assert f.metadata()["training_step"] == str(best["step"])


def test_pair_rotate_adds_quarter_turns_to_the_flips(train):
    """``--pair-rotate`` (for equivariant PnP): the pair crops are also turned by quarter turns, input and target
    alike; without it only the four flips occur and the draws are unchanged (the same generator state gives the
    same batch as before the option)."""
    x = torch.arange(2 * 4 * 4, dtype=torch.float32).reshape(1, 2, 4, 4)
    pairs = {"inputs": x, "targets": x + 1000.0, "sigma": torch.tensor([0.3])}
    flips = {tuple(torch.flip(x[0], dims=d).flatten().tolist()) for d in ((), (1,), (2,), (1, 2))}
    seen = {False: set(), True: set()}
    for rotate in (False, True):
        for s in range(64):
            xi, sig, t = train.pair_batch(pairs, 1, 4, torch.Generator().manual_seed(s), rotate)
            assert torch.equal(t, xi + 1000.0) and float(sig[0]) == pytest.approx(0.3)
            seen[rotate].add(tuple(xi[0].flatten().tolist()))
    assert seen[False] <= flips and len(seen[False]) == 4
    assert len(seen[True]) == 8 and not seen[True] <= flips  # the whole dihedral group
    a = train.pair_batch(pairs, 1, 4, torch.Generator().manual_seed(5))
    b = train.pair_batch(pairs, 1, 4, torch.Generator().manual_seed(5), False)
    assert all(torch.equal(p, q) for p, q in zip(a, b))
