#!/usr/bin/env bash
# MadNIS's multi-channel integrator against nis on the built-in multi-channel examples (same
# maps, same priors, all evaluations counted), in a venv of its own under target/bench-py
# (MadNIS pulls PyTorch: a large download on first use). Writes its section of
# docs/results/integration.md (between <!-- madnis-channels:start --> and
# <!-- madnis-channels:end -->).
#
#   scripts/bench/bench-madnis-channels.sh [--seeds 3] [--evals 1000000] [--only dalitz ...]
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/bench-py/madnis-channels
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --disable-pip-version-check numpy "madnis==1.0.*" "maturin>=1.9,<2"
PATH="$PWD/$venv/bin:$PATH" CARGO_TARGET_DIR="$PWD/target/py" "$venv/bin/python" -m pip install -q \
    --disable-pip-version-check --no-build-isolation --force-reinstall --no-deps ./crates/nis-py
"$venv/bin/python" scripts/bench/bench-madnis-channels.py "$@"
