#!/usr/bin/env bash
# Install splat4d and run the main job on the bundled procedural sample.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
OUT="${OUT:-out/demo}"
mkdir -p "$OUT"
echo "== generating the 'spinner' sample (16 views x 16 frames, D-NeRF layout) in $OUT/spinner"
splat4d sample spinner "$OUT/spinner" --model "$OUT/spinner.safetensors" --force
echo "== the 4D Gaussian model built from it"
splat4d info "$OUT/spinner.safetensors"
