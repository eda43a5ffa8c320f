#!/usr/bin/env bash
# Run tests in real Blender (bpy from PyPI) in the project venv of one Blender version.
#   bash scripts/test.sh                       # the whole suite on bpy 5.0.1 (Python 3.11)
#   PDEHEAD_BPY=5.3.0 bash scripts/test.sh tests/blender -q   # another Blender, other pytest args
# The venv (outside the clone, see scripts/venv.sh) is created and filled on first use.
# The whole test matrix over every supported Blender is .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/venv.sh
VENV="$(pdehead_venv "${PDEHEAD_BPY:-5.0.1}")"
if [ "$#" -eq 0 ]; then set -- tests; fi
exec "$VENV/bin/python" -m pytest "$@"
