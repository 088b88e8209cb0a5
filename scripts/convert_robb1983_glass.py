#!/usr/bin/env python3
"""Convert the SCHOTT rows of Robb & Mercado's 1983 Buchdahl fits into diffcassi's built-in legacy catalogue
`data/glass/SCHOTT1980.buchdahl` (embedded by `src/materials/builtin_catalogs.rs`).

Source: P. N. Robb and R. I. Mercado, "Calculation of refractive indices using Buchdahl's chromatic
coordinate", Applied Optics 22(8), 1198–1215 (1983), Table V: for every glass of the 1980 catalogues of
SCHOTT, OHARA, HOYA, Corning-France and Chance, the quadratic model n = n0 + ν1 ω + ν2 ω² in Buchdahl's
chromatic coordinate ω = (λ − λ0)/(1 + 2.5 (λ − λ0)) fitted over the visible region, with the fit's standard
deviation, its largest error and where that error falls. The table as text is the file
`opticalglass/data/robb1983_data_final.txt` of the opticalglass package (M. J. Hayford, BSD 3-Clause; installed
by scripts/setup.sh with rayoptics), read here from the installed package: nothing is downloaded.

Base wavelength. The rows are about λ0 = 0.574 µm, not the d line: about 0.574 µm they reproduce the current
SCHOTT glasses of the same composition (same name, or the `N-` successor) to a median 5.9e-5 at every nm of 400–700 nm,
about 0.5876 µm (where opticalglass's own Robb1983 class evaluates them) to a median 3.3e-3 — BK7's n_d comes out
1.517385 instead of 1.51680. `tests` in src/materials/builtin_catalogs.rs checks this on the converted rows.

Which rows are kept. The table was transcribed from a scanned paper, and some rows are scrambled (the SF5x
block: SCHOTT SF57's n0 1.763801 against its catalogue n_d 1.84666). So a row is kept only if it can be checked:
the current SCHOTT glass of the same name, else its successor (`N-NAME`, or `N-` with the old `N` infix dropped:
LAKN22 → N-LAK22), taken from diffcassi's built-in data/glass/SCHOTT.agf (the refractiveindex.info database, CC0),
must agree with the row to within TOLERANCE at every one of the 301 wavelengths 400, 401, …, 700 nm. The rows kept
agree to 6e-6 … 5e-4 (the larger ones: glasses reformulated lead- and arsenic-free); the rows refused are off by
2e-2 or more; a row whose glass has no current glass to check against is left out. The script prints both lists.

Output records (diffcassi's own format, like data/glass/SCHOTT.tabulated): `CC` comments (source, licence,
conventions), then per glass `NM name status` (2: obsolete), `GC` its source row and check, `BD λ0 n0 ν1 ν2`
(λ0 in µm; n0, ν1, ν2 copied as the source prints them, so Rust's float parser reads the f64 they denote),
`LD λmin λmax` (µm).

Usage (from the repository root, with the project's venv):

    .venv/bin/python scripts/convert_robb1983_glass.py [--write]

Without --write it prints the file and the report; with --write it writes data/glass/SCHOTT1980.buchdahl.
"""
import argparse
import math
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "glass" / "SCHOTT1980.buchdahl"
BASE_UM = "0.574"
RANGE_UM = ("0.400", "0.700")
TOLERANCE = 1e-3
CHECK_NM = range(400, 701)


def robb_rows(path):
    """SCHOTT rows of Table V as (name, n0, nu1, nu2, std, max_err, wvl) text fields."""
    rows, section = [], None
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            if "GLASS CATALOGUE" in line:
                section = line[1:].split()[0]
            continue
        t = line.split()
        if section == "SCHOTT" and len(t) == 7:
            rows.append(t)
    return rows


def schott_agf(path):
    """Current SCHOTT glasses: name -> (Sellmeier 1 coefficients, GC comment)."""
    glasses, name = {}, None
    for line in path.read_text().splitlines():
        t = line.split()
        if not t:
            continue
        if t[0] == "NM":
            name, formula = t[1], t[2]
        elif t[0] == "GC" and name:
            glasses.setdefault(name, [None, " ".join(t[1:])])[1] = " ".join(t[1:])
        elif t[0] == "CD" and name:
            if formula != "2":
                sys.exit(f"SCHOTT.agf glass {name}: formula {formula}, this script evaluates Sellmeier 1 (2) only")
            glasses.setdefault(name, [None, ""])[0] = [float(v) for v in t[1:7]]
    return glasses


