#!/usr/bin/env bash
# Install splat4d and run the main job: generate the procedural 'spinner' sample, fit 4D Gaussians to it with the
# default auto recipe (4 minutes), evaluate on the held-out views, and leave the checkpoint for `splat4d view`.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
OUT="${OUT:-out/demo}"
mkdir -p "$OUT"
echo "== generating the 'spinner' sample (16 views x 16 frames, D-NeRF layout) in $OUT/spinner"
splat4d sample spinner "$OUT/spinner" --force
echo "== training (the auto recipe, 4 minutes)"
splat4d train "$OUT/spinner" --out "$OUT/spinner.safetensors" --force
echo "== evaluation on the test views (other azimuths, elevations and times)"
splat4d eval "$OUT/spinner.safetensors" "$OUT/spinner" --json "$OUT/eval.json" --force
splat4d info "$OUT/spinner.safetensors"
echo "== done: view it with  .venv/bin/splat4d view $OUT/spinner.safetensors   (.venv/bin/splat4d view alone opens the bundled one)"
