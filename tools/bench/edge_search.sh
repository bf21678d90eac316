#!/usr/bin/env bash
# Edge-preset search (issue 6), accuracy half: each candidate and `paper` get the same wall-clock training budget
# on airplane partial (1 torch thread, batch 8, Adam 5e-4), then calibrate and evaluate on the same test subset.
# Usage: tools/bench/edge_search.sh MINUTES "edge-a edge-b tiny paper"
set -u
MIN=${1:-6}; CANDS=${2:-"edge-a edge-b tiny paper"}
EQ=${EQ:-.venv/bin/equipose}
for P in $CANDS; do
  OUT=runs/edge/$P
  rm -rf "$OUT"; mkdir -p "$OUT"
  echo "== $P: train ${MIN} min" >&2
  timeout -s INT "${MIN}m" $EQ train --category airplane --mode partial --preset "$P" --steps 1000000 --views 4 \
      --out "$OUT" --ckpt-every 2 --val-every 1000000 --threads 1 > "$OUT/train.log" 2>&1
  $EQ calibrate --checkpoint "$OUT/latest.pt" --num 256 > "$OUT/calibrate.log" 2>&1
  $EQ eval --checkpoint "$OUT/latest.pt" --category airplane --mode partial --limit 20 --icp-templates 1 \
      --json "docs/results/edge/$P.json" > "$OUT/eval.log" 2>&1
  echo "== $P done: $(python3 -c "import json;d=json.load(open('docs/results/edge/$P.json'));print(d['rows'][0])")" >&2
done
