#!/usr/bin/env python3
"""Convert the optical-glass catalogues of the refractiveindex.info database (CC0 1.0) into the built-in
AGF files of diffcassi (`data/glass/<VENDOR>.agf`, embedded by `src/materials/builtin_catalogs.rs`).

Source: https://github.com/polyanskiy/refractiveindex.info-database, folder `database/data/specs/<vendor>/`.
Each glass page (`<vendor>/<group>/<NAME>.yml`) holds the vendor's dispersion formula as it appears in the
vendor's Zemax catalogue, written in refractiveindex.info's own formula numbering:

* refractiveindex.info formula 2 ("Sellmeier-2"): n² − 1 = C1 + Σ Cᵢ λ²/(λ² − Cᵢ₊₁), C1 = 0 → AGF formula 2
  (Sellmeier 1, 3 terms) or 6 (Sellmeier 3, 4 terms); C1 ≠ 0 has no AGF form and is skipped (reported).
* refractiveindex.info formula 3 ("polynomial"): n² = C1 + Σ Cᵢ λ^eᵢ with explicit exponents → the first AGF
  power series whose exponents hold every eᵢ: 1 (Schott: 2, −2, −4, −6, −8), 10 (Extended: + −10, −12),
  12 (Extended 2: + 4, 6), 13 (Extended 3: 2, 4, −2 … −12); the other slots are 0.
* a page with no formula but a `tabulated n` table of at least 2 points (SCHOTT's B270: a datasheet's n at 8
  lines) → a tabulated glass in `data/glass/<VENDOR>.tabulated` (diffcassi's own format, beside the AGF: OpticStudio's
  AGF has no tabulated formula; see `src/materials/builtin_catalogs.rs`): `NM name status`, `GC` as below, and one
  `TN λ(µm) n` line per point, copied as the page prints them. The file is written only for a vendor that has one.
* anything else (one tabulated point, other formulas) is skipped and reported.

Every number is copied as the source prints it (no float formatting), so diffcassi's float parser reads the
same f64 the source text denotes. Per glass the AGF holds: `NM name formula code nd vd 0 status` (nd, vd
and the glass code as printed in the page's PROPERTIES; code 0 when the page has none), `GC` the source page
path and the vendor catalogue it was taken from (the page's REFERENCES link text), `CD` the coefficients and
`LD` the formula's wavelength range (µm). The catalogue's `CC` lines name the database, its commit, date and
licence. Thermal data are not copied (diffcassi evaluates indices at the catalogue reference only).

Usage (nothing is downloaded: point it at a clone or bare git directory of the database):

    python3 scripts/convert_refractiveindex_glass.py --git-dir PATH/TO/refractiveindex.info-database[.git] \
        [--commit HEAD] --out data/glass

Needs PyYAML (present in the project's .venv).
"""
import argparse
import io
import subprocess
import sys
import tarfile

import yaml

# Vendor folder → (catalogue name, groups converted). The catalogue name is the `GCAT` name OpticStudio uses.
VENDORS = [
    ("schott", "SCHOTT", ["optical", "obsolete", "misc"]),
    ("ohara", "OHARA", ["optical"]),
    ("hoya", "HOYA", ["optical"]),
    ("cdgm", "CDGM", ["optical"]),
    ("sumita", "SUMITA", ["optical"]),
    ("hikari", "HIKARI", ["optical"]),
]

# AGF power-series formulas: number → exponents of the slots after the constant, in CD order.
POWER_SERIES = [
    (1, [2, -2, -4, -6, -8]),
    (10, [2, -2, -4, -6, -8, -10, -12]),
    (12, [2, -2, -4, -6, -8, 4, 6]),
    (13, [2, 4, -2, -4, -6, -8, -10, -12]),
]

STATUS = {"standard": 0, "preferred": 1, "obsolete": 2, "special": 3, "melt": 4}


def is_zero(text):
    return float(text) == 0.0


def convert_formula(data):
    """(AGF formula number, [coefficient texts]) or a reason string."""
    kind = data.get("type", "")
    coeffs = data.get("coefficients", "").split()
    if kind == "formula 2":
        if not coeffs or not is_zero(coeffs[0]):
            return f"Sellmeier with a constant term C1 = {coeffs[0] if coeffs else '?'} (no AGF form)"
        terms = coeffs[1:]
        if len(terms) % 2:
            return f"Sellmeier with an odd number of coefficients ({len(coeffs)})"
        n = len(terms) // 2
        if n <= 3:
            return 2, terms + ["0"] * (6 - len(terms))
        if n == 4:
            return 6, terms
        if n == 5:
            return 11, terms
        return f"Sellmeier with {n} terms"
    if kind == "formula 3":
        if len(coeffs) % 2 == 0:
            return f"polynomial with an even number of coefficients ({len(coeffs)})"
        c0, rest = coeffs[0], coeffs[1:]
        pairs = [(rest[i], float(rest[i + 1])) for i in range(0, len(rest), 2)]
        exps = [e for _, e in pairs]
        if len(set(exps)) != len(exps):
            return f"polynomial with a repeated exponent {exps}"
        for number, slots in POWER_SERIES:
            if all(e in slots for e in exps):
                cd = [c0] + ["0"] * len(slots)
                for c, e in pairs:
                    cd[1 + slots.index(e)] = c
                return number, cd
        return f"polynomial exponents {exps} fit no AGF formula"
    return f"`{kind}` has no AGF form"


