#!/usr/bin/env bash
# The add-on on every Blender it supports, both install modes, headless, against a real daemon:
#   Blender 3.4 (Debian's `blender -b`): legacy zip install;
#   Blender 4.2 LTS, 4.5 LTS, 5.0 (PyPI's bpy wheels, venvs made once per machine by
#   setup-bpy.sh under ${SWEPTVOL_CACHE:-~/.cache/sweptvol}): legacy install and extension install,
#   after Blender's own extension validator (each wheel's blender_ext.py validate) passes on the
#   package folder and on the zip.
# Runs one Blender at a time and fails (never skips) if any version cannot run.
# Usage: blender_addon/tests/run-e2e-all.sh [SWEPTVOL_BINARY]
# Environment: SWEPTVOL_BPY_SERIES (default "4.2 4.5 5.0"), BLENDER (default blender).
set -euo pipefail
cd "$(dirname "$0")/../.."
binary="${1:-target/release/sweptvol}"
series=(${SWEPTVOL_BPY_SERIES:-4.2 4.5 5.0})
command -v "${BLENDER:-blender}" >/dev/null || { echo "no Blender 3.4 (${BLENDER:-blender})" >&2; exit 1; }
mapfile -t pythons < <(blender_addon/tests/setup-bpy.sh "${series[@]}")
[ "${#pythons[@]}" = "${#series[@]}" ] || { echo "setup-bpy.sh did not give a python per series" >&2; exit 1; }
scripts/build-addon-zip.sh target/sweptvol_addon.zip >/dev/null
results=()
run() {  # label, then env assignments for run-e2e.sh
    local label="$1" t0 rc=0
    shift
    echo "--- e2e: $label"
    t0=$(date +%s)
    env "$@" blender_addon/tests/run-e2e.sh "$binary" || rc=$?
    results+=("$label: $([ "$rc" = 0 ] && echo PASS || echo FAIL) in $(($(date +%s) - t0)) s")
    return "$rc"
}
fail=0
blender_version=$("${BLENDER:-blender}" --version 2>/dev/null | head -1)
run "$blender_version (blender -b), legacy install" E2E_MODE=legacy || fail=1
for i in "${!series[@]}"; do
    py="${pythons[$i]}"
    version=$(timeout -k 5 120 "$py" -c 'import bpy, os, sys; sys.stdout.write(bpy.app.version_string); sys.stdout.flush(); os._exit(0)')
    case "$version" in
        "${series[$i]}".*) ;;
        *) echo "the bpy-${series[$i]} venv holds Blender $version" >&2; results+=("bpy-${series[$i]}: holds $version"); fail=1; continue ;;
    esac
    validator=$(find "$(dirname "$(dirname "$py")")" -path '*/addons_core/bl_pkg/cli/blender_ext.py' | head -1)
    echo "--- extension validate with Blender $version's validator"
    if [ -z "$validator" ]; then
        echo "no blender_ext.py in the bpy $version wheel" >&2
        results+=("bpy $version: extension validate: NOT FOUND"); fail=1
    elif "$py" "$validator" validate blender_addon/sweptvol_addon &&
         "$py" "$validator" validate target/sweptvol_addon.zip; then
        results+=("bpy $version: extension validate: PASS")
    else
        results+=("bpy $version: extension validate: FAIL"); fail=1
    fi
    for mode in legacy extension; do
        run "bpy $version, $mode install" BPY_PYTHON="$py" E2E_MODE="$mode" || fail=1
    done
done
echo
echo "Blender add-on e2e summary:"
printf '  %s\n' "${results[@]}"
exit "$fail"
