#!/bin/bash
# The paper's Table I on a GPU machine: ANN-6 (voxel grids), ResNet-50 on accumulated frames (A)
# and on voxel grids (V), trained on one simulated dataset (seed 11, 1,280 sequences) and scored
# beside the bundled SNN-6 and ANN-6 on its test windows (64 sequences, 320 windows of 100 ms),
# then `spikegyro report`.
#
# Each step fits one command of at most 10 minutes on a fresh machine: it simulates the dataset
# first when it is not there yet (seed 11 gives the same sequences everywhere; ~2.5 minutes on 16
# cores), so no step depends on files that an earlier command left behind.
#
#   scripts/table1.sh WORK_DIR row MODEL INPUT MIN   # train until the run has MIN minutes, score
#                                                    #   best.pt, keep it; again with a larger MIN
#                                                    #   continues the run (e.g. resnet50 voxel 9,
#                                                    #   then 18, 27, ...)
#   scripts/table1.sh WORK_DIR score                 # score the bundled snn6 and ann6, report
#                                                    #   them with every row kept so far
#   scripts/table1.sh WORK_DIR data                  # only simulate the dataset
#
# WORK_DIR/table1/ collects what is worth keeping (per row: config, log, throughput, metrics and
# predictions; the report), small enough to copy off the machine after each command;
# WORK_DIR/table1.tgz packs it. The dataset (6.3 GB) goes to T1_DATA (default WORK_DIR/data) and
# the runs (ResNet-50's checkpoints are 95 MB each) to T1_RUNS (default WORK_DIR/runs): point
# them outside a folder that is copied back. Run it from the repository root.
# Knobs for a small check on a CPU: T1_SEQUENCES (1280), T1_WORKERS (16), T1_TRAIN_ARGS and
# T1_EVAL_ARGS (extra options, e.g. --device cpu --sensor-width 128 --sensor-height 96).
# shellcheck disable=SC2086  # T1_TRAIN_ARGS and T1_EVAL_ARGS are word lists
set -eo pipefail
export PYTHONUNBUFFERED=1
S="${SPIKEGYRO:-python3 -m spikegyro}"
usage() { sed -n '11,17p' "$0" | sed 's/^# *//' >&2; exit 2; }
[ $# -ge 2 ] || usage
WORK=$1
shift
DATA=${T1_DATA:-$WORK/data}
RUNS=${T1_RUNS:-$WORK/runs}
KEEP=$WORK/table1
mkdir -p "$WORK" "$KEEP"

ensure_data() {
    [ -f "$DATA/meta.json" ] && return
    $S simulate --out $DATA --sequences "${T1_SEQUENCES:-1280}" --workers "${T1_WORKERS:-16}" \
        --seed 11 | tail -4
}

evaluate() {  # CHECKPOINT NAME KEY: score on the test split into KEEP/eval-KEY
    $S evaluate --data $DATA --split test --checkpoint "$1" --out "$KEEP/eval-$3" --name "$2" \
        --example 0 ${T1_EVAL_ARGS} | tail -3
    rm -f "$KEEP/eval-$3"/window_*.png "$KEEP/eval-$3"/report.html  # the report holds them
}

pack() {
    local evals=("$KEEP"/eval-*)
    [ -e "${evals[0]}" ] && $S report "${evals[@]}" --out "$KEEP/report" | tail -20
    tar -czf "$WORK/table1.tgz" -C "$WORK" table1
    echo "wrote $KEEP and $WORK/table1.tgz"
}

case "$1" in
data)
    ensure_data
    ;;
row)
    [ $# -eq 4 ] || usage
    ensure_data
    run=$RUNS/run-$2-$3
    if [ -f "$run/resume.pt" ]; then  # a run already there goes on until it has MIN minutes
        $S train --data $DATA --out "$run" --resume --max-minutes "$4" 2>&1 | grep -v "━"
    else
        # bfloat16 autocast speeds ResNet-50 up on an H100 and slows ANN-6 down (BENCHMARKS.md);
        # ${T1_TRAIN_ARGS} sets CPU runs apart (--device cpu --threads 1 --batch-size 16 ...).
        amp="--amp off"
        [ "$2" = resnet50 ] && amp="--amp bf16"
        $S train --data $DATA --out "$run" --preset paper --model "$2" --input "$3" $amp \
            --max-minutes "$4" --val-every 1000 --val-windows 200 --log-every 100 \
            --num-workers "${T1_WORKERS:-15}" ${T1_TRAIN_ARGS} 2>&1 | grep -v "━"
    fi
    row=$KEEP/run-$2-$3
    mkdir -p "$row" && cp "$run"/{config.json,log.csv,throughput.json,loss.png} "$row"/
    case "$2-$3" in  # the report's names (and colors) of the paper's rows
    ann6-voxel) name="ANN-6 (this run)" ;;
    resnet50-frames) name="ResNet-50 (A)" ;;
    resnet50-voxel) name="ResNet-50 (V)" ;;
    *) name="$2 ($3)" ;;
    esac
    evaluate "$run/best.pt" "$name" "$2-$3"
    pack
    ;;
score)
    ensure_data
    evaluate snn6 "SNN-6" snn6
    evaluate ann6 "ANN-6" ann6-bundled
    pack
    ;;
*)
    usage
    ;;
esac
