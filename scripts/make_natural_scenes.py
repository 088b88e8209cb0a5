"""Regenerate data/scenes/*.png: six public-domain / CC0 RGB photographs shipped inside scikit-image's wheel
(skimage/data/), centre-cropped to a square and area-downscaled to 256×256 sRGB 8-bit PNGs.

Run once (needs scikit-image and Pillow, e.g. in a throwaway venv):
    python3 -m venv /tmp/skvenv && /tmp/skvenv/bin/pip install scikit-image
    /tmp/skvenv/bin/python scripts/make_natural_scenes.py data/scenes
Licences: see data/scenes/README.md (copied from the skimage.data docstrings).
"""
import sys
from pathlib import Path

import numpy as np
from PIL import Image
import skimage.data as d

SIZE = 256
SCENES = {
    "astronaut": d.astronaut,
    "chelsea": d.chelsea,
    "coffee": d.coffee,
    "rocket": d.rocket,
    "retina": d.retina,
    "ihc": d.immunohistochemistry,
}

out = Path(sys.argv[1] if len(sys.argv) > 1 else "data/scenes")
out.mkdir(parents=True, exist_ok=True)
for name, load in SCENES.items():
    rgb = np.asarray(load())[..., :3]
    h, w = rgb.shape[:2]
    s = min(h, w)
    r0, c0 = (h - s) // 2, (w - s) // 2
    square = Image.fromarray(rgb[r0:r0 + s, c0:c0 + s])
    square.resize((SIZE, SIZE), Image.Resampling.BOX).save(out / f"{name}.png", optimize=True)
    print(name, rgb.shape, "->", (SIZE, SIZE))
