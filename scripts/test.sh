#!/usr/bin/env bash
# The tests: the Rust workspace, the MPI tests (scripts/test-mpi.sh: installs Open MPI if needed,
# builds with the feature `mpi` into target/mpi, runs `nis` under mpirun with 1, 2 and 3 ranks),
# then the Python module `nis` built as a wheel, installed into its own virtual environment and
# run under pytest.
#
#   scripts/test.sh
#
# The venv (target/py-venv: maturin, pytest, numpy from PyPI) is created on first use. The
# extension module builds in its own target directory (target/py): maturin builds it with other
# settings than `cargo test`, and sharing one directory would rebuild both each time.
set -euo pipefail
cd "$(dirname "$0")/.."
started=$SECONDS

cargo test --workspace --release
scripts/test-mpi.sh
export PYTHONDONTWRITEBYTECODE=1   # no __pycache__ beside the sources

venv=target/py-venv
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check "maturin>=1.9,<2" pytest numpy
# The wheel, as `pip install ./crates/nis-py` builds it (maturin is the PEP 517 backend).
PATH="$PWD/$venv/bin:$PATH" CARGO_TARGET_DIR="$PWD/target/py" "$venv/bin/python" -m pip install -q --disable-pip-version-check \
    --no-build-isolation --force-reinstall --no-deps ./crates/nis-py

# pytest exits 5 when it collected no test: that is a failure here, not a pass.
set +e
"$venv/bin/python" -m pytest crates/nis-py/tests -p no:cacheprovider -q
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
    echo "scripts/test.sh: pytest collected no tests" >&2
    exit 1
fi
echo "scripts/test.sh: $((SECONDS - started)) s in all" >&2
exit "$rc"
