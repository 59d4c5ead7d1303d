#!/usr/bin/env bash
# The MPI benchmark: strong scaling 1 vs 2 ranks, communication per training step, and the
# scaling model (docs/results/scaling.md, sections `mpi` and `scaling-model`). Builds what it needs with
# scripts/setup/build-mpi.sh. A few minutes on 2 cores.
#
#   scripts/bench/bench-mpi.sh [--runs 3]
set -euo pipefail
cd "$(dirname "$0")/../.."
scripts/setup/build-mpi.sh
cargo build --release -p nis-cli
target/release/nis bench mpi --mpi-nis target/mpi/nis --mpi-example target/mpi/mpi_ranks "$@"
