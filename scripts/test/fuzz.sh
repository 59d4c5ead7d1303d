#!/usr/bin/env bash
# The long fuzz run of every reader of outside data (issue 16): the fuzz_readers tests of nis,
# nis-render and nis-paper with NIS_FUZZ_CASES cases per target (default 20000; the normal
# `cargo test` runs a few hundred each). Prints one line per target (cases, accepted, rejected,
# peak of live bytes) and the total; exits non-zero on the first failing case, which proptest
# shrinks and prints.
#
#   NIS_FUZZ_CASES=200000 scripts/test/fuzz.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
export NIS_FUZZ_CASES=${NIS_FUZZ_CASES:-20000}
log=$(mktemp /tmp/nis-fuzz-XXXXXX.log)
started=$SECONDS
for crate in nis nis-render nis-paper; do
    set +e
    cargo test --release -q -p "$crate" --test fuzz_readers -- --nocapture --test-threads 1 2>&1 | tee -a "$log" \
        | grep -E 'fuzz [a-z-]+:|test result|panicked|minimal failing|memory allocation'
    status=${PIPESTATUS[0]}
    set -e
    if [ "$status" -ne 0 ]; then
        echo "fuzz: FAILED in $crate (log: $log)"
        exit 1
    fi
done
total=$(grep -oE 'fuzz [a-z-]+: [0-9]+ cases' "$log" | awk '{s += $3} END {print s}')
echo "fuzz: $total cases in $((SECONDS - started)) s with NIS_FUZZ_CASES=$NIS_FUZZ_CASES, no failure (log: $log)"
