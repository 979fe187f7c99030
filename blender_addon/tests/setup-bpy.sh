#!/usr/bin/env bash
# Make (once per machine) a venv with PyPI's `bpy` wheel (Blender as a Python module) for each
# Blender series asked for, outside the repository so a fresh clone reuses it:
#     ${SWEPTVOL_CACHE:-$HOME/.cache/sweptvol}/bpy-<series>    (e.g. bpy-4.2, bpy-4.5, bpy-5.0)
# A venv is (re)made only if `import bpy` fails in it. Prints each venv's python.
# Usage: blender_addon/tests/setup-bpy.sh 4.2 4.5 5.0
set -euo pipefail
cache="${SWEPTVOL_CACHE:-$HOME/.cache/sweptvol}"
py="${SWEPTVOL_BPY_PYTHON:-python3}"  # the wheels are built for CPython 3.11
mkdir -p "$cache"
for series in "$@"; do
    venv="$cache/bpy-$series"
    # os._exit: the bpy module may crash or hang at interpreter exit (see blender_e2e.py)
    probe=(timeout -k 5 120 "$venv/bin/python" -c 'import bpy, os; os._exit(0)')
    if "${probe[@]}" >/dev/null 2>&1; then
        echo "$venv/bin/python"
        continue
    fi
    echo "setup-bpy: installing bpy==$series.* into $venv" >&2
    rm -rf "$venv"
    "$py" -m venv "$venv"
    "$venv/bin/pip" install -q --disable-pip-version-check "bpy==$series.*" >&2
    if ! "${probe[@]}" >&2; then
        echo "setup-bpy: bpy $series installed but cannot be imported (missing X11/GL libraries?)" >&2
        exit 1
    fi
    echo "$venv/bin/python"
done
