#!/usr/bin/env python3
"""Measures plug-and-play schedules against GAP-TV in the realistic setting (issue 22), through the Python
bindings, on validation renders of procedural scenes (``--scenes val``: dead-leaves cubes of seeds
``EVAL_VAL_SEED_BASE + i``, disjoint from every training seed; what schedules are chosen on) or on the six
natural scenes of ``data/scenes`` (``--scenes natural``: reported, never tuned on).

    .venv/bin/python scripts/eval_pnp.py --scenes val --count 6 --weights W.safetensors --json out.json
    .venv/bin/python scripts/eval_pnp.py --scenes natural --weights W.safetensors --json out.json

Setting (docs/study.md's): 128² scenes (natural: the 256² uplift area-averaged to 128², ``study``'s default fit), 28 bands 450–650 nm, 112 planes,
20 rays per pixel per plane (acquisition seed 0), Airy 2.5 px, the paper's mask's centre crop; the exact
operator traced with seed 1 (``--operator-seed``; 0 = the acquisition's own rays, the oracle: no model mismatch, δ = 0); δ from :func:`diffcassi.monte_carlo_noise_norm`. Per scene and preset: GAP-TV with
its defaults; then the network schedules of ``--schedules`` — ``one:S`` = one network call at σ = S on the iterate
``pnp-gap`` hands it (GAP-TV's stop, then one data step: obtained once with an identity network, then denoised
in PyTorch, equal to the Rust inference to 1e-4; mean-colour neutralisation with ``--neutral``, the
self-ensemble with ``--ensemble``: ``diffcassi.denoiser.denoise``), ``pnp:N:S1:S2[:plain]`` = ``pnp-gap`` with N network
iterations σ S1 → S2 (geometric), accelerated unless ``plain``, no early stop (``discrepancy`` 0, tolerance 0);
``pnp:...:eq[=SEED]`` = the same with equivariant PnP on (``equivariant=True``, seed SEED, default 0) and
``pnp:...:noeq`` with it off (the library's default otherwise);
``roll:N:S1:S2[:eq=SEED|:flips=SEED]`` = the same accelerated schedule rolled out in NumPy/PyTorch from the cell's GAP-TV result and
network input (``make_pnp_pairs.gap_rollout``, equal to ``pnp-gap`` to f32 and the inferences' 1e-4; ``eq=SEED``:
equivariant, the transforms of ``diffcassi.denoiser.dihedral_draw`` as the Rust solver draws them; ``flips=SEED``:
the four flips only, also for square cubes; with
``--cache`` only the operator is rebuilt: no TV phase per schedule and weights).
PSNR is the paper's (``diffcassi.metrics``: one MSE over the cube, peak = the truth's max); each cell also
records SSIM (``KEY|ssim``, per band on the [0, 1]-clamped estimate) and SAM in degrees (``KEY|sam``, the
estimate as is), as ``diffcassi evaluate``. ``--diagnose`` adds, per ``roll:`` schedule, where SAM comes from:
the mean per-pixel angle over the truth-brightness quartiles (``|sam_q1``..``|sam_q4``, q1 darkest, brightness
= the truth's spectral norm), SAM of the estimate clipped at 0 (``|sam_clip0``), and the share of negative
values (``|neg``).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import diffcassi  # noqa: E402
from diffcassi.deadleaves import BANDS_NM, dead_leaves  # noqa: E402
from diffcassi.denoiser import denoise, dihedral_draw, load_weights  # noqa: E402

EVAL_VAL_SEED_BASE = 7_000_000
RAYS, PLANES, SIZE = 20, 112, 128
ACQUISITION_SEED, OPERATOR_SEED = 0, 1


def scenes(which: str, count: int):
    if which == "natural":
        for png in sorted((ROOT / "data/scenes").glob("*.png")):
            cube, _ = diffcassi.load_scene(png, list(BANDS_NM))
            h, w, b = cube.shape
            if (h, w) != (2 * SIZE, 2 * SIZE):
                raise SystemExit(f"eval_pnp: error: {png} is {h}×{w}, expected {2 * SIZE}² (the study's --fit resize by 2)")
            # `study --fit resize` (its default): the area average, here of 2×2 blocks (256² → 128²).
            cube = cube.astype(np.float64).reshape(SIZE, 2, SIZE, 2, b).mean(axis=(1, 3))
            yield png.stem, np.ascontiguousarray(cube, dtype=np.float32)
    else:
        for i in range(count):
            seed = EVAL_VAL_SEED_BASE + i
            c = dead_leaves(seed, SIZE, BANDS_NM, kind="spectral" if i % 3 == 2 else "rgb")
            yield f"val{seed}", np.ascontiguousarray(c.transpose(1, 2, 0))


def project_metrics(truth: np.ndarray, estimate: np.ndarray) -> dict:
    """The project's metrics of ``estimate`` against ``truth`` ((H, W, B) each), by :func:`diffcassi.metrics`:
    the paper's PSNR (dB), SSIM, SAM (degrees)."""
    d = diffcassi.metrics(truth, np.ascontiguousarray(estimate, dtype=np.float32))
    d = d.get("metrics", d)
    return {"psnr": float(d["psnr_db"]), "ssim": float(d["ssim"]), "sam": float(d["sam_deg"])}


