"""Round 9 of the held-out battery (prober B: the torch modules and scripts/train_unrolled.py): a resume into a folder
of another training is refused; a diverged training saves nothing non-finite and says which step the state keeps;
Ctrl-C stops at a step boundary with the checkpoint, the weights and the manifest of one step (a Ctrl-C during a
save waits for it); bad options are usage errors before anything is written; ``--val-every`` is restored on resume;
``--summary`` names the line of a bad record and keeps the last record of a step; ``load_unrolled`` checks the band
wavelengths and warns about a System of a preset's name with another prescription; ``CassiRenderer`` state dicts
record θ's parameters and system, and negative views render; messages. Tiny sizes only."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch not installed (DIFFCASSI_TORCH=skip)")
pytest.importorskip("safetensors", reason="safetensors not installed (scripts/setup.sh installs it with torch)")
pytest.importorskip("colour", reason="colour-science not installed (scripts/setup.sh installs it with torch)")

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.unrolled import ARCH_V2, UnrolledGAP, load_unrolled, read_metadata, save_unrolled  # noqa: E402

from conftest import ROOT, load_script  # noqa: E402

TINY = ["--system", "sp", "--size", "16", "--planes", "4", "--rays", "1", "--stages", "1", "--width", "4", "--batch",
        "1", "--threads", "1", "--warmup", "1"]
V1 = {"w": "unrolled-gap-v1-sp.safetensors", "log": "unrolled-sp-log.jsonl", "man": "unrolled-sp-manifest.json",
      "ck": "unrolled-sp-state.pt"}
V2 = {"w": f"{ARCH_V2}-sp.safetensors", "log": f"{ARCH_V2}-sp-log.jsonl", "man": f"{ARCH_V2}-sp-manifest.json",
      "ck": f"{ARCH_V2}-sp-checkpoint.pt"}
V2_TINY = ["--arch", ARCH_V2, "--system", "sp", "--size", "8", "--bands", "3", "--stages", "1", "--width", "4",
           "--planes", "6", "--rays", "1", "--batch", "1", "--warmup", "1", "--threads", "1"]
WEIGHTS_V1 = ROOT / "diffcassi" / "weights" / "unrolled-gap-v1-sp.safetensors"


@pytest.fixture(scope="module")
def train():
    return load_script("train_unrolled")


def _no_nan(text):
    """JSON lines parsed strictly: NaN, Infinity and -Infinity are not JSON."""
    def refuse(c):
        raise AssertionError(f"non-JSON constant {c} in a log line")
    return [json.loads(line, parse_constant=refuse) for line in text.splitlines()]


def _files(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _consistent(folder, names, step):
    """The checkpoint, the weights (and a v2 manifest) describe ``step``."""
    ck = torch.load(folder / names["ck"], weights_only=True)
    assert ck["step"] == step and read_metadata(folder / names["w"])["training_step"] == str(step)
    man = json.loads((folder / names["man"]).read_text())
    if "steps" in man:
        assert man["steps"] == step and man["runs"] == json.loads(ck["runs"])
    return ck


@pytest.fixture(scope="module")
def straight(train, tmp_path_factory):
    """A straight 4-step v1 run validating every 3 steps (seed 7)."""
    out = tmp_path_factory.mktemp("r9") / "straight"
    assert train.main(TINY + ["--steps", "4", "--val-every", "3", "--seed", "7", "--out", str(out)]) == 0
    return out


# ------------------------------------------------------------------------------------------- finding 1

def test_a_resume_into_the_folder_of_another_training_is_refused(train, straight, tmp_path, capsys):
    other = tmp_path / "other"
    assert train.main(TINY + ["--steps", "4", "--val-every", "3", "--stop-at", "1", "--out", str(other)]) == 0
    before = _files(straight)
    capsys.readouterr()
    assert train.main(["--resume", str(other / V1["ck"]), "--out", str(straight)]) == 2
    err = capsys.readouterr().err
    assert "already holds the checkpoint unrolled-sp-state.pt of another training" in err and "nothing written" in err
    assert _files(straight) == before
    # A folder holding only part of a training (its log) is another training too.
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / V1["log"]).write_text("{}\n")
    assert train.main(["--resume", str(other / V1["ck"]), "--out", str(partial)]) == 2
    assert "the files unrolled-sp-log.jsonl" in capsys.readouterr().err
    # Its own checkpoint (the same file, or a copy of the same bytes) resumes in its folder; so does an empty folder.
    copy = tmp_path / "copy.pt"
    copy.write_bytes((other / V1["ck"]).read_bytes())
    assert train.main(["--resume", str(copy), "--out", str(other), "--stop-at", "2"]) == 0
    assert torch.load(other / V1["ck"], weights_only=True)["step"] == 2
    assert train.main(["--resume", str(copy), "--out", str(tmp_path / "fresh"), "--stop-at", "1"]) == 0


# ------------------------------------------------------------------------------------- findings 2, 8, 9

def test_a_diverged_training_saves_nothing_non_finite(train, tmp_path, monkeypatch, capsys):
    real, calls = train.l1_step, []

    def poisoned(opt, params, *args):
        loss = real(opt, params, *args)
        calls.append(loss)
        if len(calls) == 3:  # the update of step 2 leaves the network non-finite
            with torch.no_grad():
                for p in opt.param_groups[0]["params"]:
                    p.fill_(float("inf"))
        return loss

    monkeypatch.setattr(train, "l1_step", poisoned)
    out = tmp_path / "div"
    capsys.readouterr()
    assert train.main(TINY + ["--steps", "5", "--val-every", "1", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "diverged at step 3" in err and "the state keeps step 2" in err and "lower --lr" in err, err
    assert "Traceback" not in err
    ck = _consistent(out, V1, 2)
    assert all(torch.isfinite(v).all() for v in ck["model"].values())
    log = _no_nan((out / V1["log"]).read_text())
    assert [r["step"] for r in log if "val_psnr_db" in r] == [0, 1, 2]
    assert log[-1]["event"] == "stop" and log[-1]["reason"] == "diverged" and log[-1]["saved_step"] == 2
    phi = dt.CassiOperator.from_operator(diffcassi.exact(diffcassi.System.preset("sp"), 16, 16, planes=4, rays=1, seed=1),
                                         matrix_free=True)
    assert all(torch.isfinite(p).all() for p in load_unrolled(out / V1["w"], phi, system="sp").parameters())


@pytest.mark.parametrize("args, named", [
    (["--lr", "inf"], "--lr"), (["--lr", "1e300"], "--lr"), (["--lr", "nan"], "--lr"), (["--lr-min", "inf"], "--lr-min"),
    (["--lr-min", "0.01"], "--lr-min"), (["--clip", "inf"], "--clip"), (["--minutes", "nan"], "--minutes"),
    (["--time-budget-s", "inf"], "--time-budget-s"), (["--seed", "-1"], "--seed"),
    (["--acquisition-seed", "-1"], "--acquisition-seed"), (["--operator-seed", str(2 ** 64)], "--operator-seed"),
    (["--threads", "5000"], "--threads"), (["--workers", "2"], "--workers"), (["--stop-at", "-1"], "--stop-at"),
    (["--warmup", "4"], "--warmup"), (["--warmup", "100"], "--warmup"),
])
def test_bad_options_are_usage_errors_before_anything_is_written(train, tmp_path, capsys, args, named):
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as e:
        train.main(TINY + ["--steps", "4", "--out", str(out)] + args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err, err
    assert not out.exists()


def test_bad_device_and_out_are_refused_before_any_work(train, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert train.main(TINY + ["--steps", "4", "--out", str(afile / "sub")]) == 2
    assert f"{afile} is not a folder" in capsys.readouterr().err and afile.read_text() == "x"
    out = tmp_path / "dev"
    assert train.main(TINY + ["--steps", "4", "--device", "cpu:1", "--out", str(out)]) == 2
    assert "--device cpu:1" in capsys.readouterr().err and not out.exists()


# ------------------------------------------------------------------------------------------- finding 6

def _interrupt_on_call(n):
    """A wrapper of a function that sends this process SIGINT at its ``n``-th call (before calling it)."""
    calls = []

    def wrap(real):
        def f(*args, **kwargs):
            calls.append(1)
            if len(calls) == n:
                os.kill(os.getpid(), signal.SIGINT)
            return real(*args, **kwargs)
        return f
    return wrap


def test_ctrl_c_stops_at_a_step_boundary_and_the_resume_is_exact(train, straight, tmp_path, monkeypatch, capsys):
    out = tmp_path / "int"
    monkeypatch.setattr(train, "l1_step", _interrupt_on_call(2)(train.l1_step))  # during step 1
    capsys.readouterr()
    assert train.main(TINY + ["--steps", "4", "--val-every", "3", "--seed", "7", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert f"interrupted at step 2: the state keeps step 2; continue with --resume {out / V1['ck']}" in err, err
    ck = _consistent(out, V1, 2)
    assert ck["val_every"] == 3
    log = _no_nan((out / V1["log"]).read_text())
    assert log[-1]["event"] == "stop" and log[-1]["reason"] == "interrupted" and log[-1]["step"] == 2
    monkeypatch.undo()
    # The resume takes --val-every from the checkpoint (3: validates at 3 and 4) and ends bit for bit as the
    # uninterrupted run.
    assert train.main(["--resume", str(out / V1["ck"]), "--out", str(out)]) == 0
    log = _no_nan((out / V1["log"]).read_text())
    k = max(i for i, r in enumerate(log) if r.get("event") == "resume")
    assert [r["step"] for r in log[k:] if "val_psnr_db" in r] == [3, 4]
    a, b = torch.load(straight / V1["ck"], weights_only=True), torch.load(out / V1["ck"], weights_only=True)
    assert a["step"] == b["step"] == 4 and all(torch.equal(a["model"][n], b["model"][n]) for n in a["model"])


def test_ctrl_c_during_a_save_waits_for_it_and_the_manifest_agrees(train, tmp_path, monkeypatch, capsys):
    out = tmp_path / "v2"
    real = train.save_unrolled
    calls = []

    def save_twice_interrupted(*args, **kwargs):  # two Ctrl-C inside the save of step 2 (the 3rd save)
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(train, "save_unrolled", save_twice_interrupted)
    capsys.readouterr()
    assert train.main(V2_TINY + ["--steps", "6", "--val-every", "1", "--out", str(out)]) == 130
    assert "interrupted at step 2: the state keeps step 2" in capsys.readouterr().err
    ck = _consistent(out, V2, 2)
    assert [(r["steps_from"], r["steps_to"]) for r in json.loads(ck["runs"])] == [(0, 2)]
    monkeypatch.undo()
    # A resume removes the staged files of a killed save, and its manifest at start describes the checkpoint (the
    # runs so far), not a new run: stopped in its set-up, the folder still agrees.
    (out / f"{V2['ck']}.tmp").write_bytes(b"partial")
    (out / f"{V2['man']}.tmp").write_bytes(b"partial")

    def stop(*args, **kwargs):
        raise RuntimeError("stopped in the set-up")
    monkeypatch.setattr(train, "make_cubes_v2", stop)
    with pytest.raises(RuntimeError, match="stopped in the set-up"):
        train.main(["--resume", str(out / V2["ck"]), "--out", str(out)])
    assert not (out / f"{V2['ck']}.tmp").exists() and not (out / f"{V2['man']}.tmp").exists()
    _consistent(out, V2, 2)


def test_sigint_to_the_script_exits_130_with_the_state_saved(tmp_path):
    out = tmp_path / "sig"
    p = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train_unrolled.py")] + TINY +
                         ["--steps", "100000", "--val-every", "1000", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert p.stdout.readline().startswith("step 0 val")  # the initial state is saved: the loop starts
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert "Traceback" not in err and "interrupted at step" in err and "continue with --resume" in err, err
    step = int(err.split("interrupted at step ")[1].split(":")[0])
    assert f"the state keeps step {step};" in err
    _consistent(out, V1, step)
    log = _no_nan((out / V1["log"]).read_text())
    assert log[-1] == dict(log[-1], event="stop", reason="interrupted", step=step)


# ------------------------------------------------------------------------------------------ finding 12

def test_resume_conflicts_are_settings_conflicts(train, straight, tmp_path, capsys):
    out = tmp_path / "conf"
    assert train.main(["--resume", str(straight / V1["ck"]), "--out", str(out), "--size", "24"]) == 2
    err = capsys.readouterr().err
    assert "other settings" in err and "'size': (16, 24)" in err and "the mask is" not in err, err
    assert not out.exists()


def test_summary_names_the_bad_line_and_keeps_the_last_record_of_a_step(train, tmp_path, capsys):
    def rec(step, db):
        return json.dumps({"step": step, "elapsed_s": 6.0 * step, "lr": 1e-3, "train_l1": 0.5, "val_psnr_db": {"a": db},
                           "val_mean_db": db})
    lines = [json.dumps({"event": "start", "step": 0}), rec(0, 10.0), rec(2, 11.0), json.dumps({"event": "resume", "step": 2}),
             rec(2, 12.0), rec(4, 13.0)]
    log = tmp_path / V1["log"]
    log.write_text("\n".join(lines) + '\n{"step": 6, "elap')  # a last line cut short
    capsys.readouterr()
    assert train.main(["--system", "sp", "--out", str(tmp_path), "--summary", "2"]) == 0
    cap = capsys.readouterr()
    rows = [r.split("|") for r in cap.out.splitlines()[2:]]
    assert [(r[1].strip(), r[5].strip()) for r in rows] == [("0", "10.00"), ("2", "12.00"), ("4", "13.00")]
    assert "line 7 is cut short" in cap.err
    log.write_text("\n".join(lines[:2] + ["{not json"] + lines[2:]) + "\n")
    assert train.main(["--system", "sp", "--out", str(tmp_path), "--summary", "2"]) == 1
    assert "line 3: not JSON" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ findings 3, 4

def _mf(bands_nm=None):
    op = diffcassi.exact(diffcassi.System.preset("sp"), 16, 16, rays=1, planes=4, seed=1,
                         **({} if bands_nm is None else {"bands_nm": bands_nm}))
    return dt.CassiOperator.from_operator(op, matrix_free=True)


def test_load_unrolled_checks_the_band_wavelengths():
    other = [float(b) for b in np.linspace(380, 720, 28)]
    with pytest.raises(diffcassi.DiffcassiValueError, match="band 0 is 450 nm, the operator's is 380 nm .*other wavelengths"):
        load_unrolled(WEIGHTS_V1, _mf(other), system="sp")
    op = diffcassi.exact(diffcassi.System.preset("sp"), 16, 16, rays=1, planes=4, seed=1, bands_nm=other)
    assert dt.CassiOperator.from_operator(op).bands_nm == pytest.approx(other)
    with pytest.raises(diffcassi.DiffcassiValueError, match="other wavelengths"):
        load_unrolled(WEIGHTS_V1, dt.CassiOperator.from_operator(op), system="sp")
    assert isinstance(load_unrolled(WEIGHTS_V1, _mf(), system="sp"), UnrolledGAP)  # the default bands: 450–650


def test_load_unrolled_warns_about_a_system_of_a_preset_name_with_another_prescription(recwarn):
    spec = json.loads(diffcassi.System.preset("sp").to_json())
    spec["surfaces"][1]["thickness_mm"] += 0.5
    edited = diffcassi.System.from_string(json.dumps(spec), format="json")
    assert edited.name == "sp"
    assert "system_sha256" not in read_metadata(WEIGHTS_V1)
    with pytest.warns(UserWarning, match="system_sha256 not recorded.*not the preset 'sp'"):
        load_unrolled(WEIGHTS_V1, _mf(), system=edited)
    recwarn.clear()
    load_unrolled(WEIGHTS_V1, _mf(), system=diffcassi.System.preset("sp"))  # the preset itself: no warning
    # (but the operator's own: its 4 planes leave 24 of the 28 bands unsampled, said since round 17)
    assert not [w for w in recwarn if issubclass(w.category, UserWarning) and "seen by no detector pixel" not in str(w.message)]


# --------------------------------------------------------------------------------------------- findings 5, 11

def test_renderer_state_records_its_parameters_and_system():
    sp = diffcassi.System.preset("sp")
    r1 = dt.CassiRenderer(sp, 8, 8, free=["prism_tilt_x"], rays=1, planes=4)
    with torch.no_grad():
        r1.theta += 0.3
    state = r1.state_dict()
    r2 = dt.CassiRenderer(sp, 8, 8, free=["prism_tilt_y"], rays=1, planes=4)
    theta2 = r2.theta.detach().clone()
    with pytest.raises(diffcassi.DiffcassiValueError, match=r"free parameters \['s4.tilt_x_deg'\].*\['s4.tilt_y_deg'\]"):
        r2.load_state_dict(state)
    assert torch.equal(r2.theta.detach(), theta2)
    r3 = dt.CassiRenderer(diffcassi.System.preset("msp"), 8, 8, free=["prism_tilt_x"], rays=1, planes=4)
    with pytest.raises(diffcassi.DiffcassiValueError, match="system 'msp' is another"):
        r3.load_state_dict(state)
    r4 = dt.CassiRenderer(sp, 8, 8, free=["prism_tilt_x"], rays=1, planes=4)
    r4.load_state_dict(state)
    assert torch.equal(r4.theta.detach(), r1.theta.detach())
    old = dict(state, _extra_state={"temperature": 0.5})  # a state from before round 9
    r2.load_state_dict(old)
    assert r2.temperature == 0.5


def test_renderer_takes_negative_and_conjugate_views():
    r = dt.CassiRenderer(diffcassi.System.preset("sp"), 8, 8, free=["prism_tilt_x"], rays=1, planes=4)
    x = torch.rand(1, 28, 8, 8, dtype=torch.float64)
    with torch.no_grad():
        want = r(x)
        assert torch.equal(r(torch._neg_view(-x)), want)
        z = torch.complex(torch.zeros_like(x), x)
        assert torch.equal(r(z.conj().imag), -r(x))


# --------------------------------------------------------------------------------------------------- finding 13

def test_messages_and_save_unrolled_files(tmp_path):
    T = diffcassi.Transport(diffcassi.System.preset("sp"), 8, 8, bands_nm=[500, 540, 580], planes=6, rays=1)
    net = UnrolledGAP(dt.CassiOperator.from_operator(T.operator, matrix_free=True), stages=1, width=4)
    with pytest.raises(TypeError, match="got Tensor of dtype torch.int64"):
        net(torch.ones(1, *net.phi.image_shape, dtype=torch.int64))
    path = tmp_path / "w.safetensors"
    for bad, msg in (([1, 2], "has 2 wavelengths, the network 3 bands"), ([500, 580, 540], "increasing"),
                     ("[500, 540, nan]", "not a JSON list|finite")):
        with pytest.raises(diffcassi.DiffcassiValueError, match=msg):
            save_unrolled(net, path, {"system": "sp", "bands_nm": bad})
        assert not path.exists()
    path.write_text("old")
    os.chmod(path, 0o644)
    save_unrolled(net, path, {"system": "sp", "bands_nm": [500, 540, 580]})
    um = os.umask(0o022)
    os.umask(um)
    assert path.stat().st_mode & 0o777 == 0o666 & ~um
    # A bytes path is a path (it was "not a valid safetensors file"); an int is a TypeError naming the path.
    assert isinstance(load_unrolled(os.fsencode(str(path)), net.phi, system="sp"), UnrolledGAP)
    with pytest.raises(TypeError, match="path: expected a str, bytes or os.PathLike, got int"):
        load_unrolled(3, net.phi)


@pytest.mark.parametrize("device, err, msg", [(0, TypeError, '"cpu-twin" or None, got int 0'),
                                              (" cpu", diffcassi.DiffcassiValueError, "no spaces"),
                                              ("cuda ", diffcassi.DiffcassiValueError, "no spaces")])
def test_render_device_keyword(device, err, msg):
    cube = np.ones((8, 8, 3), np.float32)
    with pytest.raises(err, match=msg):
        diffcassi.render(diffcassi.System.preset("sp"), cube, [500, 550, 600], bands_nm=[500, 550, 600], planes=3, rays=1,
                         device=device)
