# Sourced by scripts/test.sh, scripts/demo.sh and .ci/run: the project's virtual environments.
#
# One venv per Blender version, in a cache folder outside the clone (never the system Python):
#   ${PDEHEAD_CACHE:-${XDG_CACHE_HOME:-~/.cache}/pdehead}/venv-bpy<version>-py<python>
# created when absent, reused when present; a fresh machine downloads each bpy once (~0.8 GB).
# Each gets requirements.txt with its own bpy and numpy pins (the numpy that Blender bundles)
# and the engine as an editable install (pyproject.toml), so `import pdehead_addon` works from
# any folder with that venv's python.

PDEHEAD_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PDEHEAD_CACHE="${PDEHEAD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/pdehead}"

# Blender version -> Python and numpy it embeds (bpy from PyPI pins Python; numpy as in Blender).
pdehead_leg_python() { case "$1" in 4.*|5.0.*) echo 3.11 ;; *) echo 3.13 ;; esac; }
pdehead_leg_numpy() { case "$1" in 4.*|5.0.*) echo 1.26.4 ;; 5.3.0) echo 2.5.5 ;; *) echo "" ;; esac; }

pdehead_find_python() {  # an interpreter for Python $1 (e.g. 3.13): PATH, then pyenv
    local want="$1" cand
    for cand in "python$want" "$(command -v pyenv >/dev/null 2>&1 && pyenv root)/versions/$want"*/bin/"python$want"; do
        if command -v "$cand" >/dev/null 2>&1 && [ "$("$cand" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" = "$want" ]; then
            command -v "$cand"; return 0
        fi
    done
    echo "no Python $want found (needed for bpy $2): install it, e.g. 'pyenv install $want'" >&2
    return 1
}

# pdehead_venv BPY_VERSION -> prints the venv folder, ready to use (set-up output goes to stderr)
pdehead_venv() {
    local bpy="$1" py numpy dir base reqs stamp
    py="$(pdehead_leg_python "$bpy")"
    numpy="$(pdehead_leg_numpy "$bpy")"
    dir="$PDEHEAD_CACHE/venv-bpy$bpy-py${py/./}"
    if [ ! -x "$dir/bin/python" ]; then
        base="$(pdehead_find_python "$py" "$bpy")" || return 1
        echo "[pdehead] creating $dir (Python $py, bpy $bpy)" >&2
        mkdir -p "$PDEHEAD_CACHE"
        "$base" -m venv "$dir" >&2 || return 1
    fi
    # requirements.txt with this leg's bpy (and numpy) instead of the default ones
    reqs="$(grep -vE '^(bpy|numpy)==' "$PDEHEAD_ROOT/requirements.txt"; echo "bpy==$bpy"; [ -n "$numpy" ] && echo "numpy==$numpy")"
    stamp="$dir/.pdehead-requirements"
    if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$reqs" ]; then
        echo "[pdehead] installing the pinned requirements into $dir" >&2
        "$dir/bin/python" -m pip install -q --disable-pip-version-check -r /dev/stdin <<<"$reqs" >&2 || return 1
        printf '%s' "$reqs" >"$stamp"
    fi
    # the engine, editable, from this clone (again when the venv last pointed at another clone)
    if [ "$(cd / && "$dir/bin/python" -c 'import os, pdehead_addon as m; print(os.path.dirname(os.path.dirname(os.path.abspath(m.__file__))))' 2>/dev/null)" != "$PDEHEAD_ROOT" ]; then
        echo "[pdehead] editable install of the engine from $PDEHEAD_ROOT into $dir" >&2
        "$dir/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e "$PDEHEAD_ROOT" >&2 || return 1
    fi
    echo "$dir"
}
