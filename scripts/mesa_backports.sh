#!/usr/bin/env bash
# Unpacks Mesa's lavapipe from Debian 12's bookworm-backports (Mesa 25) into a
# folder of its own, beside the system's Mesa 22, for speed comparisons
# (docs/notebook.md, "Mesa versions"). Installs nothing system-wide. Prints the two
# variables that make a qtrace run use it:
#
#   eval "$(scripts/mesa_backports.sh)"   # then: qtrace devices
#
# DIR (default ~/.cache/qtrace/mesa-backports) holds the apt lists, the
# packages and the unpacked tree. Benchmarks only: tests never need it.
set -euo pipefail

dir="${DIR:-$HOME/.cache/qtrace/mesa-backports}"
mkdir -p "$dir/lists/partial" "$dir/cache/archives/partial" "$dir/debs" "$dir/root"
echo "deb http://deb.debian.org/debian bookworm-backports main" > "$dir/sources.list"
apt_opts=(
    -o "Dir::Etc::sourcelist=$dir/sources.list"
    -o "Dir::Etc::sourceparts=/dev/null"
    -o "Dir::State::Lists=$dir/lists"
    -o "Dir::Cache=$dir/cache"
    -o "APT::Sandbox::User=$(id -un)"
)

if [ ! -e "$dir/root/usr/share/vulkan/icd.d/lvp_icd.json" ]; then
    apt-get "${apt_opts[@]}" update >&2
    version=$(apt-cache "${apt_opts[@]}" policy mesa-vulkan-drivers |
        awk '/bpo/ && $1 ~ /^[0-9]/ { print $1; exit }')
    if [ -z "$version" ]; then
        echo "error: no mesa-vulkan-drivers in bookworm-backports" >&2
        exit 1
    fi
    # lavapipe, and the libdrm it was built against (newer than Debian 12's).
    (cd "$dir/debs" && apt-get "${apt_opts[@]}" download \
        "mesa-vulkan-drivers=$version" libdrm2/bookworm-backports >&2)
    for deb in "$dir"/debs/*.deb; do
        dpkg -x "$deb" "$dir/root"
    done
fi

lib="$dir/root/usr/lib/x86_64-linux-gnu"
icd="$dir/root/usr/share/vulkan/icd.d/lvp_icd.json"
# The ICD names its library without a path; point it at the unpacked one.
sed -i "s#\"library_path\": \"[^\"]*\"#\"library_path\": \"$lib/libvulkan_lvp.so\"#" "$icd"
echo "export VK_ICD_FILENAMES=$icd"
echo "export LD_LIBRARY_PATH=$lib"
