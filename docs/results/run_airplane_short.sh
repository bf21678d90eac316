#!/usr/bin/env bash
# The short CPU runs of issue 3 (airplane complete and partial, tiny preset), exactly as run.
# Training was stopped by hand at the time budget; latest.pt (saved every 100 steps) is what was evaluated.
set -euo pipefail
equipose render --category airplane --split test --views 5
equipose render --category airplane --split train --views 4
nice -n 10 equipose train --category airplane --mode complete --preset tiny --steps 3000 --batch-size 8 \
    --out runs/airplane_complete_tiny --val-every 500 --ckpt-every 100 &
nice -n 10 equipose train --category airplane --mode partial --preset tiny --steps 3000 --batch-size 8 --views 4 \
    --out runs/airplane_partial_tiny --val-every 500 --ckpt-every 100 &
wait
for mode in complete partial; do
    nice -n 10 equipose calibrate --checkpoint runs/airplane_${mode}_tiny/latest.pt --num 1024
    nice -n 10 equipose eval --checkpoint runs/airplane_${mode}_tiny/latest.pt --category airplane --mode $mode \
        --icp-samples 100 --json docs/results/airplane_${mode}_tiny.json --plot docs/results/airplane_${mode}_tiny.png
done
