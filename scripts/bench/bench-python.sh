#!/usr/bin/env bash
# The Python module's benchmark: camel d = 8 at 10^6 evaluations through Python (numpy
# integrand) against the Rust closure (the CLI), the `vegas` package and MadNIS, each Python
# package in its own venv under target/bench-py (made on first use). Writes its section of
# docs/results/integration.md (between <!-- python:start --> and <!-- python:end -->).
#
#   scripts/bench/bench-python.sh [--reps 3]
set -euo pipefail
cd "$(dirname "$0")/../.."
root=target/bench-py
mkdir -p "$root"

venv() { # venv NAME PACKAGES...: create target/bench-py/NAME if missing and install PACKAGES
    local name=$1; shift
    [ -x "$root/$name/bin/python" ] || python3 -m venv "$root/$name"
    "$root/$name/bin/python" -m pip install -q --disable-pip-version-check "$@"
}

cargo build --release -p nis-cli
venv nis numpy "maturin>=1.9,<2"
PATH="$PWD/$root/nis/bin:$PATH" CARGO_TARGET_DIR="$PWD/target/py" "$root/nis/bin/python" -m pip install -q --disable-pip-version-check \
    --no-build-isolation --force-reinstall --no-deps ./crates/nis-py
venv vegas numpy vegas
# MadNIS needs PyTorch (a large download); without it the table says why.
madnis_note=""
if ! venv madnis numpy madnis >"$root/madnis-install.log" 2>&1; then
    madnis_note="pip install madnis failed: $(tail -1 "$root/madnis-install.log")"
    rm -rf "$root/madnis"
fi
python3 scripts/bench/bench-python.py --cli target/release/nis --venvs "$root" --out docs/results/integration.md \
    --madnis-note "$madnis_note" "$@"
