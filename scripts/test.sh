#!/usr/bin/env bash
# Install everything the tests need (system libraries, .venv) and run the test suite.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k cameras`.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
exec "$VENV_PY" -m pytest -q "$@"
