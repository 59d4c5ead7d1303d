#!/usr/bin/env bash
# Builds what runs under `mpirun`: installs Open MPI if needed (scripts/setup/install-mpi.sh), builds
# `nis` with the feature `mpi` and the library's `mpi_ranks` example, and copies them to
# target/mpi/nis and target/mpi/mpi_ranks.
#
#   scripts/setup/build-mpi.sh
#
# The build shares target/ with the default one: third-party crates are built once, only the
# workspace's crates twice (their artifacts with and without the feature have distinct hashes and
# live side by side). The copies are needed because target/release/nis is the default build's
# name and the next default build takes it back.
set -euo pipefail
cd "$(dirname "$0")/../.."

scripts/setup/install-mpi.sh
executable() {  # the path of executable $1 that `cargo build --message-format=json` reports
    python3 -c 'import json, sys
path = None
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["name"] == sys.argv[1]:
        path = m["executable"]
if path is None:
    sys.exit("build-mpi: cargo reported no executable " + sys.argv[1])
print(path)' "$1"
}
mkdir -p target/mpi
# One invocation for both, so that their dependencies' features unify as in the CLI's build.
json=$(cargo build --release -p nis-cli -p nis --features nis-cli/mpi --bin nis --example mpi_ranks \
    --message-format=json-render-diagnostics)
cp "$(executable nis <<<"$json")" target/mpi/nis
cp "$(executable mpi_ranks <<<"$json")" target/mpi/mpi_ranks
