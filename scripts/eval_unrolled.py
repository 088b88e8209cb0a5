#!/usr/bin/env python3
"""Evaluates the trained unrolled networks (``diffcassi/weights/unrolled-gap-v1-<system>.safetensors``) on the six
natural scenes of ``data/scenes`` beside the CLI's GAP-TV and PnP-GAP, in the realistic setting, and prints the
table of docs/reconstruction.md, section "Unrolled network".

    .venv/bin/python scripts/eval_unrolled.py --mask ../shared/reference/paper_mask_512.npy --out out/eval-unrolled

1. ``diffcassi study --presets SYSTEMS --operators exact --solvers gap-tv,pnp-gap --scenes data/scenes
   --scene-size 128 --mask MASK --out OUT/study`` renders every scene (28 bands, 112 planes, 20 rays, Airy 2.5 px,
   acquisition seed 0) and reconstructs it with the CLI's defaults (exact operator traced with seed 1); resumable:
   a rerun reuses what is done (``--no-study`` only reads it);
2. the truth cubes are ``diffcassi make-scene --rgb SCENE.png --size 128`` (the study's scenes, area-resized);
3. checks: the acquisition of the study's render equals ``diffcassi.Transport(seed 0).apply(truth)`` with the
   script's mask and settings (so truth, mask and settings are the study's), and ``diffcassi.metrics`` of the
   study's GAP-TV cube gives study.csv's PSNR;
4. the network reads each render's ``acquisition.exr`` and runs around the exact operator traced with the study's
   operator seed (acquisition seed + 1) in its matrix-free torch form; the weights' metadata (system, bands, mask)
   are checked against it; metrics by ``diffcassi.metrics`` (the study's: paper PSNR, SSIM, SAM).
"""
from __future__ import annotations

import argparse
import csv
import json
import pathlib
import subprocess
import sys
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import diffcassi  # noqa: E402
import diffcassi.torch as dt  # noqa: E402
from diffcassi.unrolled import ARCH, ARCHS, load_unrolled, make_unrolled  # noqa: E402

sys.path.insert(0, str(ROOT / "scripts"))
from train_unrolled import BANDS_NM, load_mask, names, setting  # noqa: E402

WEIGHTS = ROOT / "diffcassi" / "weights"


def run(cmd: list) -> None:
    print("+", " ".join(map(str, cmd)), flush=True)
    subprocess.run([str(c) for c in cmd], check=True)


def metrics(truth: np.ndarray, estimate: np.ndarray) -> dict:
    """diffcassi.metrics (the study's: paper PSNR, SSIM, SAM) of an estimate (H, W, bands) against the truth."""
    d = diffcassi.metrics(truth, estimate)
    return d.get("metrics", d)


