#!/usr/bin/env bash
# Quick look at a training run's latest checkpoint as the SDK would run it: export to a temp ONNX, refined
# calibration on NUM training inputs, evaluation on the first LIMIT test instances (no ICP), plain and refined.
# Usage: tools/bench/probe_run.sh RUN_DIR CATEGORY MODE [NUM] [LIMIT]
set -euo pipefail
RUN=$1; CAT=$2; MODE=$3; NUM=${4:-128}; LIMIT=${5:-20}
EQ=${EQ:-.venv/bin/equipose}
VIEWS=$(python3 -c "import json;print(json.load(open('$RUN/config.json')).get('views', 10))")
TMP=$(mktemp -d)
$EQ calibrate --checkpoint "$RUN/latest.pt" --num "$NUM" --out "$TMP/c.pt" | tail -1
$EQ export --checkpoint "$TMP/c.pt" -o "$TMP/m.onnx" --no-verify > /dev/null
$EQ calibrate --model "$TMP/m.onnx" --num "$NUM" --views "$VIEWS" | tail -1
for K in 0 5; do
  $EQ eval --model "$TMP/m.onnx" --category "$CAT" --mode "$MODE" --limit "$LIMIT" --icp-templates 0 --refine $K 2>&1 \
      | tr '\r' '\n' | grep -v "it/s\]" | tail -1
done
rm -rf "$TMP"
