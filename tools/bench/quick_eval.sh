#!/usr/bin/env bash
# Quick comparison of a trained run before shipping it (no ICP-60 baseline): calibrate → export fp32 to a scratch
# folder → refined calibration (ICP re-scoring of 5) → the stages a release recipe would add → SDK evaluation on the
# test set: the plain network (before the stages) and the default pipeline.
# Usage: tools/bench/quick_eval.sh RUN_DIR CATEGORY MODE [CALIB_NUM]
#   EQ, SCALE, EXPORT_CATEGORY, REFINE_ITERS, COPIES, VISIBILITY, POLISH, DENSIFY, REST_FACET, FRAME_PRIORS, FLIP_TEACHER, FLIP_AXES, FLIP_POOL, TURN_STATE, TURN_AXES, TURN_FROM: the release recipe's fields (train/release/recipe.py);
#   KEEP=path.onnx keeps the evaluated file there.
set -euo pipefail
RUN=$1; CAT=$2; MODE=$3; NUM=${4:-512}
EQ=${EQ:-.venv/bin/equipose}; PY=${PY:-.venv/bin/python}; ECAT=${EXPORT_CATEGORY:-$CAT}
VIEWS=$(python3 -c "import json;print(json.load(open('$RUN/config.json')).get('views', 10))")
TMP=$(mktemp -d); M=$TMP/model.onnx; trap 'rm -rf "$TMP"' EXIT
$EQ calibrate --checkpoint "$RUN/latest.pt" --num "$NUM" --out "$RUN/calibrated.pt" > "$RUN/calibrate.log"
$EQ export --checkpoint "$RUN/calibrated.pt" -o "$M" --category "$ECAT" ${SCALE:+--scale $SCALE} > /dev/null
$EQ calibrate --model "$M" --num "$NUM" --views "$VIEWS" --refine 5 ${REFINE_ITERS:+--refine-iters $REFINE_ITERS} ${COPIES:+--copies $COPIES} ${VISIBILITY:+--visibility $VISIBILITY} ${POLISH:+--polish $POLISH} ${DENSIFY:+--densify $DENSIFY} > /dev/null
$EQ eval --model "$M" --category "$ECAT" --mode "$MODE" --icp-templates 0 --refine 0 2>&1 | grep -E "^equipose" | sed 's/^/plain  /'
if [ -n "${REST_FACET:-}" ]; then
  $PY -c "from equipose.export.onnx_export import update_metadata as u; u('$M', rest_facet={'tolerance_deg': float('$REST_FACET')})"
fi
if [ -n "${FLIP_TEACHER:-}" ]; then
  $PY -m equipose.export.flip_templates --model "$M" --teacher "$FLIP_TEACHER" --category "$CAT" \
      --axes "${FLIP_AXES:-z}" --pool "${FLIP_POOL:-24}" > /dev/null
fi
if [ -n "${TURN_FROM:-}" ]; then
  $PY -m equipose.train.turn_classifier --model "$M" --copy-from "$TURN_FROM" > /dev/null
elif [ -n "${TURN_STATE:-}" ]; then
  $PY -m equipose.train.turn_classifier --model "$M" --state "$TURN_STATE" --axes "${TURN_AXES:-x,y,z}" > /dev/null
fi
if [ -n "${FRAME_PRIORS:-}" ]; then
  $PY -m equipose.export.frame_priors --model "$M" --category "$CAT" --steps "$FRAME_PRIORS" 2>/dev/null | tail -1
fi
$EQ eval --model "$M" --category "$ECAT" --mode "$MODE" --icp-templates 0 2>&1 | grep -E "^(method|equipose)"
if [ -n "${KEEP:-}" ]; then cp "$M" "$KEEP"; fi
