#!/usr/bin/env bash
# Regenerate the trained checkpoint shipped in samples/ (splatreel.samples.trained_checkpoint): the 'spinner' sample's
# default dataset, fitted with the default (auto) recipe at seed 0 for a fixed 3000 iterations (so the run is
# deterministic, not time-budgeted; about twice the steps a 5-minute run gets on 2 cores, though it scored the same,
# 27.82 dB) under the recipe's cap of 60k Gaussians (a file of about 4.5 MB). About 10 minutes on 2 cores.
# The dataset is named relatively, so a rebuild on the same software gives the same bytes. The shipped file is
# replaced only if the new one scores at least 23 dB PSNR on the sample's test views (on white, the D-NeRF
# convention; the same-camera nearest-image baseline scores 18.5 dB there).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
cd "$TMP"
splatreel sample spinner --out spinner
splatreel train spinner --out spinner.safetensors --seed 0 --iters 3000
splatreel eval spinner.safetensors spinner --out eval.json
python - <<'PY'
import json, sys
psnr = json.load(open("eval.json"))["psnr"]
if psnr < 23.0:
    sys.exit(f"bundle_sample: test PSNR {psnr:.2f} dB is below 23 dB; samples/ left unchanged")
PY
mv spinner.safetensors "$ROOT/samples/spinner.safetensors"
chmod 644 "$ROOT/samples/spinner.safetensors"
splatreel info "$ROOT/samples/spinner.safetensors"
