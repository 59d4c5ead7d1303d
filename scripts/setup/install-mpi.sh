#!/usr/bin/env bash
# Installs what `--features mpi` needs, from Debian's packages: Open MPI (the library, its headers
# and `mpirun`), pkg-config (how the `mpi` crate finds it) and libclang (the crate's bindgen reads
# mpi.h with it). Idempotent and quiet when everything is there already.
#
#   scripts/setup/install-mpi.sh
#
# Runs as root (CI) or through sudo when there is one. Open MPI refuses to run as root unless told:
# run `mpirun --allow-run-as-root …` or export OMPI_ALLOW_RUN_AS_ROOT=1 and
# OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 (scripts/test/test-mpi.sh does the latter).
set -euo pipefail

SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null; then
    SUDO="sudo"
fi

packages=(openmpi-bin libopenmpi-dev pkg-config libclang-dev clang)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ "${#missing[@]}" -eq 0 ]; then
    exit 0
fi

echo "install-mpi: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