def sellmeier1(c, um):
    l2 = um * um
    return math.sqrt(1.0 + sum(c[i] * l2 / (l2 - c[i + 1]) for i in (0, 2, 4)))


def buchdahl(n0, nu1, nu2, um, base=float(BASE_UM)):
    d = um - base
    o = d / (1.0 + 2.5 * d)
    return n0 + nu1 * o + nu2 * o * o


def successors(name):
    yield name
    yield "N-" + name
    # Old names with an `N` infix (the first reformulation): LAKN22 → N-LAK22, BAFN10 → N-BAF10.
    i = len(name.rstrip("0123456789"))
    if i > 1 and name[i - 1] == "N":
        yield "N-" + name[: i - 1] + name[i:]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"write {OUT.relative_to(ROOT)}")
    args = ap.parse_args()
    import opticalglass  # noqa: PLC0415 (installed by scripts/setup.sh)

    src = pathlib.Path(opticalglass.__file__).parent / "data" / "robb1983_data_final.txt"
    current = schott_agf(ROOT / "data" / "glass" / "SCHOTT.agf")
    kept, refused, unchecked = [], [], []
    for name, n0, nu1, nu2, std, err, wvl in robb_rows(src):
        succ = next((s for s in successors(name) if s in current), None)
        if succ is None:
            unchecked.append(name)
            continue
        coef, gc = current[succ]
        dev = max(abs(buchdahl(float(n0), float(nu1), float(nu2), nm / 1000) - sellmeier1(coef, nm / 1000)) for nm in CHECK_NM)
        row = (name, n0, nu1, nu2, std, err, wvl, succ, gc.split(";")[0], dev)
        (kept if dev <= TOLERANCE else refused).append(row)
    lines = [
        "CC SCHOTT optical glasses of the 1980 catalogue, built into diffcassi as the legacy catalogue SCHOTT1980 (see src/materials/builtin_catalogs.rs)",
        "CC Source: P. N. Robb and R. I. Mercado, Calculation of refractive indices using Buchdahl's chromatic coordinate, Applied Optics 22(8), 1198 (1983), Table V (SCHOTT, quadratic model, visible region)",
        f"CC Table text: opticalglass {opticalglass.__version__} data/robb1983_data_final.txt (M. J. Hayford, BSD 3-Clause); converted by scripts/convert_robb1983_glass.py",
        f"CC n = n0 + nu1 w + nu2 w^2, w = (l - l0)/(1 + 2.5 (l - l0)), l in um, l0 = {BASE_UM} um; range {RANGE_UM[0]}-{RANGE_UM[1]} um (the visible region of the fit)",
        f"CC Kept: rows within {TOLERANCE:g} of the current SCHOTT glass of the same name or its N- successor (data/glass/SCHOTT.agf) at every nm of 400-700 nm",
    ]
    for name, n0, nu1, nu2, std, err, wvl, succ, page, dev in kept:
        lines += [
            f"NM {name} 2",
            f"GC Robb & Mercado 1983 Table V, SCHOTT {name} (fit std {float(std):.0e}, max error {float(err):.0e} at {wvl} um); within {dev:.1e} of SCHOTT {succ} ({page}) over 400-700 nm",
            f"BD {BASE_UM} {n0} {nu1} {nu2}",
            f"LD {RANGE_UM[0]} {RANGE_UM[1]}",
        ]
    text = "\n".join(lines) + "\n"
    report = [f"kept {len(kept)} rows: " + ", ".join(f"{r[0]} ({r[9]:.1e} vs {r[7]})" for r in kept)]
    report.append(f"refused {len(refused)} rows (off their current glass by more than {TOLERANCE:g}): " + ", ".join(f"{r[0]} ({r[9]:.1e} vs {r[7]})" for r in refused))
    report.append(f"left out {len(unchecked)} rows (no current SCHOTT glass to check against): " + ", ".join(unchecked))
    if args.write:
        OUT.write_text(text)
        print(f"wrote {OUT.relative_to(ROOT)}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    print("\n".join(report), file=sys.stderr)


if __name__ == "__main__":
    main()
