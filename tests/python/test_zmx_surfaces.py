"""Public .zmx files with mirrors, a toroidal (cylindrical) lens and a diffraction grating against an independent
reader, rayoptics (issue 42; docs/zemax-files.md "Mirrors, toroids, gratings").

Fixtures (tests/fixtures/zmx, README there: sources, commits, licences), opened by rayoptics as they are:
* cassegrain_mirrors_HoO_V2C18Ex03.zmx: a Cassegrain (paraboloid primary, hyperboloid secondary, GLAS MIRROR,
  negative thickness between them) — rayoptics' test model;
* fold_mirrors_optiland.zmx: two flat 45° fold mirrors built with Coordinate Breaks (optiland's test model);
* cylinder_thorlabs_LJ1598L1.zmx: Thorlabs LJ1598L1 plano-convex cylindrical lens (TYPE TOROIDAL, radius of
  rotation 0 = a cylinder), as optiland redistributes it;
* grating_flat_transmission_optiland.zmx: an N-BK7 plate whose back is a DGRATING (0.2 lines/µm, order −1).

Conventions, and how they are reconciled (both readers get the same copy): the files put their objects at
infinity (being implemented separately), so each is compared with its object at 1000 mm, field angles as
heights 1000·tan θ and F/# as an entrance pupil diameter — the copy test_zmx.py makes; glasses use rayoptics'
SCHOTT coefficients (an AGF file for diffcassi). OpticStudio's parameter pickups (PPAR) in the fold-mirror
file repeat values the file already holds; diffcassi skips them (listed) and both readers trace the values.
The grating: rayoptics' DiffractionGrating (Ludwig's vector grating equation, oprops/doe.py) with the
order's sign as diffcassi's (n₂d′_t = n₁d_t − mλT K). A real-ray grid (3 object points × 5 × 5 directions)
lands on the image surface at the same points to 1e-6 relative; for the mirror and lens systems, EFL and BFL
agree too (the flat grating plate has no power: its EFL is infinite, not compared).
"""
import math
import pathlib
import re
import subprocess

import numpy as np
import pytest

import diffcassi

rayoptics = pytest.importorskip("rayoptics", reason="rayoptics (scripts/setup.sh installs it) is the independent reader")
from rayoptics.raytr.raytrace import trace as ro_trace  # noqa: E402
from rayoptics.zemax import zmxread  # noqa: E402
from opticalglass import glassfactory  # noqa: E402
# The file decoding and rayoptics' sequential-model reader of test_zmx.py (its element model, used for drawing,
# has no grammar for fold-mirror layouts built from Coordinate Breaks either).
from test_zmx import decode, ro_open  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "tests" / "fixtures" / "zmx"
OBJECT_MM = 1000.0
# Keywords diffcassi skips in these copies and why that does not change where the explicit rays land.
SKIPPABLE = {
    "VDXN", "VDYN", "VCXN", "VCYN", "VANN",  # vignetting factors: pupil sampling only
    "PPAR",  # parameter pickups whose values the file holds (checked below)
    "HYPR", "SSID", "LUID", "EERA", "AUTH", "IWDP", "NOTE", "REAX",  # bookkeeping, display, merit operands
}


def finite_copy(path, out_dir):
    lines = decode(path).splitlines()
    out, in_obj = [], False
    for line in lines:
        key = line.strip().split(" ", 1)[0]
        if key == "SURF":
            in_obj = line.split()[1] == "0"
        if in_obj and key == "DISZ":
            line = f"  DISZ {OBJECT_MM}"
        elif key == "FTYP":
            parts = line.split()
            assert parts[1] == "0", "the fixtures give field angles"
            parts[1] = "1"
            line = " ".join(parts)
        elif key in ("XFLN", "YFLN"):
            vals = [OBJECT_MM * math.tan(math.radians(float(v))) for v in line.split()[1:]]
            line = key + " " + " ".join(repr(v) for v in vals)
        elif key == "FNUM":
            line = "ENPD 10"
        out.append(line)
    text = "\n".join(out) + "\n"
    glasses = sorted({m.group(1) for m in re.finditer(r"^\s*GLAS (\S+)", text, re.M)} - {"MIRROR"})
    if glasses:
        text = re.sub(r"^GCAT .*$", "GCAT SCHOTT ROSCHOTT", text, flags=re.M)
    agf = []
    for g in glasses:
        glass = glassfactory.create_glass(g, "Schott")
        b1, b2, b3, c1, c2, c3 = (float(c) for c in glass.coefs[:6])
        agf.append(f"NM {g} 2 0 {glass.calc_rindex(587.5618):.6f} 50 0 0\nCD {b1!r} {c1!r} {b2!r} {c2!r} {b3!r} {c3!r}\nLD 0.3 2.5\n")
    if agf:
        (out_dir / "ROSCHOTT.AGF").write_text("".join(agf))
    copy = out_dir / path.name
    copy.write_text(text)
    return copy


