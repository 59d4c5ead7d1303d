#!/usr/bin/env bash
# Installs the system packages the tests need beyond the Rust toolchain, from Debian's packages:
# a C compiler (the C examples of crates/nis-c) and gfortran (its Fortran example; the test skips
# it with a message when gfortran is missing). Idempotent: installs only what is not on PATH.
# Runs as root (CI) or through sudo when there is one.
set -euo pipefail

SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null; then
    SUDO="sudo"
fi

missing=()
command -v cc >/dev/null || missing+=(gcc libc6-dev)
command -v gfortran >/dev/null || missing+=(gfortran)

if [ "${#missing[@]}" -eq 0 ]; then
    echo "install-system-deps: cc and gfortran are installed"
    exit 0
fi

echo "install-system-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
