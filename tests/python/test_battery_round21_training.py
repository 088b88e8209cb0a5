"""Round 21 held-out battery, training: train_unrolled.py --resume strict (model, format, optimiser, step, fields),
named errors for bad checkpoint fields and CLI values, the training step's memory checked before anything is
written, the unrolled networks' activations against the memory budget, CassiDataset's own masks and scenes, and
the thread count recorded and compared on resume."""
import contextlib
import copy
import importlib.util
import io
import pathlib
import shutil

import numpy as np
import pytest
import torch

import diffcassi
import diffcassi.torch as dt
from diffcassi.unrolled import ARCH, ARCH_V2, UnrolledDAUHST, UnrolledGAP, activation_bytes

ROOT = pathlib.Path(__file__).resolve().parents[2]
TINY = ["--system", "sp", "--size", "16", "--planes", "4", "--rays", "1", "--stages", "1", "--width", "4", "--batch",
        "1", "--warmup", "1", "--seed", "7", "--threads", "1"]


def _script():
    spec = importlib.util.spec_from_file_location("train_unrolled_r21", ROOT / "scripts" / "train_unrolled.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


TU = _script()


def run(argv):
    err = io.StringIO()
    threads = torch.get_num_threads()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = TU.main(argv)
            except SystemExit as e:  # argparse's usage errors
                rc = e.code
    finally:
        torch.set_num_threads(threads)
    return rc, err.getvalue()


@pytest.fixture(scope="module")
def step1(tmp_path_factory):
    """A tiny v1 training stopped at step 1 (of 2): its checkpoint."""
    out = tmp_path_factory.mktemp("r21train") / "run"
    rc, err = run(TINY + ["--steps", "2", "--val-every", "1", "--stop-at", "1", "--out", str(out)])
    assert rc == 0, err
    return out / "unrolled-sp-state.pt"


def _variant(src, tmp_path, fn):
    ck = torch.load(src, weights_only=True)
    fn(ck)
    p = tmp_path / "ck.pt"
    torch.save(ck, p)
    return p


CASES = {
    "model_empty": (lambda c: c.__setitem__("model", {}), "model is empty"),
    "model_missing": (lambda c: c["model"].pop("steps"), "missing tensor(s) steps"),
    "model_extra": (lambda c: c["model"].__setitem__("bogus.weight", torch.zeros(3)), "unexpected tensor(s) bogus.weight"),
    "model_shape": (lambda c: c["model"].__setitem__("steps", torch.ones(5)), "other shapes"),
    "no_format": (lambda c: c.pop("format"), "format None"),
    "future_format": (lambda c: c.__setitem__("format", "diffcassi-unrolled-checkpoint-99"), "checkpoint-99"),
    "optim_dropped": (lambda c: c["optim"].__setitem__("state", {}), "no Adam state"),
    "step_beyond": (lambda c: c.__setitem__("step", 100), "step = 100 is beyond --steps 2"),
    "torch_rng": (lambda c: c.__setitem__("torch_rng", torch.zeros(3, dtype=torch.uint8)), "field torch_rng"),
    "elapsed": (lambda c: c.__setitem__("elapsed_s", "abc"), "field elapsed_s = 'abc'"),
    "mask_nan": (lambda c: c["mask"].fill_(float("nan")), "field mask: value nan"),
    "mask_2": (lambda c: c["mask"].mul_(2), "field mask: value 2.0"),
    "runs": (lambda c: c.__setitem__("runs", "not json"), "field runs"),
    "config_size": (lambda c: c["config"].__setitem__("size", "16"), "field config.size = '16'"),
    "threads": (lambda c: c.__setitem__("threads", 0), "field threads"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_damaged_checkpoint_is_refused_by_name_and_nothing_written(step1, tmp_path, case):
    fn, says = CASES[case]
    p = _variant(step1, tmp_path, fn)
    out = tmp_path / "out"
    rc, err = run(["--threads", "1", "--resume", str(p), "--out", str(out)])
    assert rc == 2, err
    assert str(p) in err and says in err and "nothing written" in err, err
    assert not out.exists()


def test_the_committed_checkpoint_still_fits_strictly():
    """The committed v2 initial checkpoint (scripts/gpu/train_run.sh resumes it; step 0: no Adam moments yet)."""
    path = ROOT / "diffcassi" / "weights" / "unrolled-dauhst-v2-sp-init.pt"
    ck = TU.read_checkpoint(path, ARCH_V2, "sp", 28)
    cfg = ck["config"]
    net = UnrolledDAUHST(_Stub(16, 16, cfg["bands"]), stages=cfg["stages"], width=cfg["width"])
    TU.check_resume_fit(path, ck, net, opt_state_needed=ck["step"] > 0)
    assert ck["step"] <= cfg["steps"]


def test_bad_cli_values_are_named_before_tracing_or_writing(tmp_path):
    for extra, says in ((["--bands", "100000"], "--bands 100000"), (["--stages", "100000", "--width", "1000"], "--stages 100000"),
                        (["--batch", "1000000000"], "--batch 1000000000"), (["--planes", "200000"], "--planes 200000"),
                        (["--size", "100000"], "--size 100000")):
        out = tmp_path / "o"
        rc, err = run(TINY + ["--steps", "2", *extra, "--out", str(out)])
        assert rc == 2 and says in err and "nothing written" in err and "Traceback" not in err, (extra, err)
        assert not out.exists(), extra
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    rc, err = run(TINY + ["--steps", "2", "--mask", str(empty), "--out", str(tmp_path / "o")])
    assert rc == 1 and f"--mask {empty}" in err, err


def test_the_training_step_memory_estimate_scales_with_the_batch():
    one = TU.step_memory_bytes(ARCH, 28, 6, 16, 128, 1)
    assert TU.step_memory_bytes(ARCH, 28, 6, 16, 128, 4) == pytest.approx(4 * one)
    assert one > activation_bytes(ARCH, 28, 16, 6, 128, 128, 1)


class _Stub(torch.nn.Module):
    """An operator of the right shapes (Φ: ones; cheap): enough for the networks' construction and memory checks."""

    def __init__(self, h, w, bands):
        super().__init__()
        self.cube_shape, self.image_shape = (h, w, bands), (h, w + 8)

    def forward(self, x):
        return x.sum(1)[..., :1].expand(*x.shape[:1], *self.image_shape) if x.dim() == 4 else torch.ones(self.image_shape)

    def adjoint(self, y):
        h, w, b = self.cube_shape
        return y.mean().expand(*y.shape[:-2], b, h, w).clone() if y.dim() == 3 else torch.ones(b, h, w)


@pytest.fixture
def budget():
    before = diffcassi.get_limits()
    yield
    diffcassi.set_limits(max_memory_gb=None)
    assert diffcassi.get_limits()["max_memory_gb"] == before["max_memory_gb"]


@pytest.mark.parametrize("cls,arch", [(UnrolledGAP, ARCH), (UnrolledDAUHST, ARCH_V2)])
def test_unrolled_forward_checks_its_activations_against_the_budget(budget, cls, arch):
    net = cls(_Stub(64, 64, 8), stages=2, width=8)
    need = activation_bytes(arch, 8, 8, 2, 64, 64, 4, grad=True)
    free = activation_bytes(arch, 8, 8, 2, 64, 64, 4, grad=False)
    assert free < need
    diffcassi.set_limits(max_memory_gb=(need + free) / 2 / 1e9)  # between: grad refused, no_grad runs
    y = torch.rand(4, 64, 72)
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"batch 4 of 64×64.*kept for backward.*max_memory_gb"):
        net(y)
    with torch.no_grad():
        assert net(y).shape == (4, 8, 64, 64)
    diffcassi.set_limits(max_memory_gb=None)
    assert net(y[:1]).shape == (1, 8, 64, 64)


def _dataset(cube):
    return dt.CassiDataset([(cube, [500.0, 550.0, 600.0])], "sp", 8, length=3, seed=0, transport=dict(planes=2, rays=1))


def test_dataset_items_have_their_own_mask():
    ds = _dataset(np.full((12, 12, 3), 0.5, np.float32))
    a, b = ds[0], ds[1]
    assert a[1].data_ptr() != b[1].data_ptr()
    total = float(b[1].sum())
    a[1].zero_()  # an in-place augmentation of one item's mask
    assert float(ds[2][1].sum()) == total > 0


def test_dataset_copies_the_callers_scene():
    cube = np.full((12, 12, 3), 0.5, np.float32)
    ds = _dataset(cube)
    before = ds[0][2].clone()
    cube[:] = np.nan  # after the radiance check at construction
    assert torch.equal(ds[0][2], before)


def test_a_resume_with_other_threads_warns_and_is_recorded(step1, tmp_path):
    ck = torch.load(step1, weights_only=True)
    assert ck["threads"] == 1
    out = tmp_path / "t2"
    rc, err = run(["--threads", "2", "--resume", str(step1), "--stop-at", "2", "--out", str(out)])
    assert rc == 0, err
    assert "WARNING" in err and "--threads 1" in err and "--threads 2" in err and "thread count" in err, err
    log = (out / "unrolled-sp-log.jsonl").read_text()
    assert '"threads_changed": [1, 2]' in log
    rc, err = run(["--threads", "1", "--resume", str(step1), "--stop-at", "2", "--out", str(tmp_path / "t1")])
    assert rc == 0 and "WARNING" not in err, err