def ro_read(path, first_order):
    if first_order:
        return zmxread.read_lens_file(path)[0]
    return ro_open(path)


CASES = [
    ("cassegrain_mirrors_HoO_V2C18Ex03.zmx", True),
    ("fold_mirrors_optiland.zmx", False),
    ("cylinder_thorlabs_LJ1598L1.zmx", True),
    ("grating_flat_transmission_optiland.zmx", False),
]


@pytest.mark.parametrize("design,first_order", CASES)
def test_mirror_toroid_grating_designs_agree_with_rayoptics(cli, tmp_path, design, first_order):
    ro_read(FIXTURES / design, first_order)  # rayoptics opens the original file as it is
    copy = finite_copy(FIXTURES / design, tmp_path)
    toml = tmp_path / "design.toml"
    done = subprocess.run([cli, "import-zmx", str(copy), "--out", str(toml), "--glass-dir", str(tmp_path), "--ignore-unsupported"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    for line in done.stderr.splitlines()[1:]:
        m = re.search(r"`(\w+)`", line)
        assert m and m.group(1) in SKIPPABLE, line
    ours = diffcassi.System.from_file(toml)
    om = ro_read(copy, first_order)
    sm = om["seq_model"]
    assert len(sm.ifcs) == len(ours.surfaces)
    wl = ours.primary_wavelength_nm
    sd = next(s.get("semi_diameter_mm") for s in ours.surfaces[1:] if s.get("semi_diameter_mm"))
    hmax = max(max(abs(f[0]), abs(f[1])) for f in ours.fields_mm)
    origins, dirs = [], []
    for h in [0.0, 0.5 * hmax, hmax]:
        for ax in np.linspace(-0.3, 0.3, 5):
            for ay in np.linspace(-0.3, 0.3, 5):
                d = np.array([ax * sd, ay * sd - h, OBJECT_MM])
                origins.append([0.0, h, 0.0])
                dirs.append(d / np.linalg.norm(d))
    origins, dirs = np.array(origins), np.array(dirs)
    got = diffcassi.trace(ours, origins, dirs, np.full(len(origins), wl))
    assert (got["status"] == 0).all(), got["status"]
    scale = max(1.0, float(np.abs(got["positions"][:, :2]).max()))
    worst = 0.0
    for k in range(len(origins)):
        ray, _, _ = ro_trace(sm, origins[k], dirs[k], wl)
        x, y = ray[-1][0][0], ray[-1][0][1]
        worst = max(worst, abs(got["positions"][k, 0] - x), abs(got["positions"][k, 1] - y))
        assert abs(got["positions"][k, 0] - x) <= 1e-6 * scale, (k, got["positions"][k], (x, y))
        assert abs(got["positions"][k, 1] - y) <= 1e-6 * scale, (k, got["positions"][k], (x, y))
    print(f"{design}: {len(origins)} rays, worst landing difference {worst:.2e} mm (scale {scale:.3g} mm)")
    if first_order:
        fod = om["analysis_results"]["parax_data"].fod
        h, wl = 1e-4, ours.primary_wavelength_nm
        got = diffcassi.trace(ours, np.array([[0.0, h, 0.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([wl]))
        p, d = got["positions"][0], got["directions"][0]
        u = d[1] / d[2]
        efl = -h / u
        thickness = [c["value"] if isinstance(c, dict) else c for c in (s["thickness_mm"] for s in ours.surfaces)]
        bfl = -p[1] / u + thickness[-2]
        print(f"{design}: EFL {efl:.9g} (rayoptics {fod.efl:.9g}), BFL {bfl:.9g} (rayoptics {fod.bfl:.9g})")
        assert efl == pytest.approx(fod.efl, rel=1e-6)
        assert bfl == pytest.approx(fod.bfl, rel=1e-6)


def test_pickups_skipped_in_the_fold_file_repeat_its_values():
    text = decode(FIXTURES / "fold_mirrors_optiland.zmx")
    blocks = re.split(r"^SURF (\d+)", text, flags=re.M)
    parm = {}
    for num, body in zip(blocks[1::2], blocks[2::2]):
        for m in re.finditer(r"PARM (\d+) (\S+)", body):
            parm[(int(num), int(m.group(1)))] = float(m.group(2))
    for num, body in zip(blocks[1::2], blocks[2::2]):
        for m in re.finditer(r"PPAR (\d+) (\d+) (\S+) (\S+)", body):
            i, src, scale, off = int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4))
            assert parm[(int(num), i)] == scale * parm[(src, i)] + off
