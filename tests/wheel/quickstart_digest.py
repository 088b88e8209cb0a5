"""Run examples/python/quickstart.py with whichever `diffcassi` this interpreter imports and print, as one JSON
line, where that package lives, whether it has Embree, and the SHA-256 of the quickstart's acquisition and
reconstruction bytes (tests/wheel/run.sh compares the wheel's with the `maturin develop` build's). With
`--embree-refusal` it also checks that asking a build without Embree for an Embree backend raises
DiffcassiValueError naming the missing Embree. Run it from outside the repository: the script's folder, not the
working directory, is on sys.path, so the package imported is the installed one."""
import contextlib
import hashlib
import io
import json
import pathlib
import runpy
import sys

import numpy as np

import diffcassi

ROOT = pathlib.Path(__file__).resolve().parents[2]
with contextlib.redirect_stdout(io.StringIO()) as printed:
    g = runpy.run_path(str(ROOT / "examples/python/quickstart.py"), run_name="__main__")
acq, est = g["acq"], g["est"]
assert isinstance(acq, np.ndarray) and acq.dtype == np.float64 and acq.size > 0 and np.isfinite(acq).all(), acq
assert isinstance(est, np.ndarray) and est.dtype == np.float32 and est.shape == (64, 64, 28), est.shape
out = {"package": str(pathlib.Path(diffcassi.__file__).resolve().parent), "native": str(pathlib.Path(diffcassi._native.__file__).name),
       "embree": bool(diffcassi.EMBREE), "version": diffcassi.__version__,
       "acquisition_sha256": hashlib.sha256(np.ascontiguousarray(acq).tobytes()).hexdigest(),
       "estimate_sha256": hashlib.sha256(np.ascontiguousarray(est).tobytes()).hexdigest(),
       "acquisition_total": float(acq.sum()), "quickstart_output": printed.getvalue().strip().splitlines()}
if "--embree-refusal" in sys.argv:
    if diffcassi.EMBREE:
        sys.exit("quickstart_digest.py: --embree-refusal on a build with Embree")
    try:
        diffcassi.render(g["sp"], g["cube"], g["wl"], rays=1, planes=2, backend="embree-user")
    except diffcassi.DiffcassiValueError as e:
        assert "without Embree" in str(e), e
        out["embree_refusal"] = str(e)
    else:
        sys.exit("quickstart_digest.py: backend='embree-user' did not raise in a build without Embree")
print(json.dumps(out))
