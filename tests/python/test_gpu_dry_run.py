"""The GPU check's dry run (docs/gpu.md, "The dry run"): `diffcassi.gpu_check(..., dry_run=True)` and
`scripts/gpu/render_check.py --dry-run` on a machine without a GPU, the host twin standing in for the device, so
that the check a lent GPU machine runs is known to work before it runs there."""
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
import diffcassi  # noqa: E402


def test_the_dry_run_reports_the_twin_as_the_device():
    cube, wl = diffcassi.synthetic_scene(12, 12, seed=0)
    r = diffcassi.gpu_check(diffcassi.System.preset("sp"), cube, wl, dry_run=True, planes=4, rays=2, opening=0.5)
    assert r["dry_run"] is True and r["gpu"].startswith("none (dry run")
    # The twin against itself bit for bit, and the plan's own landings against plane_landings_of's launch.
    assert r["runs_bit_identical"] and r["twin_bit_identical"] and r["twin_max_rel_diff"] == 0.0
    assert r["landing_rays"] > 0 and r["landing_status_mismatches"] == 0 and r["landing_max_diff_mm"] == 0.0
    assert 0.0 <= r["cpu_max_rel_diff"] <= 2e-6
    assert r["gpu_kernels_ms"] is None and r["gpu_total_ms"] > 0
    # Without dry_run the check still needs a device (this machine has none).
    with pytest.raises(diffcassi.DiffcassiValueError, match="no CUDA device"):
        diffcassi.gpu_check(diffcassi.System.preset("sp"), cube, wl, planes=4, rays=2)


def test_the_dry_run_weights_the_landings_of_a_mask_surface():
    cube, wl = diffcassi.synthetic_scene(12, 12, seed=1)
    r = diffcassi.gpu_check(diffcassi.System.preset("ddsp"), cube, wl, dry_run=True, planes=4, rays=2, opening=0.5)
    assert r["dry_run"] and r["landing_status_mismatches"] == 0 and r["landing_max_diff_mm"] == 0.0
    assert r["twin_bit_identical"] and 0.0 <= r["cpu_max_rel_diff"] <= 2e-6


@pytest.mark.parametrize("systems", [False, True], ids=["bench", "systems"])
def test_render_check_script_dry_run(tmp_path, systems):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    args = [sys.executable, str(ROOT / "scripts" / "gpu" / "render_check.py"), "--dry-run", "--size", "12", "--planes", "4",
            "--rays", "2", "--out", str(tmp_path)] + (["--systems"] if systems else [])
    p = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "DRY RUN" in p.stdout and "FAILED" not in p.stdout + p.stderr
    rec = json.loads((tmp_path / ("render_systems_check.json" if systems else "render_check.json")).read_text())
    assert rec["dry_run"] is True and rec["failed"] == []
    if systems:
        names = [k for k in rec if isinstance(rec[k], dict)]
        assert len(names) == 6 and all(rec[k]["dry_run"] for k in names)
    else:
        assert set(rec["mapping"]) == {"f64", "f32"} and all(m["bit_identical"] for m in rec["mapping"].values())
        assert np.isfinite(rec["cpu_seconds"])
