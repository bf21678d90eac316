#!/usr/bin/env bash
# Quick comparison of a trained run before shipping it (no ICP-60 baseline): calibrate → export fp32 to a scratch
# folder → refined calibration (ICP re-scoring of 5) → SDK evaluation on the test set.
# Usage: tools/bench/quick_eval.sh RUN_DIR CATEGORY MODE [CALIB_NUM]   (EQ, SCALE, EXPORT_CATEGORY as in ship_model.sh)
set -euo pipefail
RUN=$1; CAT=$2; MODE=$3; NUM=${4:-512}
EQ=${EQ:-.venv/bin/equipose}; ECAT=${EXPORT_CATEGORY:-$CAT}
VIEWS=$(python3 -c "import json;print(json.load(open('$RUN/config.json')).get('views', 10))")
TMP=$(mktemp -d); M=$TMP/model.onnx; trap 'rm -rf "$TMP"' EXIT
$EQ calibrate --checkpoint "$RUN/latest.pt" --num "$NUM" --out "$RUN/calibrated.pt" > "$RUN/calibrate.log"
$EQ export --checkpoint "$RUN/calibrated.pt" -o "$M" --category "$ECAT" ${SCALE:+--scale $SCALE} > /dev/null
$EQ calibrate --model "$M" --num "$NUM" --views "$VIEWS" --refine 5 > /dev/null
$EQ eval --model "$M" --category "$ECAT" --mode "$MODE" --icp-templates 0 2>&1 | grep -E "^(method|equipose)"
