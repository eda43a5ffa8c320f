#!/usr/bin/env bash
# PDE Head demo: install the pinned requirements, then build the phantom head headless into demo/.
# Writes demo/phantom.blend (+ demo/pdehead_vdb/*.vdb beside it), demo/surface.png and demo/volume.png.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
"$PYTHON" -m pip install -q --disable-pip-version-check -r requirements.txt
mkdir -p demo
exec "$PYTHON" scripts/pdehead.py --phantom --patches 10 --out demo/phantom.blend \
    --render demo/surface.png --render-volume demo/volume.png "$@"
