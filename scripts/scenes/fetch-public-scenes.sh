#!/usr/bin/env bash
# Clones the public path-guiding and Mitsuba scenes that nis render is checked on into
# data/scenes/ (git-ignored), each at a pinned commit, and checks the SHA-256 of its scene files.
# Not run in CI (it needs the public git hosts); for users and for re-measuring
# docs/results/scenes.md. Idempotent: a clone already at its commit is kept.
#
#   data/scenes/practical-path-guiding/scenes/{cbox,kitchen,spaceship}   Müller et al. 2017's
#       scenes in Mitsuba 0.5 form (kitchen: Jay-Artist, CC BY 3.0; spaceship: thecali, CC0;
#       see each folder's LICENSE.txt)
#   data/scenes/mitsuba-data/docs/scenes                                  Mitsuba 3's own
#       documentation scenes (BSD-3-Clause, like Mitsuba)
#   data/scenes/mitsuba-data/sunsky/output/{sunsky_datasets,sampling_data}.bin  Mitsuba 3's
#       sun-and-sky tables (BSD-3-Clause), which the `sunsky` emitter reads (e.g. the kitchen's)
#   data/scenes/ppg-lab/scenes/{cornell-box,veach-ajar,veach-bidir,veach-mis,torus}
#       Bitterli's Mitsuba scenes (CC0, see each LICENSE.txt) and the practical-path-guiding
#       torus, in Mitsuba 3 form, from a guiding lab's repository (its code GPL-3, not used;
#       the snapshot lacks veach-ajar's three teapots: --drop-missing-meshes)
#   data/scenes/dppm-scenes/scenes/{staircase,living-room,bathroom}
#       Bitterli's 'The Wooden Staircase' (Wig42), 'The Grey & White Room' (Wig42) and
#       'Contemporary Bathroom' (Mareck), CC BY 3.0 (see each LICENSE.txt), in Mitsuba 0.6 form,
#       from a research group's scene collection (only these three folders are checked out)
#
# Then, e.g.:
#   nis render data/scenes/practical-path-guiding/scenes/spaceship/spaceship.xml --spp 64
#   nis bench guiding --scene data/scenes/ppg-lab/scenes/veach-bidir/scene.xml --seeds 3
#   target/mitsuba-venv/bin/python scripts/scenes/compare-scenes.py data/scenes/mitsuba-data/docs/scenes/*.xml
#
# Needs git and sha256sum.
set -euo pipefail
cd "$(dirname "$0")/../.."

# name | repository | commit | folders to check out (none: all)
REPOS=(
  "practical-path-guiding|https://github.com/Tom94/practical-path-guiding|effbd1934a87bd7c471bb6981eea758fc4b72854"
  "mitsuba-data|https://github.com/mitsuba-renderer/mitsuba-data|01100fa9b0b154492061a92404f26dcd7b784dbb"
  "ppg-lab|https://github.com/takkasila/practical_path_guiding_lab|c4b6605b3c78dccaa5721275d96ef6cd30c0630c"
  "dppm-scenes|https://github.com/hchoi405/dppm-scenes|8fdb2dcb3fe575bb04bc586fded35e81d76787d5|scenes/staircase scenes/living-room scenes/bathroom"
)
CHECKS=(
  "practical-path-guiding f29ece69d068191097766fcef98335eb71c394c577c1bf86363f9bafc28ad8c7 scenes/cbox/cbox.xml"
  "practical-path-guiding 77b783c4ef0891e1317287517201c711740dc35f13f8a98831fa70adc6f37d2d scenes/kitchen/kitchen.xml"
  "practical-path-guiding 2bb537ad751d659a633256d36aebdaccb3d84158eef3c5e52e6a11ab64b52807 scenes/spaceship/spaceship.xml"
  "mitsuba-data aef4e298979a55d8df0102ae080a78de9f7ade793ad4cc9920849a9693660d85 docs/scenes/include/matpreview.xml"
  "mitsuba-data eda853c45dfbe5811baa4a4b0b2b9189fab01cd166a061d5bbba5b22099b0c11 docs/scenes/bsdf_roughplastic_beckmann.xml"
  "mitsuba-data f110fa54ebcaf5f764da3a20bb4aafeeffd28111fcd0986f50a2489c12b294c7 sunsky/output/sunsky_datasets.bin"
  "mitsuba-data fd62a05e1f3b2fe29e4072b077ba4046b8fc0dbe1f0cbf848fc2a0594d21fbb1 sunsky/output/sampling_data.bin"
  "ppg-lab 4c6ca8210ebf54757b29ca4d5da851fa0cba37201a26fea8de5e5d76ab658b9c scenes/cornell-box/scene.xml"
  "ppg-lab 463902168a287fe0d01aa3abbe2d1e61fb6847ea68b143caf1477f757a083e44 scenes/veach-ajar/scene.xml"
  "ppg-lab fbec3e990fd2529a55109a0abd4aba62b85299abeccf61100e00729ebf4d3f34 scenes/veach-bidir/scene.xml"
  "ppg-lab 5d8588d174d4468c3b4e3bcd5b1df486d775a9d082d97fb8da2ff4da886d2d09 scenes/veach-mis/scene.xml"
  "ppg-lab 31ab87422d663de98e0e652d10d145bab7f27fae327217318120f0fca7dde1ce scenes/torus/scene.xml"
  "dppm-scenes c10b5734d2af1879d315f12ec2d19b78b22e260e79e54da06b93a3a382011341 scenes/staircase/scene.xml"
  "dppm-scenes 3cb1e1fa594a3d6c228deb6f8af09cff6a55db070c459878b6a2f6241929e27d scenes/living-room/scene.xml"
  "dppm-scenes b15d6db4e0a3b6669861b24f4d7f9ce767696f4d9ccc29ee8fc5cadfbe6a1131 scenes/bathroom/scene.xml"
)

mkdir -p data/scenes
for entry in "${REPOS[@]}"; do
  IFS='|' read -r name url commit folders <<<"$entry"
  dir="data/scenes/$name"
  if [ -d "$dir/.git" ] && [ "$(git -C "$dir" rev-parse HEAD)" = "$commit" ]; then
    echo "$name: at $commit"
    continue
  fi
  echo "$name: cloning $url at $commit"
  rm -rf "$dir"
  git clone --quiet --filter=blob:none --no-checkout "$url" "$dir"
  if [ -n "$folders" ]; then
    # shellcheck disable=SC2086 # the folders are words
    git -C "$dir" sparse-checkout set $folders
  fi
  git -C "$dir" checkout --quiet "$commit"
done
for check in "${CHECKS[@]}"; do
  read -r name sha path <<<"$check"
  echo "$sha  data/scenes/$name/$path" | sha256sum --check --quiet
done
echo "scenes in data/scenes, checksums verified"
