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
    (dict(synthetic=1, planes="many"), "planes: expected an integer in 1..=18446744073709551615"),
    (dict(synthetic=1, solvers="gap-tv,"), "empty entry"),
    (dict(synthetic=1, noise_estimate="guess"), "noise_estimate `guess`"),
    (dict(synthetic=1, operators=[1, 2]), "operators `1,2`: entry `1`: use exact"),
    (dict(synthetic=1, bands=[450.0, 2000.0], presets="sp", scene_size=12, rays=1), "render plane 0"),
])
def test_bad_settings_are_refused_before_anything_is_written(tmp_path, settings, needle):
    out = tmp_path / "study"
    with pytest.raises(diffcassi.DiffcassiError) as e:
        diffcassi.study(str(out), **settings)
    assert needle in str(e.value), str(e.value)
    assert not out.exists()


def test_keywords_read_as_the_command_reads_its_options(tmp_path):
    """A comma string of `systems` is split as `--systems a,b` is; `None` is the default; bools are not
    integers; bytes are not lists; `accelerated=False, plain=False` is the default, not a conflict (a held-out
    battery, round 8)."""
    import numpy as np
    spec = diffcassi.System.preset("sp").to_toml()
    for name in ("a", "b"):
        (tmp_path / f"{name}.toml").write_text(spec)
    small = dict(synthetic=1, scene_size=12, operators="shift", bands="480:600:4", planes=4, rays=1, iterations=2)
    done = diffcassi.study(str(tmp_path / "files"), systems=f"{tmp_path / 'a.toml'},{tmp_path / 'b.toml'}", **small)
    assert done["computed"] == 2, done
    done = diffcassi.study(str(tmp_path / "none"), presets="sp", mask=None, tv_weight=None, accelerated=False, plain=False, **small)
    assert done["computed"] == 1, done
    for bad, needle in [(dict(planes=True), "planes: expected an integer in 1..="), (dict(rays=False), "rays: expected an integer in 1..="),
                        (dict(presets=b"sp"), "not bytes"), (dict(accelerated=True, plain=True), "give one")]:
        out = tmp_path / "bad"
        with pytest.raises(diffcassi.DiffcassiValueError, match=needle):
            diffcassi.study(str(out), **{**small, **bad})
        assert not out.exists()
    # The render keywords refuse bools for integers too (`planes=True` rendered one plane).
    sp = diffcassi.System.preset("sp")
    for kw in [dict(planes=True), dict(rays=True), dict(seed=False), dict(noise={"noise": "adc", "adc_bits": True})]:
        with pytest.raises(diffcassi.DiffcassiValueError, match="expected an integer"):
            diffcassi.render(sp, np.ones((8, 8, 4), np.float32), [480.0, 520.0, 560.0, 600.0], **kw)


def test_ctrl_c_stops_a_study_between_cells_and_it_resumes(tmp_path):
    """Ctrl-C (SIGINT) raises KeyboardInterrupt at the next cell, not after the whole study; the finished
    cells are kept and a second call computes only the rest (a held-out battery, round 8)."""
    import signal
    import threading
    import time
    # 18 cells of ≈ 0.25 s each on 2 cores (600 iterations at 16²).
    settings = dict(synthetic=3, scene_size=16, presets="sp", operators="exact,mapping,shift", solvers="gap-tv,admm-tv",
                    planes=8, bands="480:600:4", rays=2, iterations=600)
    out = str(tmp_path / "s")
    cells = lambda: sum(len(files) for _, _, files in os.walk(os.path.join(out, "cells")))
    # Ctrl-C once the first cell is on disk, not after a fixed delay: a timer of 0.2 s fired after the whole
    # study on a CI run (kept = 18), which tested nothing about stopping between cells.
    # (Never once the call has returned: a study that failed before its first cell must not interrupt pytest.)
    sent, returned = [], threading.Event()

    def press_ctrl_c():
        while cells() == 0 and not returned.wait(0.002):
            pass
        if not returned.is_set():
            sent.append(cells())
            os.kill(os.getpid(), signal.SIGINT)

    watcher = threading.Thread(target=press_ctrl_c)
    # Python's own Ctrl-C handler, whatever the suite was started under: a shell without job control starts a
    # background command (`cmd &`) with SIGINT ignored, and Python then keeps it ignored — the signal raised
    # nothing and the study ran to its end (a suite run from a background script, round 21).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    t = time.time()
    watcher.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            diffcassi.study(out, **settings)
    finally:
        returned.set()
        watcher.join()
        signal.signal(signal.SIGINT, previous)
    assert sent, "the study wrote no cell"
    kept = cells()
    done = diffcassi.study(out, **settings)
    assert done["skipped"] == kept and done["computed"] == 18 - kept, (kept, done, time.time() - t)
    # Stopped at a cell boundary soon after the signal (the 50 ms poll plus the cell then running), not at the end.
    assert 1 <= sent[0] <= kept < 18, (sent, kept, time.time() - t)
