#!/usr/bin/env bash
# Ship a trained run as a packaged model (issue 7): calibrate → export fp32 + int8 → evaluate each ONNX file through
# the SDK (paper table + ICP-60 from the same command) and store its metrics in its own metadata.
# Usage: tools/ship_model.sh NAME RUN_DIR CATEGORY MODE [CALIB_NUM] [ICP_SAMPLES]
#   e.g. tools/ship_model.sh airplane-partial runs/airplane_partial_edge airplane partial
# Writes sdk/models/NAME.onnx, sdk/models/NAME.int8.onnx, docs/results/models/NAME{,.int8}.json and .png.
set -euo pipefail
NAME=$1; RUN=$2; CAT=$3; MODE=$4; NUM=${5:-512}; ICPN=${6:-100}
EQ=${EQ:-.venv/bin/equipose}
OUT=docs/results/models; mkdir -p "$OUT"
$EQ calibrate --checkpoint "$RUN/latest.pt" --num "$NUM" --out "$RUN/calibrated.pt" | tee "$RUN/calibrate.log"
$EQ export --checkpoint "$RUN/calibrated.pt" -o "sdk/models/$NAME.onnx" --int8
for F in "$NAME" "$NAME.int8"; do
  $EQ eval --model "sdk/models/$F.onnx" --category "$CAT" --mode "$MODE" --icp-samples "$ICPN" \
      --json "$OUT/$F.json" --plot "$OUT/$F.png" --store-metrics | tee "$OUT/$F.txt"
done
