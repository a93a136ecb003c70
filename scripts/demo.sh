#!/usr/bin/env bash
# End-to-end demo on a synthetic scene it generates: dataset -> maps -> batch localization.
# Usage: [PYTHON=python3] scripts/demo.sh [OUT]   (default demo_out; about 3 minutes on 2 cores)
# The programs run as modules of $PYTHON (`make demo PYTHON=...` passes it), so the demo uses the
# toolkit installed for that interpreter, not whatever `ldlmap` is first on PATH.
set -euo pipefail
PYTHON="${PYTHON:-python3}"
OUT="${1:-demo_out}"
DATA="$OUT/data"

echo "== 1/4 generate a synthetic dataset (2 rooms, 8 splits) into $DATA"
"$PYTHON" -m ldlmap.cli synth "$DATA" --preset demo --seed 1 --overwrite

echo "== 2/4 build one LDL map per scene (3D lines, translations, SIFT features)"
"$PYTHON" -m ldlmap.cli prepare "$DATA"
"$PYTHON" -m ldlmap.cli info "$DATA/maps/synthroom_1.h5"

echo "== 3/4 localize one panorama"
PANO="$(ls "$DATA"/extreme_pano/extreme_synthroom_1_scene_1/*.jpg | head -n 1)"
"$PYTHON" -m ldlloc.cli localize "$DATA/maps/synthroom_1.h5" "$PANO" --vis "$OUT/localize.jpg"

echo "== 4/4 localize every split and print accuracy tables"
"$PYTHON" -m ldlloc.cli run --root "$DATA" --output "$OUT/results.json" --save-vis "$OUT/vis"
echo "pictures: $OUT/localize.jpg and $OUT/vis/; results: $OUT/results.json and $OUT/results.csv"
