#!/usr/bin/env bash
# Ship a trained run as a packaged model (issue 7): calibrate → export fp32 + int8 → per file: calibrate for the SDK's
# ICP re-scoring (refine_calibration metadata) → evaluate through the SDK (paper table + ICP-60 from the same command)
# and store its metrics in its own metadata; also the plain network (--refine 0) for reference.
# Usage: tools/release/ship_model.sh NAME RUN_DIR CATEGORY MODE [CALIB_NUM] [ICP_SAMPLES]
#   e.g. tools/release/ship_model.sh airplane-partial runs/airplane_partial_edge airplane partial
#   RUN_DIR "-": keep the network of sdk/models/NAME{,.int8}.onnx; re-calibrate and re-measure them (an SDK change)
# Environment (deploying a network trained on another data set, e.g. a complete-shape network on tabletop depth):
#   SCALE=m/unit  EXPORT_CATEGORY=name  EVAL_MODE=complete|partial (test set; default MODE)  REFINE=0 (no ICP
#   re-scoring calibration: the file then runs the plain network by default)  REFINE_ITERS=N (ICP iterations of the
#   re-scoring, default 10; the ModelNet models ship with 30 except sofa-partial)  COPIES=K (rotated input copies per
#   object, equipose.runtime.copies; default 1; chair-partial and sofa-partial ship with 8)  VISIBILITY=E (partial
#   views: view-aware re-scoring with that hidden-point-removal exponent, equipose.runtime.visibility; default off;
#   chair-partial and sofa-partial ship with 1)  POLISH=N (ICP iterations on the selected
#   pose, equipose.runtime.refine; default 0; sofa-partial ships with 30)  DENSIFY=N (ICP template plus the midpoints
#   to each canonical point's N nearest neighbours, equipose.runtime.template; default 0)  FLIP_TEACHER=model FLIP_AXES=z
#   FLIP_POOL=24 (front/back templates from that complete-shape model, the 6 of FLIP_POOL reconstructions that agree
#   on the frame, equipose.export.flip_templates, added before evaluation)
#   TURN_STATE=train/state/NAME TURN_AXES=x,y,z (partial views: the turn classifier trained on that lane's views
#   posed by its teacher, equipose.train.turn_classifier, added after the flip templates; the int8 file copies it)
#   TURN_FROM=file.onnx (copy that file's turn classifier instead of training one)
#   REST_FACET=deg (complete clouds: the rest-facet stage with that tolerance, metadata rest_facet)
#   FRAME_PRIORS=auto|none|steps (complete clouds: mirror plane / footprint steps, chosen on training clouds when
#   auto; equipose.export.frame_priors, metadata frame_priors)
# Writes sdk/models/NAME{,.int8}.onnx and docs/results/models/NAME{,.int8}{.json,.png,.txt} (+ .norefine.txt).
set -euo pipefail
NAME=$1; RUN=$2; CAT=$3; MODE=$4; NUM=${5:-512}; ICPN=${6:-100}
EQ=${EQ:-.venv/bin/equipose}
EVAL_MODE=${EVAL_MODE:-$MODE}; REFINE=${REFINE:-5}; ECAT=${EXPORT_CATEGORY:-$CAT}
OUT=docs/results/models; mkdir -p "$OUT"
if [ "$RUN" = "-" ]; then          # the files already in sdk/models: re-calibrate and re-measure them (an SDK change)
  VIEWS=10
else
  VIEWS=$(python3 -c "import json;print(json.load(open('$RUN/config.json')).get('views', 10))")
  $EQ calibrate --checkpoint "$RUN/latest.pt" --num "$NUM" --out "$RUN/calibrated.pt" | tee "$RUN/calibrate.log"
  $EQ export --checkpoint "$RUN/calibrated.pt" -o "sdk/models/$NAME.onnx" --int8 --category "$ECAT" ${SCALE:+--scale $SCALE}
fi
for F in "$NAME" "$NAME.int8"; do
  if [ "$REFINE" != 0 ]; then
    $EQ calibrate --model "sdk/models/$F.onnx" --num "$NUM" --views "$VIEWS" --refine "$REFINE" \
        ${REFINE_ITERS:+--refine-iters $REFINE_ITERS} ${COPIES:+--copies $COPIES} ${VISIBILITY:+--visibility $VISIBILITY} ${POLISH:+--polish $POLISH} ${DENSIFY:+--densify $DENSIFY}
    $EQ eval --model "sdk/models/$F.onnx" --category "$ECAT" --mode "$EVAL_MODE" --refine 0 --icp-templates 0 \
        | tee "$OUT/$F.norefine.txt"
  fi
  if [ -n "${REST_FACET:-}" ]; then
    ${PY:-.venv/bin/python} -c "from equipose.export.onnx_export import update_metadata as u; \
u('sdk/models/$F.onnx', rest_facet={'tolerance_deg': float('$REST_FACET')})"
  fi
  if [ -n "${FLIP_TEACHER:-}" ]; then
    ${PY:-.venv/bin/python} -m equipose.export.flip_templates --model "sdk/models/$F.onnx" --teacher "$FLIP_TEACHER" \
        --category "$CAT" --axes "${FLIP_AXES:-z}" --pool "${FLIP_POOL:-24}"
  fi
  if [ -n "${TURN_FROM:-}" ]; then           # a classifier trained before (it does not depend on the network)
    ${PY:-.venv/bin/python} -m equipose.train.turn_classifier --model "sdk/models/$F.onnx" --copy-from "$TURN_FROM"
  elif [ -n "${TURN_STATE:-}" ]; then
    if [ "$F" = "$NAME" ]; then
      ${PY:-.venv/bin/python} -m equipose.train.turn_classifier --model "sdk/models/$F.onnx" --state "$TURN_STATE" \
          --axes "${TURN_AXES:-x,y,z}"
    else                        # the int8 file carries the fp32 file's classifier
      ${PY:-.venv/bin/python} -m equipose.train.turn_classifier --model "sdk/models/$F.onnx" --copy-from "sdk/models/$NAME.onnx"
    fi
  fi
  if [ -n "${FRAME_PRIORS:-}" ]; then
    ${PY:-.venv/bin/python} -m equipose.export.frame_priors --model "sdk/models/$F.onnx" --category "$CAT" \
        --steps "$FRAME_PRIORS"
  fi
  $EQ eval --model "sdk/models/$F.onnx" --category "$ECAT" --mode "$EVAL_MODE" --icp-samples "$ICPN" \
      --json "$OUT/$F.json" --plot "$OUT/$F.png" --store-metrics | tee "$OUT/$F.txt"
done
