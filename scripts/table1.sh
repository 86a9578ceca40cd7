#!/bin/bash
# The paper's Table I on a GPU machine: ANN-6 (voxel grids), ResNet-50 on accumulated frames (A)
# and on voxel grids (V), trained on one simulated dataset and scored beside the shipped SNN-6 on
# its test windows (seed 11, 64 sequences, 320 windows of 100 ms), then `spikegyro report`.
# Every file goes under WORK_DIR; WORK_DIR/table1.tgz holds what is worth keeping (reports,
# metrics, logs, configs; ResNet-50's 95 MB checkpoints stay in WORK_DIR/run-*).
#
#   scripts/table1.sh WORK_DIR data                    # 1,280 sequences, seed 11 (~2 min on 16 cores)
#   scripts/table1.sh WORK_DIR train MODEL INPUT MIN   # e.g. ann6 voxel 30; resnet50 frames 60
#   scripts/table1.sh WORK_DIR score                   # evaluate the runs and the shipped SNN-6
#
# Run it from the repository root (it scores spikegyro/data/pretrained/snn6.pt).
# Knobs for a small check on a CPU: T1_SEQUENCES (1280), T1_WORKERS (16), T1_TRAIN_ARGS and
# T1_EVAL_ARGS (extra options, e.g. --device cpu --sensor-width 128 --sensor-height 96).
# shellcheck disable=SC2086  # T1_TRAIN_ARGS and T1_EVAL_ARGS are word lists
set -eo pipefail
export PYTHONUNBUFFERED=1
S="${SPIKEGYRO:-python3 -m spikegyro}"
[ $# -ge 2 ] || { sed -n '8,10p' "$0" | sed 's/^# *//' >&2; exit 2; }
WORK=$1
shift
mkdir -p "$WORK"
DATA=$WORK/data
case "$1" in
data)
    $S simulate --out $DATA --sequences "${T1_SEQUENCES:-1280}" --workers "${T1_WORKERS:-16}" \
        --seed 11 | tail -4
    ;;
train)
    [ $# -eq 4 ] || { echo "usage: scripts/table1.sh WORK_DIR train MODEL INPUT MINUTES" >&2; exit 2; }
    # ${T1_TRAIN_ARGS} lets the CPU check shrink the run (--device cpu --sensor-width ...).
    # bfloat16 autocast speeds ResNet-50 up on an H100 and slows ANN-6 down (BENCHMARKS.md).
    amp=""
    [ "$2" = resnet50 ] && amp="--amp bf16"
    $S train --data $DATA --out "$WORK/run-$2-$3" --preset paper --model "$2" --input "$3" \
        $amp --max-minutes "$4" --val-every 1000 --val-windows 200 --log-every 100 \
        --num-workers "${T1_WORKERS:-15}" ${T1_TRAIN_ARGS} 2>&1 | grep -v "━"
    ;;
score)
    names=("ann6-voxel:ANN-6 (voxel)" "resnet50-frames:ResNet-50 (A, frames)"
           "resnet50-voxel:ResNet-50 (V, voxel)")
    evals=()
    $S evaluate --data $DATA --split test --checkpoint spikegyro/data/pretrained/snn6.pt \
        --out $WORK/eval-snn6 --name "SNN-6 (shipped)" ${T1_EVAL_ARGS} | tail -3
    evals+=($WORK/eval-snn6)
    for entry in "${names[@]}"; do
        run=$WORK/run-${entry%%:*}
        [ -f "$run/best.pt" ] || continue
        $S evaluate --data $DATA --split test --checkpoint "$run/best.pt" \
            --out "$WORK/eval-${entry%%:*}" --name "${entry#*:}" ${T1_EVAL_ARGS} | tail -3
        evals+=("$WORK/eval-${entry%%:*}")
    done
    $S report "${evals[@]}" --out $WORK/report | tail -20
    mkdir -p "$WORK/table1" && cp -r "$WORK/report" "$WORK/table1/report"
    for run in "$WORK"/run-*; do
        keep=$WORK/table1/$(basename "$run")
        mkdir -p "$keep" && cp "$run"/{config.json,log.csv,throughput.json} "$keep"/
        case "$run" in *ann6*) cp "$run/best.pt" "$keep"/ ;; esac
    done
    for ev in "${evals[@]}"; do
        mkdir -p "$WORK/table1/$(basename "$ev")" && cp "$ev"/metrics.json "$WORK/table1/$(basename "$ev")"/
    done
    tar -czf "$WORK/table1.tgz" -C "$WORK" table1
    echo "wrote $WORK/table1.tgz"
    ;;
*)
    echo "usage: scripts/table1.sh WORK_DIR data | train MODEL INPUT MINUTES | score" >&2
    exit 2
    ;;
esac
