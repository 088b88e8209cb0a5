#!/bin/bash
# The stopping rule's measurement (docs/reconstruction.md, "δ̂ from the data against the truth residual"):
# for each scene, a render at S×S (the paper's mask, centre crop), the true cube, and a 300-iteration GAP-TV run
# with the rule off that records δ̂ every 5 iterations, the PSNR of every iterate and the relative changes.
# Then `.venv/bin/python scripts/stopping_table.py out/stopping/m*/*/*/rec/reconstruct.json` prints the table.
# Usage: scripts/measure_stopping.sh SIZE PRESET SCENE...   (outputs under out/stopping/mSIZE/PRESET/SCENE)
set -euo pipefail
B=${DIFFCASSI:-target/release/diffcassi}
MASK=${MASK:-../shared/reference/paper_mask_512.npy}
PY=${PYTHON:-.venv/bin/python}
S=$1; P=$2; shift 2
root=out/stopping/m$S
mkdir -p "$root/truth"
[ -f "$root/mask.npy" ] || "$PY" -c "import numpy as np,sys; m=np.load(sys.argv[1]); o=(m.shape[0]-$S)//2; np.save(sys.argv[2], np.ascontiguousarray(m[o:o+$S, o:o+$S]))" "$MASK" "$root/mask.npy"
for sc in "$@"; do
  d=$root/$P/$sc
  mkdir -p "$d"
  [ -f "$root/truth/$sc.npy" ] || "$B" make-scene --rgb "data/scenes/$sc.png" --size "$S" --out "$root/truth/$sc.npy" >/dev/null
  [ -f "$d/render/render.json" ] || "$B" render --preset "$P" --scene "data/scenes/$sc.png" --fit resize --scene-size "$S" --rays 20 --mask "$root/mask.npy" --no-mapping --out "$d/render" >/dev/null
  [ -f "$d/rec/reconstruct.json" ] || "$B" reconstruct --from "$d/render" --truth "$root/truth/$sc.npy" --iterations 300 --discrepancy 0 --tolerance 1e-30 --out "$d/rec" > "$d/rec.log" 2>&1
  echo "$S $P $sc done $(date +%T)"
done
