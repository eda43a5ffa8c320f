#!/usr/bin/env bash
# Set up a fresh machine and run the whole test suite (engine and real Blender).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
"$PYTHON" -m pip install -q --disable-pip-version-check -r requirements.txt
exec "$PYTHON" -m pytest tests "$@"
