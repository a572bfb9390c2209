#!/usr/bin/env bash
# Install pfem2x's Debian 12 packages if any is missing (needs root or sudo).
set -euo pipefail
PKGS=(python3-dolfinx python3-gmsh python3-mpi4py python3-petsc4py
      python3-venv python3-pip make
      libgl1 libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libxrender1)  # headless VTK (pyvista PNG)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "pfem2x: installing Debian packages: ${missing[*]}" >&2
SUDO=""
if [ "$(id -u)" != 0 ]; then
  command -v sudo >/dev/null || { echo "error: need root or sudo to apt-get install ${missing[*]}" >&2; exit 1; }
  SUDO=sudo
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
