#!/usr/bin/env bash
# The add-on's real-Blender test: builds the add-on zip, installs it into a fresh Blender profile
# and runs blender_e2e.py headless against a real `sweptvol watch` daemon (CPU backend).
# Usage: blender_addon/tests/run-e2e.sh [SWEPTVOL_BINARY]   (default: target/release/sweptvol)
set -euo pipefail
cd "$(dirname "$0")/../.."
binary="${1:-target/release/sweptvol}"
blender="${BLENDER:-blender}"
[ -x "$binary" ] || { echo "no sweptvol binary at $binary (cargo build --release)" >&2; exit 1; }
scripts/build-addon-zip.sh target/sweptvol_addon.zip >/dev/null
work="$(mktemp -d "${TMPDIR:-/tmp}/sweptvol-e2e.XXXXXX")"
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/user-scripts" "$work/config"
# A fresh profile: add-ons install into $work/user-scripts, preferences are never saved.
BLENDER_USER_SCRIPTS="$work/user-scripts" BLENDER_USER_CONFIG="$work/config" \
    timeout 600 "$blender" -b --factory-startup --python-exit-code 1 \
    --python blender_addon/tests/blender_e2e.py -- \
    --zip target/sweptvol_addon.zip --binary "$binary" --work "$work"
