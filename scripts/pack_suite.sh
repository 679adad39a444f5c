#!/usr/bin/env bash
# Packs the release qtrace binary and the test binaries, stripped, with the
# Vulkan loader and validation layer packages and a font for the bench's
# charts, into one archive, to run the suite on another x86-64 Linux
# machine (a GPU node, a machine without Rust) with
# scripts/run_packed_suite.sh. The tests find the repository and the
# qtrace binary at the absolute paths they were built with; the archive
# records them and the run script recreates them.
#
#   scripts/pack_suite.sh [OUT.tgz]          # default: target/suite.tgz
#
# Then, on the other machine, in a checkout of the same commit:
#   scripts/run_packed_suite.sh suite.tgz [SECONDS]
set -euo pipefail

repo=$(cd "$(dirname "$0")/.." && pwd)
out=$(realpath -m "${1:-$repo/target/suite.tgz}")
target="${CARGO_TARGET_DIR:-$repo/target}"
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/suite/tests" "$stage/suite/debs"

cd "$repo"
cargo build --release >&2
cargo test --release --no-run --message-format=json 2>/dev/null |
    python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["profile"]["test"]:
        print(m["executable"])
' > "$stage/exes"
while read -r exe; do
    strip -o "$stage/suite/tests/$(basename "$exe")" "$exe"
done < "$stage/exes"
strip -o "$stage/suite/qtrace" "$target/release/qtrace"
{
    echo "built_repo=$repo"
    echo "built_qtrace=$(realpath "$target/release/qtrace")"
    echo "built_commit=$(git rev-parse HEAD)"
} > "$stage/suite/paths"
# The Vulkan loader and validation layer, and glvnd's libraries, without
# which NVIDIA's Vulkan driver does not load on a node that has only the
# driver ("Could not get 'vkCreateInstance' via 'vk_icdGetInstanceProcAddr'").
(cd "$stage/suite/debs" && apt-get download libvulkan1 vulkan-validationlayers \
    libglvnd0 libegl1 libgl1 libglx0 libopengl0 libgles2 >&2)
# The bench's charts need a font, which a GPU node may lack.
font=/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf
if [ -e "$font" ]; then
    cp "$font" "$stage/suite/"
fi
mkdir -p "$(dirname "$out")"
tar czf "$out" -C "$stage" suite
echo "$out: $(ls "$stage/suite/tests" | wc -l) test binaries, $(du -h "$out" | cut -f1)"
