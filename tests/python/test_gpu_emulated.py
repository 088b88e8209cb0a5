"""The GPU check's real path (not its dry run) against the CUDA driver emulator of tests/cuda_emu: a
`libcuda.so.1` that runs the device build's entry points on the host (tests/gpu_launcher.rs runs the CLI against
it). `scripts/gpu/render_check.py` without `--dry-run` — the code a lent GPU machine runs, which the dry run
replaces by the twin — goes through the launcher, the device's landings and mapping, and its comparisons, at tiny
sizes; and `diffcassi.render(..., device="cuda")` returns the host twin's bits. Each runs in a child process
whose library path puts the emulator first. No figure here is a GPU's (the device name says emulator)."""
import json
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def emulator(tmp_path_factory):
    out = tmp_path_factory.mktemp("cuda-emu")
    r = subprocess.run(["bash", str(ROOT / "tests/cuda_emu/build.sh"), str(out)], capture_output=True, text=True)
    assert r.returncode == 0, f"building the CUDA emulator failed:\n{r.stderr}"
    return out


def _env(emulator):
    env = {k: v for k, v in os.environ.items() if not k.startswith("CUDA_EMU_") and k not in ("DIFFCASSI_PTX", "DIFFCASSI_CUDA_DRIVER")}
    env["LD_LIBRARY_PATH"] = str(emulator)
    env["PYTHONPATH"] = str(ROOT)
    return env


@pytest.mark.parametrize("systems", [False, True], ids=["bench", "systems"])
def test_render_check_script_on_an_emulated_device(tmp_path, emulator, systems):
    args = [sys.executable, str(ROOT / "scripts/gpu/render_check.py"), "--size", "12", "--planes", "2", "--rays", "2", "--out", str(tmp_path)]
    if systems:
        args.append("--systems")
    r = subprocess.run(args, capture_output=True, text=True, env=_env(emulator), cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "emulator" in r.stdout and "DRY RUN" not in r.stdout, r.stdout
    rec = json.loads((tmp_path / ("render_systems_check.json" if systems else "render_check.json")).read_text())
    rows = [v for v in rec.values() if isinstance(v, dict) and "runs_bit_identical" in v] if systems else [rec]
    assert len(rows) == (6 if systems else 1) and rec["dry_run"] is False and rec["failed"] == [], rec.get("failed")
    for row in rows:
        assert row.get("runs_bit_identical") is True, row
        assert row.get("landing_rays", 0) > 0 and row.get("landing_status_mismatches") == 0, row
        # The emulator runs the device branch of the same source on the host: the twin's bits, even at infinity.
        assert row.get("twin_bit_identical") is True and row.get("twin_max_rel_diff") == 0.0, row
    if not systems:
        assert "emulator" in rec["gpu"] and rec["ptx"] == "embedded PTX", rec
        assert set(rec["mapping"]) == {"f64", "f32"} and all(m["bit_identical"] for m in rec["mapping"].values()), rec["mapping"]


def test_render_on_an_emulated_device_equals_the_twin(tmp_path, emulator):
    code = """
import json, numpy as np, diffcassi
cube, wl = diffcassi.synthetic_scene(12, 12, seed=3)
s = diffcassi.System.preset("msp")
a, rec = diffcassi.render(s, cube, wl, planes=3, rays=2, device="cuda")
b, _ = diffcassi.render(s, cube, wl, planes=3, rays=2, device="cpu-twin")
print(json.dumps({"same": bool(np.array_equal(a, b)), "peak": float(np.max(a)), "device": rec["device"]}))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(emulator), cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["same"] and out["peak"] > 0, out
    assert out["device"]["device"] == "cuda" and "emulator" in out["device"]["gpu"], out["device"]
