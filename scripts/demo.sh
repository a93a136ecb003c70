#!/usr/bin/env bash
# End-to-end demo on a synthetic scene it generates: dataset -> maps -> batch localization.
# Usage: scripts/demo.sh [OUT]   (default demo_out; about 2 minutes on 2 cores)
set -euo pipefail
OUT="${1:-demo_out}"
DATA="$OUT/data"

echo "== 1/4 generate a synthetic dataset (2 rooms, 8 splits) into $DATA"
ldlmap synth "$DATA" --preset demo --seed 1 --overwrite

echo "== 2/4 build one LDL map per scene (3D lines, translations, SIFT features)"
ldlmap prepare "$DATA"
ldlmap info "$DATA/maps/synthroom_1.h5"

echo "== 3/4 localize one panorama"
PANO="$(ls "$DATA"/extreme_pano/extreme_synthroom_1_scene_1/*.jpg | head -n 1)"
ldlloc localize "$DATA/maps/synthroom_1.h5" "$PANO" --vis "$OUT/localize.jpg"

echo "== 4/4 localize every split and print accuracy tables"
ldlloc run --root "$DATA" --output "$OUT/results.json" --save-vis "$OUT/vis"
echo "pictures: $OUT/localize.jpg and $OUT/vis/; results: $OUT/results.json and $OUT/results.csv"
