#!/usr/bin/env python3
"""The GPU render check of issue 41 (run by scripts/gpu_check.sh on a GPU machine, from the installed wheel).

The bench-render workload (SP, a 512×512 synthetic scene, 112 planes, 20 rays per pixel per plane, mask
opening 0.5) rendered on the CUDA device twice, on the CPU, and through the GPU kernels' host twin
(`diffcassi.gpu_check`), then a table and a JSON record; exits non-zero on a failed check:
  - two GPU runs bit-identical, and the GPU equal to the host twin bit for bit (integer accumulation);
  - the middle plane's rays land on the device where the host kernels land them (≤ 1e-12 mm, same statuses);
  - the GPU within the CPU renderer's own f32 rounding of it (≤ 2e-6 of the peak, tests/gpu_render.rs).
The same in f32 (the renderer's f32 trace; within 1e-4 of the CPU's f32 render, landings identical). The
chief-ray mapping cube (`mapping --device cuda`) in f64 and f32 must equal the CPU's bit for bit. The
time (kernels, and with uploads) is reported against the goal of 0.1 s.

`--systems` checks instead, on small renders (128×128, 28 planes, 8 rays), what the kernels model beyond the
paper's prisms (issue 41/42), one row group per system: `gsp` (a plane transmission grating, the vector grating
equation), a toroid lens (OpticStudio's Toroidal surface, radius of rotation 35 mm, conic and y⁴ term) and a
singlet with its object at infinity (the scene sampled in field angle, 0.5° across), SP with real ray aiming
(OpticStudio's RAIM 0 2: each ray aimed at the stop by a Newton solve, the aimed kernels
dc_landing_aimed_kernel / dc_deposit_aimed_kernel), and the dual-disperser `ddsp` and `mddsp` (the coded mask on a
surface inside the system, nearest and bilinear sampling: each ray weighted by the mask's transmission where it
crosses that surface, dc_mask_transmission). Each: two GPU runs
bit-identical; the GPU within 2e-6 of the CPU's peak; the middle plane's landings ≤ 1e-12 mm from the host's, the
same statuses (and, with a mask surface, the same weights); the GPU equal to the host twin bit for bit — except at
infinity, where the device's `tan` (CUDA's libdevice, ≤ 2 ulp; the host calls the platform's libm as the CPU
renderer does) may start a ray a few ulp away, so there the bound is 1e-9 of the peak (docs/gpu.md). In f32 (the
finite systems without a mask surface — the CPU renderer refuses f32 with one): two runs bit-identical, landings
identical, within 1e-4 of the CPU's f32 render.

`--dry-run` runs every step on a machine without a GPU, the host twin standing in for the device (the same plan,
renders, landings, comparisons, table and JSON, marked as a dry run; no figure is a GPU's): `scripts/gpu_check.sh`
with `DRY_RUN=1` and `scripts/gpu/prepare.sh` run it before a GPU machine is used, so that the check itself is
known to work.

    python scripts/gpu/render_check.py [--size 512] [--planes 112] [--rays 20] [--no-twin] [--dry-run] [--out DIR]
    python scripts/gpu/render_check.py --systems [--size 128] [--planes 28] [--rays 8] [--no-twin] [--dry-run] [--out DIR]
"""
import argparse
import json
import os
import sys
import time

# The toroid lens (tests/surfaces.rs's toroid_lens, with a conic and a y⁴ term): a Toroidal N-BK7 singlet 80 mm
# from the object, radius 20 mm in y, radius of rotation 35 mm, its image 40 mm behind.
TOROID_TOML = """
name = "toroid lens (render_check)"
ray_aiming = "off"
wavelengths_nm = [450.0, 550.0, 650.0]
primary_wavelength_nm = 550.0
fields_mm = [[0.0, 0.0], [0.0, 1.0]]

[aperture]
type = "object_space_na"
value = 0.05

[[surfaces]]
type = "standard"
thickness_mm = 80.0

[[surfaces]]
type = "toroidal"
stop = true
radius_mm = 20.0
rotation_radius_mm = 35.0
conic = -0.3
asphere_coefficients = [0.0, 1.0e-5]
thickness_mm = 5.0
material = "N-BK7"

[[surfaces]]
type = "standard"
thickness_mm = 40.0

[[surfaces]]
type = "standard"
thickness_mm = 0.0
"""

