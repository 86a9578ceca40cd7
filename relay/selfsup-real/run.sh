#!/usr/bin/env bash
# usage: run_ss.sh OUT MINUTES [extra train options]
out=$1; minutes=$2; shift 2
R=/work/shared/real
exec /work/main/.venv/bin/spikegyro train --out "$out" --init snn6 --data /work/data/mix \
  --real $R/unlabeled/davis240_rotbars/events.txt --real-calib 245,245,120,90 \
  --real $R/unlabeled/ecd_shapes_start_mvtracking/events.txt --real-calib $R/ecd_windows/shapes_rotation/calib.txt \
  --real-share 0.5 --batch-size 8 --val-every 100 --val-windows 48 --log-every 10 \
  --num-workers 1 --threads 1 --max-minutes "$minutes" --seed 46 "$@"
