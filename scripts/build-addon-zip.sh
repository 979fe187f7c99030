#!/usr/bin/env bash
# Build the Blender add-on zip, target/sweptvol_addon.zip: the package folder sweptvol_addon/ at
# the zip's top level (what Blender 3.x "Install..." and 4.2+ "Install from Disk" both take).
# Usage: scripts/build-addon-zip.sh [OUT.zip]
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-target/sweptvol_addon.zip}"
mkdir -p "$(dirname "$out")"
python3 - "$out" <<'PY'
import os, sys, zipfile
out = sys.argv[1]
src = "blender_addon/sweptvol_addon"
tmp = out + ".tmp"
with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
    for name in sorted(os.listdir(src)):
        if name.endswith((".py", ".toml")):
            z.write(os.path.join(src, name), "sweptvol_addon/" + name)
os.replace(tmp, out)
print(out)
PY
