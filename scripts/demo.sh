#!/usr/bin/env bash
# Install splatreel and run the main job: generate the procedural 'spinner' sample, fit 4D Gaussians to it with the
# default auto recipe (5 minutes), evaluate on the held-out views, and leave the checkpoint for `splatreel view`.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
OUT="${OUT:-out/demo}"
mkdir -p "$OUT"
echo "== generating the 'spinner' sample (16 views x 16 frames, D-NeRF layout) in $OUT/spinner"
splatreel sample spinner --out "$OUT/spinner" --force
echo "== training (the auto recipe, 5 minutes)"
splatreel train "$OUT/spinner" --out "$OUT/spinner.safetensors" --force
echo "== evaluation on the test views (other azimuths, elevations and times)"
splatreel eval "$OUT/spinner.safetensors" "$OUT/spinner" --out "$OUT/eval.json" --force
splatreel info "$OUT/spinner.safetensors"
echo "== done: view it with  .venv/bin/splatreel view $OUT/spinner.safetensors   (.venv/bin/splatreel view alone opens the bundled one)"
