"""Shared fixtures of the Python tests: the presets, a small render configuration, and the CLI binary
(built by cargo into the repository's target/; `cargo build --release --bin diffcassi` is a no-op when fresh)."""
import importlib.util
import os
import pathlib
import subprocess

import numpy as np
import pytest

import diffcassi

ROOT = pathlib.Path(__file__).resolve().parents[2]
PRESETS = ["sp", "ap", "msp", "map"]
#: Small render settings (the suite stays fast).
SMALL = dict(bands_nm=[480.0, 520.0, 560.0, 600.0], planes=8, rays=4)


@pytest.fixture(scope="session")
def cli():
    exe = ROOT / "target" / "release" / "diffcassi"
    subprocess.run(["cargo", "build", "--release", "--quiet", "--bin", "diffcassi"], cwd=ROOT, check=True)
    assert exe.is_file(), exe
    return str(exe)


@pytest.fixture(scope="session", params=PRESETS)
def system(request):
    return diffcassi.System.preset(request.param)


def random_cube(h, w, b, seed=0):
    return np.random.default_rng(seed).random((h, w, b), dtype=np.float32)


def load_script(name):
    """The module of ``scripts/NAME.py`` (the training and evaluation scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
