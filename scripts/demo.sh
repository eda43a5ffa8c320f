#!/usr/bin/env bash
# PDE Head demo: set up the project venv (bpy 5.0.1, outside the clone; see scripts/venv.sh), then
# build the phantom head headless into demo/: demo/phantom.blend (+ demo/pdehead_vdb/*.vdb beside
# it), demo/surface.png and demo/volume.png. Extra arguments go to scripts/pdehead.py.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
VENV="$(pdehead_venv "${PDEHEAD_BPY:-5.0.1}")"
echo "[pdehead] Python with the engine and Blender: $VENV/bin/python"
mkdir -p demo
exec "$VENV/bin/python" scripts/pdehead.py --phantom --patches 10 --out demo/phantom.blend \
    --render demo/surface.png --render-volume demo/volume.png "$@"
