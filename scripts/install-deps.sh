#!/usr/bin/env bash
# Installs the Debian packages nimbus builds and tests against, only those missing.
# Needs root (apt-get); does nothing when everything is already there.
set -euo pipefail
packages=(
  libopenvdb-dev libboost-dev libclang-dev   # the OpenVDB bridge: headers, bindgen's libclang
  mesa-vulkan-drivers libvulkan1             # lavapipe: the software Vulkan adapter GPU tests run on
  libopenvdb-tools python3-openvdb openexr   # independent readers the tests check our files with
  fonts-dejavu-core                          # the font nimbus-bench labels its plot with
  g++ pkg-config make
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
echo "installing Debian packages: ${missing[*]}" >&2
if [ "$(id -u)" -ne 0 ]; then
  SUDO=sudo
else
  SUDO=
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
