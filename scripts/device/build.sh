#!/usr/bin/env bash
# Builds what scripts/device/check.sh runs on the GPU machine (which has no Rust toolchain):
# the `nis` binary with the GPU back end and the GPU test executable, stripped, into
# target/device (carried there by the device tool).
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p nis-cli --features cuda
exe=$(cargo test --release -p nis-cuda --test gpu --no-run --message-format=json \
  | python3 -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["name"] == "gpu":
        print(m["executable"])')
mkdir -p target/device
cp target/release/nis target/device/nis
cp "$exe" target/device/gpu-tests
strip target/device/nis target/device/gpu-tests
ls -la target/device
