#!/usr/bin/env bash
# The add-on's real-Blender test: builds the add-on zip, installs it into a fresh Blender profile
# and runs blender_e2e.py headless against a real `sweptvol watch` daemon (CPU backend).
# Usage: blender_addon/tests/run-e2e.sh [SWEPTVOL_BINARY]   (default: target/release/sweptvol)
# Environment:
#   BLENDER=blender       the Blender to run as `blender -b` (default), or
#   BPY_PYTHON=PYTHON     a python whose `import bpy` is PyPI's bpy wheel (then BLENDER is unused)
#   E2E_MODE=legacy       how to install: legacy (addon_install + addon_enable) or extension (4.2+)
#   E2E_TIMEOUT=240       seconds before the run is killed (a hang at exit counts as a failure)
# Passes only if the script printed `e2e: PASS`, exited 0 and no Python traceback was printed.
set -euo pipefail
cd "$(dirname "$0")/../.."
binary="${1:-target/release/sweptvol}"
mode="${E2E_MODE:-legacy}"
limit="${E2E_TIMEOUT:-240}"
[ -x "$binary" ] || { echo "no sweptvol binary at $binary (cargo build --release)" >&2; exit 1; }
scripts/build-addon-zip.sh target/sweptvol_addon.zip >/dev/null
work="$(mktemp -d "${TMPDIR:-/tmp}/sweptvol-e2e.XXXXXX")"
stop_daemon() {  # a daemon a failed run left behind: stop it by the pid in its heartbeat
    local pid
    pid=$(python3 -c 'import json, sys
try:
    d = json.load(open(sys.argv[1]))
    print(d.get("pid", "") if d.get("state") != "stopped" else "")
except Exception:
    pass' "$work/jobs/.sweptvol/daemon.json" 2>/dev/null || true)
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then kill "$pid" 2>/dev/null || true; sleep 1; fi
}
trap 'stop_daemon; rm -rf "$work"' EXIT
mkdir -p "$work/user-scripts" "$work/config" "$work/extensions"
# A fresh profile: add-ons and extensions install under $work, preferences are never saved.
export BLENDER_USER_SCRIPTS="$work/user-scripts" BLENDER_USER_CONFIG="$work/config" \
    BLENDER_USER_EXTENSIONS="$work/extensions"
script_args=(--zip target/sweptvol_addon.zip --binary "$binary" --work "$work" --mode "$mode")
if [ -n "${BPY_PYTHON:-}" ]; then
    host=("$BPY_PYTHON" blender_addon/tests/blender_e2e.py "${script_args[@]}")
else
    host=("${BLENDER:-blender}" -b --factory-startup --python-exit-code 1
          --python blender_addon/tests/blender_e2e.py -- "${script_args[@]}")
fi
rc=0
# To a file, shown afterwards: a pipe into tee could be held open by a stray child process.
timeout -k 10 "$limit" "${host[@]}" > "$work/log" 2>&1 || rc=$?
cat "$work/log"
if [ "$rc" = 124 ] || [ "$rc" = 137 ]; then
    echo "e2e ($mode, ${BPY_PYTHON:-${BLENDER:-blender}}): killed after $limit s" >&2; exit 1
fi
grep -q "^e2e: PASS" "$work/log" || { echo "e2e ($mode): no PASS verdict (exit $rc)" >&2; exit 1; }
[ "$rc" = 0 ] || { echo "e2e ($mode): PASS printed but exit status $rc" >&2; exit 1; }
if grep -q "Traceback" "$work/log"; then
    echo "e2e ($mode): a Python traceback in Blender's output" >&2; exit 1
fi
