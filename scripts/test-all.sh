#!/usr/bin/env bash
# Set up a fresh Debian machine for sweptvol's tests and run every one of them.
# Installs (only what is missing): lavapipe, the Vulkan loader, SLURM and munge, Node and npm, a Python venv with
# the independent EXR reader, pytest, trimesh and manifold3d, the Khronos glTF validator, Blender (Debian's 3.4). Then:
# format, lints, all tests (GPU path on lavapipe), the example, the Blender add-on's tests.
set -euo pipefail
cd "$(dirname "$0")/.."

# Each section's wall time is printed when the next one starts, and all of them at the end
# (CI's budget is 30 minutes: this says where it goes).
section=""
section_from=$SECONDS
timings=()
took() {
    if [ -n "$section" ]; then
        timings+=("$(printf '%5ds  %s' $((SECONDS - section_from)) "${section:0:90}")")
        printf '    (%d s)\n' $((SECONDS - section_from))
    fi
}
say() {
    took
    section="$*"
    section_from=$SECONDS
    printf '\n==> %s\n' "$*"
}
sudo_() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

apt_install() {
    # The image deletes apt's cache under concurrent runs: use a private one, wait for the lock.
    mkdir -p /tmp/apt-cache/partial
    sudo_ apt-get update -qq
    sudo_ env DEBIAN_FRONTEND=noninteractive apt-get install -y -q -o DPkg::Lock::Timeout=600 \
        -o Dir::Cache::Archives=/tmp/apt-cache "$@" ||
        { sudo_ apt-get -f install -y -q && sudo_ env DEBIAN_FRONTEND=noninteractive apt-get install -y -q \
            -o DPkg::Lock::Timeout=600 -o Dir::Cache::Archives=/tmp/apt-cache "$@"; }
}