def paper_psnr(truth: np.ndarray, estimate: np.ndarray) -> float:
    """The paper's PSNR (dB) of ``estimate`` against ``truth`` ((H, W, B) each), by :func:`diffcassi.metrics`."""
    return project_metrics(truth, estimate)["psnr"]


def sam_diagnosis(truth: np.ndarray, estimate: np.ndarray) -> dict:
    """Where the mean spectral angle comes from (degrees): the per-pixel angle (as ``recon::metrics``'s SAM)
    averaged over the quartiles of the truth's spectral norm (q1 darkest), SAM of the estimate clipped at 0,
    and the share of negative estimate values."""
    t = truth.reshape(-1, truth.shape[-1]).astype(np.float64)
    e = estimate.reshape(-1, estimate.shape[-1]).astype(np.float64)

    def angles(e):
        nt, ne = np.linalg.norm(t, axis=1), np.linalg.norm(e, axis=1)
        c = np.einsum("ij,ij->i", t, e) / np.maximum(nt * ne, 1e-300)
        a = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
        return np.where((nt == 0) & (ne == 0), 0.0, np.where((nt == 0) | (ne == 0), 90.0, a))

    a, nt = angles(e), np.linalg.norm(t, axis=1)
    q = np.quantile(nt, [0.25, 0.5, 0.75])
    bins = np.digitize(nt, q)
    out = {f"sam_q{i + 1}": float(a[bins == i].mean()) for i in range(4)}
    out["sam_clip0"] = float(angles(np.maximum(e, 0.0)).mean())
    out["neg"] = float((e < 0).mean())
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", choices=("val", "natural"), default="val")
    ap.add_argument("--count", type=int, default=6, help="validation scenes (--scenes val)")
    ap.add_argument("--presets", default="sp,msp")
    ap.add_argument("--weights", action="append", default=[], help="weights file(s) for the one-call schedules")
    ap.add_argument("--schedules", default="one:0.2", help="comma-separated one:S and pnp:N:S1:S2[:plain]")
    ap.add_argument("--mask", default=str(ROOT.parent / "shared/reference/paper_mask_512.npy"))
    ap.add_argument("--neutral", action="store_true", help="one-call rows with the mean-colour neutralisation (off by "
                    "default, as in the PnP solvers; `pnp:` rows run the Rust solvers, never neutralised)")
    ap.add_argument("--ensemble", action="store_true", help="one-call rows with the geometric self-ensemble (8× time)")
    ap.add_argument("--diagnose", action="store_true", help="per roll: schedule, SAM by truth-brightness quartile, "
                    "SAM of the estimate clipped at 0 and the share of negative values")
    ap.add_argument("--operator-seed", type=int, default=OPERATOR_SEED,
                    help=f"the exact operator's Monte-Carlo seed ({OPERATOR_SEED}: another seed than the acquisition's, "
                    f"the realistic setting; {ACQUISITION_SEED}: the acquisition's own rays, the oracle without model "
                    "mismatch: δ = 0, the discrepancy rule off, every TV phase runs to its cap)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    ap.add_argument("--cache", default=None, help="folder keeping each cell's GAP-TV PSNR and network input (they do "
                    "not depend on the weights): one-call schedules of other weights then need no solve")
    a = ap.parse_args(argv)
    if a.operator_seed < 0:
        ap.error(f"--operator-seed: expected an integer ≥ 0, got {a.operator_seed}")
    torch.set_num_threads(a.threads)
    diffcassi.set_num_threads(a.threads)
    paper = np.load(a.mask).astype(np.float32)
    y0, x0 = (paper.shape[0] - SIZE) // 2, (paper.shape[1] - SIZE) // 2
    mask = np.ascontiguousarray(paper[y0:y0 + SIZE, x0:x0 + SIZE])
    weights = a.weights or [str(ROOT / "src/recon/prior/weights/spectral-unet-v2-28.safetensors")]
    nets = {w: load_weights(w, bands=len(BANDS_NM)) for w in weights}
    scheds = [s.strip() for s in a.schedules.split(",") if s.strip()]
    rows = []
    t0 = time.time()
    from make_pnp_pairs import TV_CAP, gap_rollout, identity_weights, sigma_schedule  # noqa: E402 (scripts/ on sys.path)
    with tempfile.TemporaryDirectory() as tmp:
        ident = str(pathlib.Path(tmp) / "identity.safetensors")
        identity_weights(pathlib.Path(ident), len(BANDS_NM))
        for name, truth in scenes(a.scenes, a.count):
            for preset in a.presets.split(","):
                system = diffcassi.System.preset(preset)
                psnr = lambda c, t=truth: paper_psnr(t, c)

                def record(key, c, diagnose=False):
                    m = project_metrics(truth, c)
                    row[key], row[f"{key}|ssim"], row[f"{key}|sam"] = m["psnr"], m["ssim"], m["sam"]
                    if diagnose:
                        row.update({f"{key}|{k}": v for k, v in sam_diagnosis(truth, c).items()})
                # A cell's cache names its operator seed unless it is the realistic default (older caches keep their names):
                # a cache of one operator is never read for another.
                op_tag = "" if a.operator_seed == OPERATOR_SEED else f"-op{a.operator_seed}"
                cached = None if a.cache is None else pathlib.Path(a.cache) / f"{name}-{preset}{op_tag}.npz"
                need_op = any(x.startswith("pnp:") for x in scheds)
                need_roll = any(x.startswith("roll:") for x in scheds)
                has_cache = cached is not None and cached.is_file()
                if has_cache and need_roll:
                    with np.load(cached) as z:
                        has_cache = "gap_tv_cube" in z.files
                if has_cache and not need_op:
                    with np.load(cached) as z:
                        x, gap_tv = z["iterate"], float(z["gap_tv"])
                        gt = z["gap_tv_cube"] if "gap_tv_cube" in z.files else None
                    if need_roll:
                        y, _ = diffcassi.render(system, truth, list(BANDS_NM), mask, rays=RAYS, planes=PLANES, seed=ACQUISITION_SEED)
                        y = np.ascontiguousarray(y, dtype=np.float32)
                        op = diffcassi.exact(system, SIZE, SIZE, mask, rays=RAYS, planes=PLANES, seed=a.operator_seed)
                else:
                    y, _ = diffcassi.render(system, truth, list(BANDS_NM), mask, rays=RAYS, planes=PLANES, seed=ACQUISITION_SEED)
                    y = np.ascontiguousarray(y, dtype=np.float32)
                    op = diffcassi.exact(system, SIZE, SIZE, mask, rays=RAYS, planes=PLANES, seed=a.operator_seed)
                    # The oracle operator (the acquisition's own rays) has no Monte-Carlo mismatch: δ = 0.
                    delta = (0.0 if a.operator_seed == ACQUISITION_SEED
                             else diffcassi.monte_carlo_noise_norm(y, RAYS, RAYS, PLANES / len(BANDS_NM)))
                    gt, _ = diffcassi.reconstruct(op, y, "gap-tv", noise_norm=delta)
                    gap_tv = psnr(gt)
                    # The network's first input: the TV phase and one identity call (explicit: the default
                    # network phase has several calls since round 6).
                    # (Not needed, and not run, when every schedule is a `pnp:` solve.)
                    x = None if all(sc.startswith("pnp:") for sc in scheds) else diffcassi.reconstruct(
                        op, y, "pnp-gap", denoiser=ident, noise_norm=delta, tv_warmup=TV_CAP, iterations=TV_CAP + 1,
                        equivariant=False)[0]
                    if cached is not None and x is not None:
                        cached.parent.mkdir(parents=True, exist_ok=True)
                        np.savez(cached, iterate=x, gap_tv=gap_tv, gap_tv_cube=gt)
                row = {"scene": name, "preset": preset}
                if gt is not None:
                    record("gap_tv", gt, a.diagnose)
                else:
                    row["gap_tv"] = gap_tv
                if x is not None:
                    p = float(x.max()) if x.max() > 0 else 1.0
                    xin = torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1) / p))[None]
                    record("iterate", x)
                for s in scheds:
                    parts = s.split(":")
                    if parts[0] == "one":
                        for w, net in nets.items():
                            with torch.no_grad():
                                out = denoise(net, xin, float(parts[1]), neutral=a.neutral,
                                              ensemble=a.ensemble)[0].numpy().transpose(1, 2, 0) * p
                            record(f"{s}@{pathlib.Path(w).name}" if len(nets) > 1 else s, out)
                    elif parts[0] == "pnp":
                        n, s1, s2 = int(parts[1]), float(parts[2]), float(parts[3])
                        plain = "plain" in parts[4:]
                        eq = {}
                        for opt in parts[4:]:
                            if opt.startswith("eq"):
                                eq = {"equivariant": True, "equivariant_seed": int(opt[3:] or 0)}
                            elif opt == "noeq":
                                eq = {"equivariant": False}
                            elif opt != "plain":
                                ap.error(f"--schedules {s!r}: unknown option {opt!r} (plain, eq[=SEED], noeq)")
                        for w in weights:
                            c, _ = diffcassi.reconstruct(op, y, "pnp-gap", denoiser=w, noise_norm=delta, iterations=300 + n,
                                                         sigma_max=s1, sigma_min=min(s1, s2), discrepancy=0.0,
                                                         tolerance=0.0, accelerated=not plain, **eq)
                            record(f"{s}@{pathlib.Path(w).name}" if len(nets) > 1 else s, c)
                    elif parts[0] == "roll":
                        n, s1, s2 = int(parts[1]), float(parts[2]), float(parts[3])
                        tr = None
                        for opt in parts[4:]:
                            kind, _, seed = opt.partition("=")
                            if kind not in ("eq", "flips"):
                                ap.error(f"--schedules {s!r}: unknown option {opt!r} (eq=SEED, flips=SEED)")
                            square = kind == "eq" and truth.shape[0] == truth.shape[1]
                            tr = [dihedral_draw(int(seed or 0), j + 1, square) for j in range(n)]
                        for w, net in nets.items():
                            _, c = gap_rollout(op, y, gt, x, net, sigma_schedule(s1, s2, n), transforms=tr)
                            record(f"{s}@{pathlib.Path(w).name}" if len(nets) > 1 else s, c, a.diagnose)
                    else:
                        ap.error(f"--schedules: unknown schedule {s!r}")
                rows.append(row)
                print(json.dumps({k: (round(v, 3 if "|" in k else 2) if isinstance(v, float) else v) for k, v in row.items()}), f"{time.time() - t0:.0f} s", flush=True)
    keys = [k for k in rows[0] if k not in ("scene", "preset") and all(k in r for r in rows)]
    summary = {pr: {k: float(np.mean([r[k] for r in rows if r["preset"] == pr])) for k in keys}
               for pr in a.presets.split(",")}
    print("mean:", json.dumps({pr: {k: round(v, 3 if "|" in k else 2) for k, v in d.items()} for pr, d in summary.items()}))
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"rows": rows, "mean": summary, "args": vars(a),
                                                    "wall_s": round(time.time() - t0, 1)}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
