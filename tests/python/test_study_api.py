"""``diffcassi.study``: the library's study pipeline from Python, the same as ``diffcassi study`` (one
pipeline, ``src/study``; the CLI and the bindings only convert their arguments)."""
import csv
import json
import os
import subprocess

import pytest

import diffcassi

TINY = dict(synthetic=2, scene_size=12, presets="sp", operators=["shift", "exact"], bands="480:600:4", planes=8, rays=2,
            iterations=4, seed=3)
TINY_CLI = ["--synthetic", "2", "--scene-size", "12", "--presets", "sp", "--operators", "shift,exact", "--bands", "480:600:4",
            "--planes", "8", "--rays", "2", "--iterations", "4", "--seed", "3"]


def rows(folder):
    with open(os.path.join(folder, "study.csv"), newline="") as f:
        # Everything but the timings (they differ from run to run).
        return [{k: v for k, v in r.items() if not k.startswith("seconds")} for r in csv.DictReader(f)]


def test_study_from_python_equals_the_command_and_resumes(tmp_path, cli):
    py_out, cli_out = str(tmp_path / "py"), str(tmp_path / "cli")
    done = diffcassi.study(py_out, **TINY)
    assert done["computed"] == 4 and done["skipped"] == 0, done
    assert done["table"] == os.path.join(py_out, "study.md") and os.path.isfile(done["table"])
    for f in ["study.json", "mask.png", "study.csv", "study_psnr.png", "renders/sp/synthetic00/render.json",
              "recon/sp/synthetic01/exact-gap-tv/cube.npy", "cells/sp/synthetic01/shift-gap-tv.json"]:
        assert os.path.isfile(os.path.join(py_out, f)), f
    subprocess.run([cli, "study", *TINY_CLI, "--out", cli_out], check=True, capture_output=True)
    # The same cells, bit for bit (the CSV writes the shortest round-trip form of each number).
    assert rows(py_out) == rows(cli_out)
    a = json.load(open(os.path.join(py_out, "study.json")))["configuration"]
    b = json.load(open(os.path.join(cli_out, "study.json")))["configuration"]
    assert a == b
    # A second call with the same settings reuses every cell; another TV weight recomputes them.
    again = diffcassi.study(py_out, **TINY)
    assert (again["computed"], again["skipped"]) == (0, 4), again
    other = diffcassi.study(py_out, **{**TINY, "tv_weight": 0.5})
    assert (other["computed"], other["skipped"]) == (4, 0), other


@pytest.mark.parametrize("settings, needle", [
    (dict(bogus=1), "unknown setting `bogus`"),
    (dict(mask="m.npy", opening=0.3), "give one"),
    (dict(scenes="x", synthetic=1), "give one"),
    (dict(synthetic=1, fit="crop"), "`fit` applies"),
    (dict(synthetic=1, planes="many"), "`planes` must be a whole number"),
    (dict(synthetic=1, solvers="gap-tv,"), "empty entry"),
    (dict(synthetic=1, noise_estimate="guess"), "noise_estimate `guess`"),
    (dict(synthetic=1, operators=[1, 2]), "--operators `1,2`: entry `1`: use exact"),
    (dict(synthetic=1, bands=[450.0, 2000.0], presets="sp", scene_size=8, rays=1), "render plane 0"),
])
def test_bad_settings_are_refused_before_anything_is_written(tmp_path, settings, needle):
    out = tmp_path / "study"
    with pytest.raises(diffcassi.DiffcassiError) as e:
        diffcassi.study(str(out), **settings)
    assert needle in str(e.value), str(e.value)
    assert not out.exists()
