#!/usr/bin/env bash
# Runs the suite packed by scripts/pack_suite.sh on this machine, with the
# validation layer on, then a speed table of every method on three scenes.
# Run it as root in a checkout of the commit the archive was built from: it
# unpacks the Vulkan loader, the validation layer and glvnd's libraries
# into / (Debian 12's packages), and recreates the absolute paths the tests were built with:
# the repository, by a symbolic link to this checkout where nothing is
# there, and the qtrace binary, copied over whatever is at its path. Each
# test binary gets at most SECONDS (default 120); the whole log goes to
# $LOG (default suite.log). With EQUAL_TIME=DIR it then runs the bench at
# 1024x1024 and 1024 spp on the indirectly lit room, its report in DIR.
#
#   scripts/run_packed_suite.sh suite.tgz [SECONDS]
set -uo pipefail

pack=$(realpath "$1")
limit="${2:-120}"
checkout=$(cd "$(dirname "$0")/.." && pwd)
log=$(realpath -m "${LOG:-suite.log}")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
tar xzf "$pack" -C "$work"
. "$work/suite/paths"

# Always: a node may have a loader and NVIDIA's driver but not glvnd's
# libraries, and then no Vulkan device (an H200 node with Ubuntu 24.04 and
# driver 580 did); Debian's packages of them go into / beside the driver.
for deb in "$work"/suite/debs/*.deb; do dpkg -x "$deb" /; done
ldconfig
# NVIDIA's driver where the loader does not look for it (some containers).
nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -e "$nvidia_icd" ] &&
    ! ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | grep -q nvidia; then
    export VK_DRIVER_FILES="$nvidia_icd"
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
if [ -z "${QTRACE_FONT:-}" ] && [ ! -e /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] &&
    [ -e "$work/suite/DejaVuSans.ttf" ]; then
    export QTRACE_FONT="$work/suite/DejaVuSans.ttf"
fi
# The paths the tests were built with: the repository (this checkout, by a
# link, where nothing is there) and the qtrace binary.
if [ ! -e "$built_repo" ]; then
    mkdir -p "$(dirname "$built_repo")" && ln -s "$checkout" "$built_repo"
elif [ "$(realpath "$built_repo")" != "$checkout" ]; then
    echo "warning: the tests read $built_repo, not this checkout" | tee -a "$log"
fi
mkdir -p "$(dirname "$built_qtrace")" && cp "$work/suite/qtrace" "$built_qtrace"
cd "$checkout"
[ "$(git rev-parse HEAD 2>/dev/null)" = "$built_commit" ] ||
    echo "warning: this checkout is not $built_commit, which the suite was built from" | tee -a "$log"

"$built_qtrace" devices 2>&1 | tee -a "$log"
failed=0
for t in "$work"/suite/tests/*; do
    name=$(basename "$t" | sed 's/-[0-9a-f]*$//')
    echo "=== $name" >> "$log"
    QTRACE_VALIDATION=1 timeout "$limit" "$t" >> "$log" 2>&1
    rc=$?
    [ $rc -eq 0 ] || failed=$((failed + 1))
    echo "$name: exit $rc, $(grep -E "^test result" "$log" | tail -1)"
done
echo "=== speed" >> "$log"
"$built_qtrace" bench --speed --methods pt,pt+nee,sarsa,sarsa+nee,neural,neural+nee --repeats 3 \
    --peer none scenes/cornell-box.toml scenes/indirect-room.toml scenes/door-ajar.toml 2>&1 | tee -a "$log"
if [ -n "${EQUAL_TIME:-}" ]; then
    # On a fast GPU the bench's default size is over before the guides learn
    # (docs/notebook.md, "On a GPU"): equal time at 1024x1024 and 1024 spp instead.
    echo "=== equal time" >> "$log"
    "$built_qtrace" bench --methods pt,pt+nee,sarsa,sarsa+nee,neural,neural+nee \
        --width 1024 --height 1024 --spp-list 4,16,64,256,1024 --reference-spp 4096 \
        --out "${EQUAL_TIME}" scenes/indirect-room.toml 2>&1 | tee -a "$log"
fi
echo "$failed test binaries failed; log: $log"
[ $failed -eq 0 ]
