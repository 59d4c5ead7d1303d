#!/usr/bin/env bash
# Our VEGAS+ against the `vegas` package (its own venv under target/bench-py/vegas, made on
# first use) on every suite integrand, 3 seeds, 10^6 evaluations each; writes its section of
# docs/results/integration.md (between <!-- vegas:start --> and <!-- vegas:end -->).
#
#   scripts/bench/bench-vegas.sh [--evals 1000000] [--seeds 3] [--only camel-sharp peaks]
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p nis-cli
python=$(scripts/setup/vegas-venv.sh)
"$python" scripts/bench/bench-vegas.py --cli target/release/nis "$@"
