#!/usr/bin/env bash
# Do two builds write byte-identical outputs? For restructurings that must change no output.
#
#   scripts/same-outputs.sh REV        build REV (a commit) in a worktree under target/ and
#                                      compare it with this working tree's release build
#   scripts/same-outputs.sh OLD NEW    compare two sweptvol binaries
#
# Cases: the README example (bunny, 200 vibration poses, n = 128) and the assembly path at
# n = 96 with --keep-start-mesh, both on the CPU backend. Every .glb and .exr must match byte for
# byte; report.json must match once timings and the output folder's name are taken out.
# Exit 0 when all match, 1 otherwise (each difference is listed).
set -euo pipefail
cd "$(dirname "$0")/.."

if (($# == 1)); then
    rev=$(git rev-parse --short "$1")
    tree=target/same-outputs/$rev
    if [ ! -x "$tree/target/release/sweptvol" ]; then
        rm -rf "$tree"
        git worktree add --detach "$tree" "$rev" >/dev/null
        (cd "$tree" && cargo build --release --locked --quiet)
    fi
    cargo build --release --locked --quiet
    old=$tree/target/release/sweptvol new=target/release/sweptvol
elif (($# == 2)); then
    old=$1 new=$2
else
    sed -n 2,12p "$0"
    exit 2
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
run_case() { # binary, out dir, extra args...
    local bin=$1 out=$2
    shift 2
    "$bin" run --backend cpu --quiet --out "$out" "$@"
}
status=0
for which in old new; do
    bin=${!which}
    run_case "$bin" "$work/$which/vibration" --generator examples/bunny.glb \
        --trajectory examples/bunny-vibration.csv --resolution 128
    run_case "$bin" "$work/$which/assembly" --generator examples/bunny.glb \
        --trajectory examples/bunny-assembly.csv --resolution 96 --keep-start-mesh
done
for case in vibration assembly; do
    for f in "$work/old/$case"/*; do
        name=$(basename "$f")
        g="$work/new/$case/$name"
        if [ ! -f "$g" ]; then
            echo "$case/$name: missing from the new build's outputs"; status=1
        elif [[ $name == *.report.json ]]; then
            python3 - "$f" "$g" "$work/old/$case" "$work/new/$case" <<'EOF' || status=1
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
def clean(r, folder):
    r.pop("timings", None)
    r.get("classification", {}).pop("flood_seconds", None)  # a timing too
    return json.loads(json.dumps(r).replace(folder, "OUT"))
a, b = clean(a, sys.argv[3]), clean(b, sys.argv[4])
if a != b:
    keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    print(f"{sys.argv[1].rsplit('/', 2)[-2]}/{sys.argv[1].rsplit('/', 1)[-1]}: reports differ in {keys}")
    sys.exit(1)
EOF
        elif ! cmp -s "$f" "$g"; then
            echo "$case/$name: bytes differ"; status=1
        fi
    done
    extra=$(comm -13 <(ls "$work/old/$case") <(ls "$work/new/$case"))
    [ -z "$extra" ] || { echo "$case: new outputs $extra"; status=1; }
done
if ((status == 0)); then
    echo "same outputs: $(ls "$work/old/vibration" "$work/old/assembly" | grep -c '\.') files match ($old vs $new)"
fi
exit $status
