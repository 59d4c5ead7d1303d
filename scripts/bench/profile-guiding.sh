#!/usr/bin/env bash
# Where a guided render's time goes (docs/results/guiding.md): samples `nis render` with perf on one
# thread and sorts the samples into the guide's stages and the kernels they run in. The binary
# is a release build with frame pointers (built here into target/profiling), so that perf walks
# every stack whole: DWARF unwinding copies 32 KiB of stack per sample and cut the deep network
# stacks short, which hid a third of them from their stage.
#
#   scripts/bench/profile-guiding.sh [SCENE] [RES] [SPP] [GUIDE]   (default: cornell-box 128 64 nis-kl)
#   GUIDE_CONFIG='{"hidden_width": 16}' scripts/bench/profile-guiding.sh   (a --guide-config for the render)
#
# Needs `perf` (Debian: apt-get install linux-perf).
set -euo pipefail
scene=${1:-cornell-box}; res=${2:-128}; spp=${3:-64}; guide=${4:-nis-kl}
root=$(cd "$(dirname "$0")/../.." && pwd)
RUSTFLAGS="-C force-frame-pointers=yes" cargo build --release -q -p nis-cli \
  --manifest-path "$root/Cargo.toml" --target-dir "$root/target/profiling"
nis=$root/target/profiling/release/nis
work=$(mktemp -d /tmp/profile-guiding-XXXXXX)
trap 'rm -rf "$work"' EXIT
perf record -q -F 999 --call-graph fp -o "$work/perf.data" \
  "$nis" render "$scene" --res "$res" --spp "$spp" --guide "$guide" --threads 1 ${GUIDE_CONFIG:+--guide-config "$GUIDE_CONFIG"} \
  --out "$work/render.exr" >/dev/null
perf script -i "$work/perf.data" -F comm,tid,ip,sym 2>/dev/null > "$work/stacks.txt"
python3 "$root/scripts/bench/profile-breakdown.py" "$work/stacks.txt"
