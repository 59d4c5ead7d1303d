#!/usr/bin/env bash
# Makes (on first use) the venv of the `vegas` package baselines under target/bench-py/vegas and
# prints the path of its python. Used by scripts/bench/bench-vegas.sh and `nis bench time-to-precision`.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=target/bench-py/vegas
[ -x "$venv/bin/python" ] || python3 -m venv "$venv" >&2
"$venv/bin/python" -m pip install -q --disable-pip-version-check numpy vegas >&2
echo "$PWD/$venv/bin/python"
