#!/usr/bin/env bash
# Regenerate the trained checkpoint shipped in samples/ (splat4d.samples.trained_checkpoint): the 'spinner' sample's
# default dataset, fitted with the efficient4d preset at seed 0. About 2-3 minutes on 2 cores.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
splat4d sample spinner "$TMP/spinner"
splat4d train "$TMP/spinner" --out "$TMP/spinner.safetensors" --preset efficient4d --seed 0
splat4d eval "$TMP/spinner.safetensors" "$TMP/spinner" --json "$TMP/eval.json"
mv "$TMP/spinner.safetensors" "$ROOT/samples/spinner.safetensors"
splat4d info "$ROOT/samples/spinner.safetensors"
