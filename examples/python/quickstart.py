"""The ten-line example of docs/python.md: render, reconstruct, metrics. Run: .venv/bin/python examples/python/quickstart.py"""
import numpy as np, diffcassi
sp = diffcassi.System.preset("sp")                             # or System.from_file("my.toml" | .json | .yml | Zemax .csv)
cube, wl = diffcassi.synthetic_scene(64, 64, seed=1)           # (H, W, 31) float32 at 400–700 nm; or diffcassi.load_scene(path)
acq, info = diffcassi.render(sp, cube, wl, rays=8)             # every other default = the CLI's (28 bands, 112 planes, mask seed 0, Airy)
print(acq.shape, info["acquisition_total"])                    # (h, w) float64 and render.json's keys
phi = diffcassi.exact(sp, 64, 64, rays=8, seed=1)              # the exact operator with another Monte-Carlo seed (not the oracle)
est, record = diffcassi.reconstruct(phi, acq, iterations=50)   # GAP-TV (accelerated); solver="admm-tv" for ADMM-TV
truth = np.stack([np.interp(np.linspace(450, 650, 28), wl, v) for v in cube.reshape(-1, 31)]).reshape(64, 64, 28)
print(diffcassi.metrics(truth.astype(np.float32), est))        # rmse, psnr_db (paper), psnr_band_db (MST), ssim, sam_rad, sam_deg
