#!/usr/bin/env bash
# Continue tracked models (train/state/NAME) on a lent GPU machine, then bring the checkpoints back. Nothing depends
# on it: the same folders train on the CPU with `python -m equipose.train.lanes.long_runs run`.
#
#   tools/release/gpu_teachers.sh pack NAME...            # here: copy the data these models need into gpu_pack/
#   tools/release/gpu_teachers.sh remote MINUTES NAME...  # there (the device tool's `run`, carry ["gpu_pack"]):
#                                                         #   install equipose, one long_runs slice per model on
#                                                         #   CUDA, checkpoints + manifests to $OUT/NAME/
#                                                         #   (BATCH=32: that batch size for these slices; partial
#                                                         #   students render their views there on every core)
#   tools/release/gpu_teachers.sh fetch DIR NAME...       # here: DIR/NAME/{latest.pt,manifest.json} → train/state/
#
# e.g. pack car-complete airplane-complete; then the device tool's run with
#   command "bash tools/release/gpu_teachers.sh remote 12 car-complete airplane-complete", carry ["gpu_pack"],
#   timeout_s 600 (two 12-minute slices do not fit one 10-minute command: give each call the minutes it can hold);
#   then fetch FILES_AT car-complete airplane-complete, and commit train/state.
# Measured on an H100 (16 cores), BATCH=32: chair-partial 3844 steps in 6.5 min of training (≈ 0.1 s per step),
# sofa-partial 2928 in 5.5; a student's first call also renders its views on 16 cores and computes teacher targets
# (≈ 3.5 min; both stay on the machine while it is warm, 30 s idle). Leave ~2 min of the device budget spare: a call
# cut by the budget brings nothing back.
# On an H200, BATCH=32: airplane-complete 6,927 steps and car-complete 7,047 in 3.4 min each (about 0.03 s per step);
# the learning rate decays per epoch of samples seen, so a slice at batch 32 keeps the schedule of batch-8 slices.
# gpu_pack/ holds only modelnet40_npy1024/<category> of each model (≈ 12 KB per shape: car 3.6 MB, airplane 8.7 MB),
# far under the 64 MiB that travels. The device has python3 with torch (CUDA), scipy, tqdm, opencv, onnx.
set -euo pipefail
cd "$(dirname "$0")/../.."
cmd=${1:?pack | hide | unhide | remote | fetch}; shift
category() { python3 -c "import json,sys;print(json.load(open('train/state/$1/config.json'))['category'])"; }
case "$cmd" in
  pack)
    SRC=${EQUIPOSE_DATA:-../shared/data}
    EXCLUDE=$(git rev-parse --git-path info/exclude); mkdir -p "$(dirname "$EXCLUDE")"
    grep -qx "/gpu_pack/" "$EXCLUDE" 2>/dev/null || echo "/gpu_pack/" >> "$EXCLUDE"
    for NAME in "$@"; do
      CAT=$(category "$NAME")
      mkdir -p gpu_pack/data/modelnet40_npy1024
      rm -rf "gpu_pack/data/modelnet40_npy1024/$CAT"
      cp -r "$SRC/modelnet40_npy1024/$CAT" gpu_pack/data/modelnet40_npy1024/
    done
    du -sh gpu_pack
    TREE=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1); PACK=$(du -sb gpu_pack | cut -f1)
    echo "working tree $((TREE / 1048576)) MiB + gpu_pack $((PACK / 1048576)) MiB travel (limit 64 MiB);" \
         "over it: '$0 hide' before the run, '$0 unhide' after" ;;
  hide)     # keep the shipped ONNX files and result docs (not needed there) out of what travels, index only
    EXCLUDE=$(git rev-parse --git-path info/exclude)
    grep -qx "/sdk/models/" "$EXCLUDE" 2>/dev/null || printf '/sdk/models/\n/docs/results/\n' >> "$EXCLUDE"
    git rm -r --cached -q --ignore-unmatch sdk/models docs/results ;;
  unhide)
    git reset -q -- sdk/models docs/results
    EXCLUDE=$(git rev-parse --git-path info/exclude)
    sed -i '\#^/sdk/models/$#d;\#^/docs/results/$#d' "$EXCLUDE"
    git status --short -- sdk/models docs/results ;;
  remote)
    MINUTES=${1:?minutes per model}; shift
    PY=${PYTHON:-python3}
    $PY -m pip install -q --upgrade --no-deps --no-build-isolation --no-index --target /tmp/equipose_site . >/dev/null
    export PYTHONPATH=/tmp/equipose_site EQUIPOSE_DATA=$PWD/gpu_pack/data PYTHONUNBUFFERED=1
    export EQUIPOSE_RENDER_WORKERS=${EQUIPOSE_RENDER_WORKERS:-$(nproc)}   # partial views render once, in parallel
    $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
    for NAME in "$@"; do
      $PY -m equipose.train.lanes.long_runs slice "$NAME" --minutes "$MINUTES" --state-dir train/state \
          --cache-dir /tmp/equipose_cache ${BATCH:+--batch-size "$BATCH"} 2>&1 | tr '\r' '\n' | grep -v "it/s" || true
      if [ -n "${OUT:-}" ]; then
        mkdir -p "$OUT/$NAME"
        cp "train/state/$NAME/latest.pt" "train/state/$NAME/manifest.json" "$OUT/$NAME/"
      fi
    done ;;
  fetch)
    DIR=${1:?folder the files came back to}; shift
    for NAME in "$@"; do
      cp "$DIR/$NAME/latest.pt" "$DIR/$NAME/manifest.json" "train/state/$NAME/"
      python3 -c "import json;m=json.load(open('train/state/$NAME/manifest.json'));print('$NAME', m['steps'], m['history'][-1])"
    done ;;
  *) echo "unknown command $cmd (pack | hide | unhide | remote | fetch)" >&2; exit 2 ;;
esac
