#!/usr/bin/env bash
# Continue tracked models (train/state/NAME) on a lent GPU machine, then bring the checkpoints back. Nothing depends
# on it: the same folders train on the CPU with `python -m equipose.train.long_runs run`.
#
#   tools/release/gpu_teachers.sh pack NAME...            # here: copy the data these models need into gpu_pack/
#   tools/release/gpu_teachers.sh remote MINUTES NAME...  # there (the device tool's `run`, carry ["gpu_pack"]):
#                                                         #   install equipose, one long_runs slice per model on
#                                                         #   CUDA, checkpoints + manifests to $OUT/NAME/
#   tools/release/gpu_teachers.sh fetch DIR NAME...       # here: DIR/NAME/{latest.pt,manifest.json} → train/state/
#
# e.g. pack car-complete airplane-complete; then the device tool's run with
#   command "bash tools/release/gpu_teachers.sh remote 12 car-complete airplane-complete", carry ["gpu_pack"],
#   timeout_s 600 (two 12-minute slices do not fit one 10-minute command: give each call the minutes it can hold);
#   then fetch FILES_AT car-complete airplane-complete, and commit train/state.
# gpu_pack/ holds only modelnet40_npy1024/<category> of each model (≈ 12 KB per shape: car 3.6 MB, airplane 8.7 MB),
# far under the 64 MiB that travels. The device has python3 with torch (CUDA), scipy, tqdm, opencv, onnx.
set -euo pipefail
cd "$(dirname "$0")/../.."
cmd=${1:?pack | remote | fetch}; shift
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
    du -sh gpu_pack ;;
  remote)
    MINUTES=${1:?minutes per model}; shift
    PY=${PYTHON:-python3}
    $PY -m pip install -q --no-deps --no-build-isolation --no-index --target /tmp/equipose_site . >/dev/null
    export PYTHONPATH=/tmp/equipose_site EQUIPOSE_DATA=$PWD/gpu_pack/data PYTHONUNBUFFERED=1
    $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
    for NAME in "$@"; do
      $PY -m equipose.train.long_runs slice "$NAME" --minutes "$MINUTES" --state-dir train/state \
          --cache-dir /tmp/equipose_cache 2>&1 | tr '\r' '\n' | grep -v "it/s" || true
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
  *) echo "unknown command $cmd (pack | remote | fetch)" >&2; exit 2 ;;
esac