def network_cube(net, acquisition: np.ndarray) -> np.ndarray:
    """The network's estimate (H, W, bands) float32 of one acquisition (h, w)."""
    with torch.no_grad():
        x = net(torch.from_numpy(np.ascontiguousarray(acquisition, dtype=np.float32))[None])[0]
    return np.ascontiguousarray(x.permute(1, 2, 0).numpy(), dtype=np.float32)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="work folder (OUT/study, OUT/truth, OUT/results.json)")
    ap.add_argument("--mask", required=True, help="the mask file of the study (e.g. ../shared/reference/paper_mask_512.npy)")
    ap.add_argument("--systems", default="sp,msp")
    ap.add_argument("--scenes", default=str(ROOT / "data" / "scenes"))
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--weights", default=str(WEIGHTS), help="folder of unrolled-gap-v1-<system>.safetensors (or "
                    "unrolled-dauhst-v2-<system>.safetensors with --arch unrolled-dauhst-v2: a GPU run's --out)")
    ap.add_argument("--arch", default=ARCH, choices=sorted(ARCHS), help="the network's architecture (its file name)")
    ap.add_argument("--cli", default=str(ROOT / "target" / "release" / "diffcassi"))
    ap.add_argument("--threads", type=int, default=1, help="torch and Rust threads of the network's run")
    ap.add_argument("--no-study", action="store_true", help="do not run the study (read OUT/study as it is)")
    a = ap.parse_args(argv)
    systems = [s for s in a.systems.split(",") if s]
    out = pathlib.Path(a.out)
    study = out / "study"
    scenes = sorted(pathlib.Path(a.scenes).glob("*.png"))
    if not scenes:
        print(f"eval_unrolled: error: {a.scenes}: no .png scenes", file=sys.stderr)
        return 1
    torch.set_num_threads(a.threads)
    diffcassi.set_num_threads(a.threads)
    if not a.no_study:
        run([a.cli, "study", "--presets", ",".join(systems), "--operators", "exact", "--solvers", "gap-tv,pnp-gap",
             "--scenes", a.scenes, "--scene-size", a.size, "--mask", a.mask, "--out", study])
    rows = list(csv.DictReader(open(study / "study.csv")))
    truth_dir = out / "truth"
    truth_dir.mkdir(parents=True, exist_ok=True)
    truths = {}
    for png in scenes:
        t = truth_dir / f"{png.stem}.npy"
        if not t.is_file():
            run([a.cli, "make-scene", "--rgb", png, "--size", a.size, "--out", t])
        truths[png.stem] = np.load(t)
    mask = load_mask(a.mask, a.size)
    results: dict = {}
    for system in systems:
        rj = json.loads((study / "renders" / system / scenes[0].stem / "render.json").read_text())
        acq_seed = int(rj["seed"])
        kw = setting(mask, int(rj["planes"]), int(rj["rays_per_pixel"]), BANDS_NM)
        if [float(b) for b in rj["bands_nm"]] != kw["bands_nm"]:
            print(f"eval_unrolled: error: the study's bands {rj['bands_nm']} are not the network's", file=sys.stderr)
            return 1
        sysm = diffcassi.System.preset(system)
        t0 = time.time()
        acq_transport = diffcassi.Transport(sysm, a.size, a.size, seed=acq_seed, **kw)
        phi = dt.CassiOperator.from_operator(diffcassi.exact(sysm, a.size, a.size, seed=acq_seed + 1, **kw), matrix_free=True)
        t_op = time.time() - t0
        net = load_unrolled(pathlib.Path(a.weights) / names(system, a.arch)["weights"], phi, system=system,
                            mask=acq_transport.mask)
        # The same graph untrained (zero linear paths and tails): K plain GAP steps from Φᵀ(y ⊘ d), no prior.
        plain = make_unrolled(a.arch, phi, net.stages, net.width).eval()
        res = results[system] = {"operator_seconds": round(t_op, 1), "scenes": {}}
        for png in scenes:
            name = png.stem
            rdir = study / "renders" / system / name
            acq = np.asarray(dict(diffcassi.read_exr(rdir / "acquisition.exr"))["Y"], dtype=np.float32)
            truth = truths[name]
            mine = acq_transport.apply(truth).astype(np.float32)
            if not np.array_equal(mine, acq.reshape(mine.shape)):
                print(f"eval_unrolled: error: {rdir}: the study's acquisition differs from Transport(seed {acq_seed}).apply(truth) "
                      f"by {np.abs(mine - acq.reshape(mine.shape)).max():.3g}: not the same truth, mask or settings", file=sys.stderr)
                return 1
            cell = {}
            for solver in ("gap-tv", "pnp-gap"):
                r = [x for x in rows if x["preset"] == system and x["scene"] == name and x["operator"] == "exact" and x["solver"] == solver]
                if len(r) != 1:
                    print(f"eval_unrolled: error: study.csv has {len(r)} rows for {system}/{name}/exact/{solver}", file=sys.stderr)
                    return 1
                cell[solver] = {k: float(r[0][k]) for k in ("psnr_db", "ssim", "sam_deg", "seconds_solve")}
            own = metrics(truth, np.load(study / "recon" / system / name / "exact-gap-tv" / "cube.npy"))
            if abs(own["psnr_db"] - cell["gap-tv"]["psnr_db"]) > 0.01:
                print(f"eval_unrolled: error: {system}/{name}: metrics of the study's GAP-TV cube against the truth give "
                      f"{own['psnr_db']:.3f} dB, study.csv {cell['gap-tv']['psnr_db']:.3f} dB: not the study's truth", file=sys.stderr)
                return 1
            t1 = time.time()
            est = network_cube(net, acq.reshape(phi.image_shape))
            secs = time.time() - t1
            if not np.isfinite(est).all():
                print(f"eval_unrolled: error: {system}/{name}: the network's output is not finite", file=sys.stderr)
                return 1
            m = metrics(truth, est)
            cell["unrolled"] = {"psnr_db": m["psnr_db"], "ssim": m["ssim"], "sam_deg": m["sam_deg"], "seconds_solve": secs}
            m = metrics(truth, network_cube(plain, acq.reshape(phi.image_shape)))
            cell["plain-gap"] = {"psnr_db": m["psnr_db"], "ssim": m["ssim"], "sam_deg": m["sam_deg"], "seconds_solve": None}
            res["scenes"][name] = cell
            print(f"{system} {name} ({secs:.1f} s): " + ", ".join(f"{k} {v['psnr_db']:.2f} dB" for k, v in cell.items()), flush=True)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    names_ = [p.stem for p in scenes]
    label = {"gap-tv": "GAP-TV (CLI default)", "pnp-gap": "PnP-GAP (CLI default)", "unrolled": "unrolled network",
             "plain-gap": "the same graph untrained (plain GAP)"}
    for system in systems:
        sc = results[system]["scenes"]
        print(f"\n| {system.upper()}, exact, {a.size}×{a.size}×28, PSNR (dB) | " + " | ".join(names_) + " | mean | SSIM | SAM (°) | seconds |")
        print("|---" * (len(names_) + 5) + "|")
        for k in ("gap-tv", "pnp-gap", "plain-gap", "unrolled"):
            p = [sc[n][k]["psnr_db"] for n in names_]
            mean = lambda f: float(np.mean([sc[n][k][f] for n in names_]))  # noqa: E731
            print(f"| {label[k]} | " + " | ".join(f"{v:.2f}" for v in p) + f" | **{np.mean(p):.2f}** | {mean('ssim'):.3f} | "
                  f"{mean('sam_deg'):.1f} | {'–' if k == 'plain-gap' else format(mean('seconds_solve'), '.1f')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
