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
  patchelf binutils xz-utils                 # make dist (scripts/dist.sh) and the test that unpacks it
  slurm-wlm munge                            # the one-node render farm tests/farm.rs starts (issue #20)
  python3 python3-venv                       # the venv openjd-cli (PyPI) is installed into, below
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing Debian packages: ${missing[*]}" >&2
  if [ "$(id -u)" -ne 0 ]; then
    SUDO=sudo
  else
    SUDO=
  fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
  # The packages' own daemons are not ours: tests/farm.rs starts its own munged, slurmctld
  # and slurmd with their own keys, ports and state (scripts/farm/slurm-local.sh).
fi
# openjd-cli, which runs the Open Job Description template on one machine (tests/farm.rs),
# from PyPI into its own venv.
openjd_venv=${NIMBUS_OPENJD_VENV:-$HOME/.cache/nimbus/openjd}
if [ ! -x "$openjd_venv/bin/openjd" ]; then
  echo "installing openjd-cli into $openjd_venv" >&2
  python3 -m venv "$openjd_venv"
  "$openjd_venv/bin/pip" install -q openjd-cli
fi
