#!/usr/bin/env bash
# Shared set-up for scripts/demo.sh and scripts/test.sh (sourced, not run): system libraries through apt-get
# when missing, then a virtual environment in .venv with splatreel and its dev extras.
# Works on a fresh Debian machine with Python 3.11 and root; re-running it is cheap (it skips what is done).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

# --- system libraries: Mesa EGL/GL (llvmpipe) for headless rendering, Xvfb for the desktop-app tests ---------
APT_PACKAGES=(libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libgles2 xvfb xauth
              libx11-6 libxrandr2 libxinerama1 libxcursor1 libxi6 libxxf86vm1)
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    echo "splatreel setup: installing system packages: ${missing[*]}"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# --- Node.js for the glTF tests (the Khronos glTF-Validator is an npm package; tests/test_gltf.py installs it) ----
if ! command -v npm >/dev/null; then
    echo "splatreel setup: installing Node.js and npm"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi

# --- Python environment -----------------------------------------------------------------------------------
PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
if [ ! -x .venv/bin/python ]; then
    echo "splatreel setup: creating .venv with $($PYTHON --version)"
    "$PYTHON" -m venv .venv
fi
VENV_PY="$ROOT/.venv/bin/python"
# Reinstall only when the project's metadata changed (the stamp is the hash of pyproject.toml and this file).
stamp=".venv/.splatreel-installed"
want="$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "splatreel setup: installing Python packages into .venv (first run takes a few minutes)"
    "$VENV_PY" -m pip install -q --upgrade pip
    # Pinned CPU build: an unpinned torch would pull a multi-GB CUDA build.
    "$VENV_PY" -m pip install -q "torch==2.13.0"
    "$VENV_PY" -m pip install -q -e ".[dev]"
    echo "$want" > "$stamp"
fi
export PATH="$ROOT/.venv/bin:$PATH"
