#!/usr/bin/env bash
# The add-on's interactive path in a real Blender window under Xvfb (not in CI: needs xvfb,
# apt-get install xvfb xauth). Usage: blender_addon/tests/run-ui-check.sh [SWEPTVOL_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
binary="${1:-target/release/sweptvol}"
scripts/build-addon-zip.sh target/sweptvol_addon.zip >/dev/null
work="$(mktemp -d "${TMPDIR:-/tmp}/sweptvol-ui.XXXXXX")"
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/user-scripts" "$work/config" "$work/jobs"
BLENDER_USER_SCRIPTS="$work/user-scripts" BLENDER_USER_CONFIG="$work/config" \
    timeout 300 xvfb-run -a -s "-screen 0 1280x800x24" "${BLENDER:-blender}" --factory-startup \
    --python blender_addon/tests/blender_ui_check.py -- target/sweptvol_addon.zip "$binary" "$work" \
    2>&1 | tee "$work/log"
grep -q "ui-check: PASS" "$work/log" || exit 1
if grep -q "Traceback" "$work/log"; then echo "ui-check: a Python traceback in Blender's output" >&2; exit 1; fi
