#!/usr/bin/env bash
# The runs of this folder: SNN-6 from the shipped weights, batches of 4 simulated + 4 real windows.
#
#   runs/selfsup-real/run.sh OUT MINUTES SIM_DATA REAL_DIR [more train options, e.g. --learn-tau]
#
# SIM_DATA: a simulated dataset (here seed 11 mixed with a --slow-share 1 set, see README.md);
# REAL_DIR: a folder with unlabeled/davis240_rotbars/events.txt,
# unlabeled/ecd_shapes_start_mvtracking/events.txt and ecd_windows/shapes_rotation/calib.txt.
set -euo pipefail
[ $# -ge 4 ] || { sed -n '4p' "$0" | sed 's/^# *//' >&2; exit 2; }
out=$1; minutes=$2; data=$3; real=$4; shift 4
exec spikegyro train --out "$out" --init snn6 --data "$data" \
  --real "$real/unlabeled/davis240_rotbars/events.txt" --real-calib 245,245,120,90 \
  --real "$real/unlabeled/ecd_shapes_start_mvtracking/events.txt" \
  --real-calib "$real/ecd_windows/shapes_rotation/calib.txt" \
  --real-share 0.5 --batch-size 8 --val-every 100 --val-windows 48 --log-every 10 \
  --num-workers 1 --threads 1 --max-minutes "$minutes" --seed 46 "$@"