# The singlet at infinity of tests/common (singlet_at_infinity): an N-BK7 lens, 8 mm entrance pupil, f ≈ 60 mm
# (the repository's fixture, beside this script on the GPU machine as everywhere).
SINGLET_AT_INFINITY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tests", "fixtures", "systems", "singlet_at_infinity.toml")


DRY_TITLE = " — DRY RUN: the host twin stands in for the GPU, no figure is a GPU's"


def kernels_ms(r: dict) -> float:
    """The device kernels' time of a report (CUDA events); in a dry run, which has none, the twin's wall clock."""
    return r["gpu_kernels_ms"] if r["gpu_kernels_ms"] is not None else r["gpu_total_ms"]


def partial(record: dict, report: dict, out, stage: str) -> None:
    """What is measured so far: one line printed (flushed) and `record` written as render_check.json with
    `"partial": stage`, so that a step stopped at its cap still leaves its figures (they came only at the end,
    with the table; a held-out battery, round 15). `report` is the render just measured."""
    k = kernels_ms(report) / 1e3
    print(f"render_check: {stage}: kernels {k:.4f} s ({report['rays'] / k / 1e9:.2f} G rays/s), two runs bit-identical "
          f"{report['runs_bit_identical']}, max |GPU − CPU| / peak {report['cpu_max_rel_diff']:.2e}", flush=True)
    if out:
        os.makedirs(out, exist_ok=True)
        with open(os.path.join(out, "render_check.json"), "w") as f:
            json.dump({**record, "partial": stage}, f, indent=1)


def finish(record: dict, failed: list, out, name: str) -> int:
    """Record the failed checks in `record`, write it as `out`/`name` (JSON) when `out` is given, print each
    failure; the exit status (1 on any failure)."""
    record["failed"] = failed
    if out:
        os.makedirs(out, exist_ok=True)
        with open(os.path.join(out, name), "w") as f:
            json.dump(record, f, indent=1)
    for m in failed:
        print(f"render_check: FAILED: {m}", file=sys.stderr)
    return 1 if failed else 0


def with_ray_aiming(system, aiming: str):
    """`system` with ray_aiming set ("paraxial" or "real"), through its TOML."""
    import re
    import diffcassi
    text = system.to_toml()
    if re.search(r'^ray_aiming\s*=', text, flags=re.M):
        text = re.sub(r'^ray_aiming\s*=.*$', f'ray_aiming = "{aiming}"', text, count=1, flags=re.M)
    else:
        text = f'ray_aiming = "{aiming}"\n' + text
    return diffcassi.System.from_string(text)


def with_bilinear_mask(system):
    """`system` (with a coded-mask surface) with its mask sampled bilinearly, through its TOML."""
    import re
    import diffcassi
    text, n = re.subn(r'sampling\s*=\s*"nearest"', 'sampling = "bilinear"', system.to_toml())
    if n != 1:
        raise RuntimeError(f"render_check: {n} coded-mask samplings in the system's TOML (expected 1)")
    return diffcassi.System.from_string(text)


