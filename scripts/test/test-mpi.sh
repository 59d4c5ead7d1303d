#!/usr/bin/env bash
# The MPI tests: builds `nis` and the `mpi_ranks` example with the feature `mpi`
# (scripts/setup/build-mpi.sh, which installs Open MPI if needed), then runs
# crates/nis-cli/tests/mpi.rs, which starts them under `mpirun` with 1, 2 and 3 ranks.
#
#   scripts/test/test-mpi.sh
#
# Open MPI refuses root unless told (the variables below), and 3 ranks on 2 cores need
# --oversubscribe (the tests pass it).
set -euo pipefail
cd "$(dirname "$0")/../.."
started=$SECONDS

scripts/setup/build-mpi.sh
export NIS_MPI_BIN="$PWD/target/mpi/nis"
export NIS_MPI_EXAMPLE="$PWD/target/mpi/mpi_ranks"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
# One mpirun at a time: the ranks already fill the cores.
cargo test --release -p nis-cli --test mpi -- --ignored --test-threads 1
echo "scripts/test/test-mpi.sh: $((SECONDS - started)) s" >&2