def reference_text(refs):
    """The link texts of the REFERENCES html (the vendor catalogue the page was taken from)."""
    out, rest = [], refs or ""
    while "<a " in rest:
        rest = rest[rest.index("<a ") :]
        start = rest.index(">") + 1
        end = rest.index("</a>")
        out.append(rest[start:end].strip())
        rest = rest[end + 4 :]
        if "See also" in rest.split("<a ")[0]:
            break
    return out[0] if out else (refs or "").strip()


def git(args, git_dir):
    return subprocess.run(["git", "-C", git_dir] + args, check=True, capture_output=True).stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--git-dir", required=True)
    ap.add_argument("--commit", default="HEAD")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    commit = git(["rev-parse", a.commit], a.git_dir).decode().strip()
    date = git(["log", "-1", "--format=%cs", commit], a.git_dir).decode().strip()
    paths = [f"database/data/specs/{v}/{g}" for v, _, gs in VENDORS for g in gs]
    tar = tarfile.open(fileobj=io.BytesIO(git(["archive", commit] + paths, a.git_dir)))
    members = {m.name: m for m in tar.getmembers() if m.isfile() and m.name.endswith(".yml")}
    total, skipped, tab_total = 0, [], 0
    for vendor, catalog, groups in VENDORS:
        lines = [
            f"CC {catalog} optical glasses built into diffcassi, converted by scripts/convert_refractiveindex_glass.py",
            f"CC from the refractiveindex.info database (https://github.com/polyanskiy/refractiveindex.info-database),",
            f"CC commit {commit} ({date}), public domain (CC0 1.0); the vendor catalogue of each glass is in its GC record",
        ]
        seen = set()
        count = 0
        tabulated = []
        for group in groups:
            prefix = f"database/data/specs/{vendor}/{group}/"
            for name in sorted(n for n in members if n.startswith(prefix)):
                page = yaml.load(tar.extractfile(members[name]).read().decode("utf-8"), Loader=yaml.BaseLoader)
                glass = name[len(prefix) : -len(".yml")]
                rel = name[len("database/data/") :]
                formulas = [d for d in page.get("DATA", []) if d.get("type", "").startswith("formula")]
                if not formulas:
                    tables = [d for d in page.get("DATA", []) if d.get("type", "") == "tabulated n"]
                    rows = [r.split() for r in tables[0]["data"].strip().splitlines()] if tables else []
                    if len(rows) < 2:
                        skipped.append(f"{rel}: no dispersion formula and {len(rows)} tabulated n point(s) (no dispersion)")
                        continue
                    if any(len(r) != 2 for r in rows):
                        skipped.append(f"{rel}: a tabulated n row is not `λ n`")
                        continue
                    if glass.upper() in seen:
                        skipped.append(f"{rel}: duplicate name {glass} in {catalog}")
                        continue
                    props = page.get("PROPERTIES", {}) or {}
                    status = STATUS.get(str(props.get("glass_status", "standard")).lower(), 0)
                    seen.add(glass.upper())
                    tabulated.append(f"NM {glass} {status}")
                    tabulated.append(f"GC {rel}; {reference_text(page.get('REFERENCES', ''))}")
                    tabulated.extend(f"TN {w} {n}" for w, n in rows)
                    continue
                conv = convert_formula(formulas[0])
                if isinstance(conv, str):
                    skipped.append(f"{rel}: {conv}")
                    continue
                if glass.upper() in seen:
                    skipped.append(f"{rel}: duplicate name {glass} in {catalog}")
                    continue
                props = page.get("PROPERTIES", {}) or {}
                nd, vd = props.get("nd"), props.get("Vd")
                if nd is None or vd is None:
                    skipped.append(f"{rel}: no nd/Vd in PROPERTIES")
                    continue
                lo, hi = formulas[0]["wavelength_range"].split()
                number, cd = conv
                code = props.get("glass_code", "0")
                status = STATUS.get(str(props.get("glass_status", "standard")).lower(), 0)
                ref = reference_text(page.get("REFERENCES", ""))
                seen.add(glass.upper())
                lines.append(f"NM {glass} {number} {code} {nd} {vd} 0 {status}")
                lines.append(f"GC {rel}; {ref}")
                lines.append("CD " + " ".join(cd))
                lines.append(f"LD {lo} {hi}")
                count += 1
        total += count
        with open(f"{a.out}/{catalog}.agf", "w", encoding="ascii", newline="\n") as f:
            f.write("\n".join(lines) + "\n")
        n_tab = sum(1 for t in tabulated if t.startswith("NM "))
        if n_tab:
            head = [
                f"CC {catalog} tabulated-index glasses built into diffcassi (no dispersion formula published: n at the",
                "CC vendor's wavelengths, interpolated by diffcassi), converted by scripts/convert_refractiveindex_glass.py",
                f"CC from the refractiveindex.info database, commit {commit} ({date}), public domain (CC0 1.0)",
                "CC records: NM name status; GC source page; vendor document; TN wavelength(um) n, as the page prints them",
            ]
            with open(f"{a.out}/{catalog}.tabulated", "w", encoding="ascii", newline="\n") as f:
                f.write("\n".join(head + tabulated) + "\n")
        tab_total += n_tab
        print(f"{catalog}: {count} glasses, {n_tab} tabulated", file=sys.stderr)
    for s in skipped:
        print(f"skipped {s}", file=sys.stderr)
    print(f"{total} glasses and {tab_total} tabulated from commit {commit} ({date}); {len(skipped)} pages skipped", file=sys.stderr)


if __name__ == "__main__":
    main()