def systems_check(a) -> int:
    """The --systems rows: a grating, a toroid, an object at infinity, ray aiming, a coded mask on a surface (see the
    module's docstring)."""
    import diffcassi
    print(f"diffcassi {diffcassi.__version__} from {os.path.dirname(diffcassi.__file__)}")
    size = a.size or 128
    cube, wl = diffcassi.synthetic_scene(size, size, seed=0)
    # (name, system, scene_fov_deg at infinity, f32 rows: the CPU renders it in f32 too)
    cases = [
        ("gsp (plane transmission grating)", diffcassi.System.preset("gsp"), None, True),
        ("toroid lens", diffcassi.System.from_string(TOROID_TOML), None, True),
        ("singlet at infinity", diffcassi.System.from_file(SINGLET_AT_INFINITY), 0.5, False),
        ("sp, real ray aiming", with_ray_aiming(diffcassi.System.preset("sp"), "real"), None, True),
        ("ddsp (coded mask on a surface, nearest)", diffcassi.System.preset("ddsp"), None, False),
        ("mddsp (coded mask on a surface, bilinear)", with_bilinear_mask(diffcassi.System.preset("mddsp")), None, False),
    ]
    rows, failed, record = [], [], {}
    for name, system, fov, f32 in cases:
        kw = dict(planes=a.planes or 28, rays=a.rays or 8, opening=0.5)
        if fov is not None:
            kw["scene_fov_deg"] = fov
        t = time.time()
        r = diffcassi.gpu_check(system, cube, wl, twin=not a.no_twin, dry_run=a.dry_run, **kw)
        r["check_seconds"] = time.time() - t
        inf = r["at_infinity"]
        rows += [
            (f"{name}: rays, GPU kernels", f"{r['rays']}, {kernels_ms(r):.1f} ms", ""),
            (f"{name}: two GPU runs bit-identical", str(r["runs_bit_identical"]), "must be True"),
            (f"{name}: max |GPU − CPU| / CPU peak", f"{r['cpu_max_rel_diff']:.2e}", "≤ 2e-6"),
            (f"{name}: landings: rays, max |Δ| mm, status mismatches", f"{r['landing_rays']}, {r['landing_max_diff_mm']:.2e}, {r['landing_status_mismatches']}", "≤ 1e-12 mm, 0"),
            (f"{name}: GPU = host twin, bit for bit" + (" (at infinity: not required)" if inf else ""), str(r["twin_bit_identical"]), "True" if not inf else ""),
            (f"{name}: max |GPU − twin| / twin peak", "" if r["twin_max_rel_diff"] is None else f"{r['twin_max_rel_diff']:.2e}", "0" if not inf else "≤ 1e-9 (device tan ≤ 2 ulp)"),
        ]
        if not r["runs_bit_identical"]:
            failed.append(f"{name}: two GPU runs differ")
        if not r["cpu_max_rel_diff"] <= 2e-6:
            failed.append(f"{name}: the GPU is farther from the CPU than the CPU's f32 rounding")
        if r["landing_status_mismatches"] != 0 or not r["landing_max_diff_mm"] <= 1e-12:
            failed.append(f"{name}: device landings differ from the host's")
        if r["twin_bit_identical"] is not None:
            if not inf and not r["twin_bit_identical"]:
                failed.append(f"{name}: the GPU differs from the host twin")
            if inf and not r["twin_max_rel_diff"] <= 1e-9:
                failed.append(f"{name}: the GPU is farther than 1e-9 of the peak from the host twin")
        if f32:
            r32 = diffcassi.gpu_check(system, cube, wl, twin=False, precision="f32", dry_run=a.dry_run, **kw)
            r["f32"] = r32
            rows += [
                (f"{name} f32: two GPU runs bit-identical", str(r32["runs_bit_identical"]), "must be True"),
                (f"{name} f32: max |GPU − CPU f32| / CPU peak", f"{r32['cpu_max_rel_diff']:.2e}", "≤ 1e-4"),
                (f"{name} f32: landings: rays, max |Δ| mm, status mismatches", f"{r32['landing_rays']}, {r32['landing_max_diff_mm']:.2e}, {r32['landing_status_mismatches']}", "0 mm, 0"),
            ]
            if not r32["runs_bit_identical"]:
                failed.append(f"{name}: two GPU f32 runs differ")
            if not r32["cpu_max_rel_diff"] <= 1e-4:
                failed.append(f"{name}: the GPU f32 render is farther than 1e-4 of the peak from the CPU's f32 render")
            if r32["landing_status_mismatches"] != 0 or not r32["landing_max_diff_mm"] <= 0.0:
                failed.append(f"{name}: f32 device landings differ from the host's")
        record[name] = r
        if "gpu" not in record:  # the device, once (the figures committed name it)
            record.update(gpu=r["gpu"], driver=r["driver"], ptx=r["ptx"])
            rows.insert(0, ("GPU", f"{r['gpu']} (driver {r['driver']}; {r['ptx']})", ""))
    record["dry_run"] = a.dry_run
    print(f"| systems check ({size}×{size}, {kw['planes']} planes, {kw['rays']} rays, opening 0.5){DRY_TITLE if a.dry_run else ''} | value | bound |")
    print("|---|---|---|")
    for w, v, b in rows:
        print(f"| {w} | {v} | {b} |")
    return finish(record, failed, a.out, "render_systems_check.json")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=None, help="scene size (default 512; --systems: 128)")
    ap.add_argument("--planes", type=int, default=None, help="render planes (default 112; --systems: 28)")
    ap.add_argument("--rays", type=int, default=None, help="rays per pixel per plane (default 20; --systems: 8)")
    ap.add_argument("--preset", default="sp")
    ap.add_argument("--no-twin", action="store_true", help="skip the host twin (slow on few cores)")
    ap.add_argument("--out", default=None, help="folder for render_check.json")
    ap.add_argument("--systems", action="store_true", help="the grating, toroid, object-at-infinity, ray-aiming and dual-disperser rows instead")
    ap.add_argument("--dry-run", action="store_true", help="no GPU: the host twin stands in for the device (checks the check)")
    a = ap.parse_args()
    if a.systems:
        return systems_check(a)
    a.size, a.planes, a.rays = a.size or 512, a.planes or 112, a.rays or 20
    import diffcassi
    print(f"diffcassi {diffcassi.__version__} from {os.path.dirname(diffcassi.__file__)}")
    system = diffcassi.System.preset(a.preset)
    cube, wl = diffcassi.synthetic_scene(a.size, a.size, seed=0)
    t = time.time()
    r = diffcassi.gpu_check(system, cube, wl, twin=not a.no_twin, dry_run=a.dry_run, planes=a.planes, rays=a.rays, opening=0.5)
    r["check_seconds"] = time.time() - t
    r["workload"] = f"{a.preset}, {a.size}x{a.size}, {a.planes} planes, {a.rays} rays, opening 0.5"
    r["dry_run"] = a.dry_run
    partial(r, r, a.out, "f64 render")
    # f32: the renderer's f32 trace on the device, against the CPU's f32 render (the twin is not rerun).
    r32 = diffcassi.gpu_check(system, cube, wl, twin=False, dry_run=a.dry_run, planes=a.planes, rays=a.rays, opening=0.5, precision="f32")
    r["f32"] = r32
    partial(r, r32, a.out, "f32 render")
    # mapping --device cuda: the chief-ray cube (size² pixels × 28 bands) by the device's trace kernel, against
    # the CPU's (bit for bit: the kernel is the twin's, which equals the scalar kernel in f64 and the f32 lane
    # kernel in f32; tests/gpu_twin.rs).
    import numpy as np
    bands = list(np.linspace(450.0, 650.0, 28))
    r["mapping"] = {}
    device = "cpu-twin" if a.dry_run else "cuda"
    for prec in ("f64", "f32"):
        t = time.time()
        cpu, cpu_ok = diffcassi.mapping(system, a.size, a.size, bands, precision=prec)
        cpu_s = time.time() - t
        diffcassi.mapping(system, 8, 8, bands, device=device, precision=prec)  # the launcher started, untimed
        t = time.time()
        gpu, gpu_ok = diffcassi.mapping(system, a.size, a.size, bands, device=device, precision=prec)
        gpu_s = time.time() - t
        same = bool(np.array_equal(cpu_ok, gpu_ok) and np.array_equal(cpu.view(np.uint64), gpu.view(np.uint64)))
        r["mapping"][prec] = {"cpu_seconds": cpu_s, "gpu_seconds": gpu_s, "bit_identical": same, "entries": int(cpu_ok.size)}
    rays = r["rays"]
    k_s, t_s = kernels_ms(r) / 1e3, r["gpu_total_ms"] / 1e3
    rows = [
        ("workload", r["workload"], ""),
        ("GPU", f"{r['gpu']} (driver {r['driver']}; {r['ptx']})", ""),
        ("rays per render", f"{rays}", ""),
        ("GPU f64, kernels", f"{k_s:.4f} s, {rays / k_s / 1e9:.2f} G rays/s", "goal ≤ 0.1 s"),
        ("GPU f64, with plan, uploads, copy", f"{t_s:.4f} s", ""),
        ("CPU f64 (this machine's cores)", f"{r['cpu_seconds']:.3f} s ({r['cpu_seconds'] / k_s:.0f}× the GPU kernels)", ""),
        ("GPU f32, kernels", f"{kernels_ms(r32) / 1e3:.4f} s, {rays / (kernels_ms(r32) / 1e3) / 1e9:.2f} G rays/s", ""),
        ("CPU f32", f"{r32['cpu_seconds']:.3f} s", ""),
        ("f32: two GPU runs bit-identical", str(r32["runs_bit_identical"]), "must be True"),
        ("f32: max |GPU − CPU| / CPU peak", f"{r32['cpu_max_rel_diff']:.2e}", "≤ 1e-4"),
        ("f32 landings: rays, max |Δ| mm, status mismatches",
         f"{r32['landing_rays']}, {r32['landing_max_diff_mm']:.2e}, {r32['landing_status_mismatches']}", "0 mm, 0"),
        ("two GPU runs bit-identical", str(r["runs_bit_identical"]), "must be True"),
        ("GPU = host twin, bit for bit", str(r["twin_bit_identical"]), "must be True (None: not run)"),
        ("host twin wall clock", "" if r["twin_seconds"] is None else f"{r['twin_seconds']:.1f} s", ""),
        ("max |GPU − CPU| / CPU peak", f"{r['cpu_max_rel_diff']:.2e}", "≤ 2e-6 (the CPU's f32 splat)"),
        ("landings (middle plane): rays, max |Δ| mm, status mismatches",
         f"{r['landing_rays']}, {r['landing_max_diff_mm']:.2e}, {r['landing_status_mismatches']}", "≤ 1e-12 mm, 0"),
        ("accumulation", r["accumulation"], ""),
    ]
    for prec, m in r["mapping"].items():
        rows.append((f"mapping {prec} ({m['entries']} chief rays): GPU (with uploads) / CPU",
                     f"{m['gpu_seconds']:.3f} s / {m['cpu_seconds']:.3f} s", ""))
        rows.append((f"mapping {prec}: GPU = CPU bit for bit", str(m["bit_identical"]), "must be True"))
    print(f"| render check{DRY_TITLE if a.dry_run else ''} | value | bound |")
    print("|---|---|---|")
    for w, v, b in rows:
        print(f"| {w} | {v} | {b} |")
    failed = []
    if not r["runs_bit_identical"]:
        failed.append("two GPU runs differ")
    if r["twin_bit_identical"] is False:
        failed.append("the GPU differs from the host twin")
    if r["landing_status_mismatches"] != 0 or not r["landing_max_diff_mm"] <= 1e-12:
        failed.append("device landings differ from the host's")
    if not r["cpu_max_rel_diff"] <= 2e-6:
        failed.append("the GPU is farther from the CPU than the CPU's f32 rounding")
    if not r32["runs_bit_identical"]:
        failed.append("two GPU f32 runs differ")
    if not r32["cpu_max_rel_diff"] <= 1e-4:
        failed.append("the GPU f32 render is farther than 1e-4 of the peak from the CPU's f32 render")
    if r32["landing_status_mismatches"] != 0 or not r32["landing_max_diff_mm"] <= 0.0:
        failed.append("f32 device landings differ from the host's")
    for prec, m in r["mapping"].items():
        if not m["bit_identical"]:
            failed.append(f"the {prec} mapping cube on the GPU differs from the CPU's")
    return finish(r, failed, a.out, "render_check.json")


if __name__ == "__main__":
    sys.exit(main())
