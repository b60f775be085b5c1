#!/usr/bin/env bash
# Installs the Debian bookworm packages isouq needs to build, test and benchmark.
# Idempotent; run as root. Skips apt entirely when everything is already there.
#   scripts/install-deps.sh [--fuzz]   --fuzz: also clang-14 and libFuzzer (scripts/fuzz.sh)
set -euo pipefail
packages=(
  build-essential cmake ccache git
  libopenvdb-dev libboost-iostreams-dev libtbb-dev libopenexr-dev libblosc-dev
  catch2 libcli11-dev nlohmann-json3-dev libmuparser-dev libbenchmark-dev
  libnifti2-dev libteem-dev libtiff-dev libgdcm-dev libexpat1-dev
  libopenmpi-dev openmpi-bin
  slurmd slurmctld slurm-client munge  # the srun tests' own cluster; with no /etc/slurm/slurm.conf, Debian's units start no slurmd
  libopenvdb-tools
  python3 python3-numpy python3-matplotlib python3-pytest python3-skimage python3-meshio
  python3-openimageio python3-openvdb hyperfine strace
  python3-dev pybind11-dev libboost-python-dev
  python3-paraview python3-nibabel python3-pydicom python3-tifffile xvfb
  blender
)
if [ "${1:-}" = --fuzz ]; then
  packages+=(clang-14 libfuzzer-14-dev llvm-14)
fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "isouq: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq "${missing[@]}" >/dev/null
fi