say "system packages"
missing=()
for p in mesa-vulkan-drivers libvulkan1 blender slurm-wlm munge; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
python3 -m venv --help >/dev/null 2>&1 || missing+=(python3-venv)
command -v node >/dev/null 2>&1 || missing+=(nodejs)
command -v npm >/dev/null 2>&1 || missing+=(npm)
if ((${#missing[@]})); then apt_install "${missing[@]}"; else echo "all present"; fi

say "Python venv: the independent EXR reader, pytest, trimesh and manifold3d (downstream-tool check), ruff"
venv=target/test-venv
if ! "$venv/bin/python" -c 'import OpenEXR, numpy, pytest, trimesh, manifold3d, ruff' 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q --disable-pip-version-check OpenEXR numpy pytest trimesh manifold3d ruff
fi

say "Khronos glTF validator (npm)"
(cd tools/gltf-validator && npm ci --silent --no-audit --no-fund)

export SWEPTVOL_TEST_PYTHON="$PWD/$venv/bin/python"
export SWEPTVOL_REQUIRE_GPU=1     # a missing adapter fails the GPU tests instead of skipping
export SWEPTVOL_REQUIRE_PYTHON=1  # likewise for the independent EXR reader
export SWEPTVOL_REQUIRE_VALIDATOR=1  # and for the glTF validator
export SWEPTVOL_BIN="$PWD/target/release/sweptvol"  # the add-on's pytest files start this one
export SWEPTVOL_REQUIRE_BIN=1     # and fail, not skip, where it is missing
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/xdg-runtime-$(id -u)}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"

say "format, lints and docs"
cargo fmt --all -- --check
cargo clippy --all-targets --locked -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --locked --quiet  # a renamed item breaks a doc link
"$venv/bin/python" -m ruff check blender_addon tests/*.py  # the Python side (ruff.toml)

say "a one-machine SLURM cluster for the cluster tests (stopped at exit)"
trap 'scripts/slurm-local.sh stop' EXIT
eval "$(scripts/slurm-local.sh start)"
export SWEPTVOL_REQUIRE_SLURM=1   # tests/slurm.rs fails, not skips, without it
sinfo

say "tests (GPU path on whatever adapter wgpu finds: lavapipe here; SLURM on this machine)"
cargo test --all-targets --locked

say "the README's example"
cargo run --release --locked -- run --generator examples/bunny.glb \
    --trajectory examples/bunny-vibration.csv --out target/example-results --resolution 128 --overwrite --quiet
ls target/example-results
node tools/gltf-validator/validate.mjs target/example-results/bunny-vibration.swept.glb

say "the example's mesh is a solid to trimesh and manifold3d (no repair)"
"$venv/bin/python" tests/manifold_check.py target/example-results/bunny-vibration.swept.glb

say "the example's mesh, certified by verify (containment; the run's own bound, everywhere: the bunny is closed, so the flood classification leaves no pocket filled)"
read -r bound method < <("$venv/bin/python" -c 'import json, sys; r = json.load(open(sys.argv[1])); print(r["mesh"]["hausdorff_bound"], r["classification"]["method"])' \
    target/example-results/bunny-vibration.report.json)
[ "$method" = flood ] || { echo "the bundled example was classified by '$method', not flood" >&2; exit 1; }
target/release/sweptvol verify --generator examples/bunny.glb --trajectory examples/bunny-vibration.csv \
    --mesh target/example-results/bunny-vibration.swept.glb --bound "$bound" --quiet

say "clearance of the example's mesh from the bundled housing (examples/make_housing.py): every wall clear, the map valid glTF"
target/release/sweptvol clearance --mesh target/example-results/bunny-vibration.swept.glb \
    --report target/example-results/bunny-vibration.report.json --against examples/bunny-housing.glb \
    --require-clearance 0.2 --overwrite
node tools/gltf-validator/validate.mjs target/example-results/bunny-vibration.bunny-housing.clearance.glb

say "the gear example (examples/make_gear.py): the bundled file is the script's output, and its sweep along the assembly path is certified by verify with the run's own bound"
"$venv/bin/python" examples/make_gear.py --out target/example-results/gear.glb
cmp examples/gear.glb target/example-results/gear.glb
target/release/sweptvol run --generator examples/gear.glb --trajectory examples/bunny-assembly.csv \
    --name gear-assembly --out target/example-results --resolution 128 --motion discrete --overwrite --quiet
read -r bound < <("$venv/bin/python" -c 'import json, sys; print(json.load(open(sys.argv[1]))["mesh"]["hausdorff_bound"])' \
    target/example-results/gear-assembly.report.json)
"$venv/bin/python" tests/manifold_check.py target/example-results/gear-assembly.swept.glb
target/release/sweptvol verify --generator examples/gear.glb --trajectory examples/bunny-assembly.csv \
    --mesh target/example-results/gear-assembly.swept.glb --bound "$bound" --motion discrete --quiet

say "Blender add-on: exchange, daemon control, version handling, names vs the binary's (pytest, no Blender)"
"$venv/bin/python" -m pytest -q -p no:cacheprovider blender_addon/tests/test_exchange.py \
    blender_addon/tests/test_compat.py blender_addon/tests/test_daemon.py blender_addon/tests/test_sampling.py \
    blender_addon/tests/test_protocol_names.py

say "Blender add-on: Blender 3.4, 4.2, 4.5, 5.0, legacy and extension installs, headless, real daemon"
# Debian's Blender 3.4 needs numpy (the add-on and its glTF exporter import it); the PyPI bpy
# wheels (4.2+, cached outside the repo by setup-bpy.sh) need these X11/GL libraries.
blender_libs=()
for p in python3-numpy libxi6 libxxf86vm1 libxfixes3 libxrender1 libgl1 libsm6 libxkbcommon0; do
    dpkg -s "$p" >/dev/null 2>&1 || blender_libs+=("$p")
done
if ((${#blender_libs[@]})); then apt_install "${blender_libs[@]}"; fi
blender_addon/tests/run-e2e-all.sh target/release/sweptvol
took
printf '\n==> every test passed; wall time by section:\n'
printf '%s\n' "${timings[@]}"
printf '%5ds  in all\n' "$SECONDS"
