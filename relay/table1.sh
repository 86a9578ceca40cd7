#!/bin/bash
# The paper's Table I on a GPU machine (issue 16): ANN-6 (voxel), ResNet-50 on accumulated frames
# (A) and on voxel grids (V), trained on the relay's dataset recipe and scored, beside the shipped
# SNN-6, on the relay's own test windows (seed 11, 64 sequences, 320 windows of 100 ms). Planned
# for a session with a GPU; checked end to end on the CPU at a toy size (T1_SEQUENCES=12 ...).
#
#   bash relay/table1.sh data                    # 1,280 sequences, seed 11 (~2 min on 16 cores)
#   bash relay/table1.sh train MODEL INPUT MIN   # e.g. ann6 voxel 3; resnet50 frames 5; resnet50 voxel 5
#   bash relay/table1.sh score                   # evaluate every trained run and the shipped SNN-6,
#                                                # then the report; $OUT/table1.tgz comes back
#
# Chain the calls while the machine is warm: data and runs live in /tmp there. ResNet-50's
# checkpoints (~95 MB) exceed what comes back from the machine, so scoring happens there and only
# metrics, logs, configs and the report return (ANN-6's best.pt, 1 MB, too). The relay segment
# (relay/segment10.sh) has first claim on the device minutes; this spends what is left.
# shellcheck disable=SC2086  # T1_TRAIN_ARGS and T1_EVAL_ARGS are word lists
set -eo pipefail
export PYTHONUNBUFFERED=1
S="python3 -m spikegyro"
DATA=/tmp/t1
case "$1" in
data)
    $S simulate --out $DATA --sequences "${T1_SEQUENCES:-1280}" --workers "${T1_WORKERS:-16}" \
        --seed 11 | tail -4
    ;;
train)
    [ $# -eq 4 ] || { echo "usage: bash relay/table1.sh train MODEL INPUT MINUTES" >&2; exit 2; }
    # ${T1_TRAIN_ARGS} lets the CPU check shrink the run (--device cpu --sensor-width ...)
    $S train --data $DATA --out "/tmp/run-$2-$3" --preset paper --model "$2" --input "$3" \
        --amp bf16 --max-minutes "$4" --val-every 1000 --val-windows 200 --log-every 100 \
        --num-workers "${T1_WORKERS:-15}" ${T1_TRAIN_ARGS} 2>&1 | grep -v "━"
    ;;
score)
    names=("ann6-voxel:ANN-6 (voxel)" "resnet50-frames:ResNet-50 (A, frames)"
           "resnet50-voxel:ResNet-50 (V, voxel)")
    evals=()
    $S evaluate --data $DATA --split test --checkpoint spikegyro/data/pretrained/snn6.pt \
        --out /tmp/eval-snn6 --name "SNN-6 (shipped)" ${T1_EVAL_ARGS} | tail -3
    evals+=(/tmp/eval-snn6)
    for entry in "${names[@]}"; do
        run=/tmp/run-${entry%%:*}
        [ -f "$run/best.pt" ] || continue
        $S evaluate --data $DATA --split test --checkpoint "$run/best.pt" \
            --out "/tmp/eval-${entry%%:*}" --name "${entry#*:}" ${T1_EVAL_ARGS} | tail -3
        evals+=("/tmp/eval-${entry%%:*}")
    done
    $S report "${evals[@]}" --out /tmp/table1-report | tail -20
    mkdir -p /tmp/table1 && cp -r /tmp/table1-report /tmp/table1/report
    for run in /tmp/run-*; do
        keep=/tmp/table1/$(basename "$run")
        mkdir -p "$keep" && cp "$run"/{config.json,log.csv,throughput.json} "$keep"/
        case "$run" in *ann6*) cp "$run/best.pt" "$keep"/ ;; esac
    done
    for ev in "${evals[@]}"; do
        mkdir -p "/tmp/table1/$(basename "$ev")" && cp "$ev"/metrics.json "/tmp/table1/$(basename "$ev")"/
    done
    tar -czf "${OUT:-/tmp}/table1.tgz" -C /tmp table1
    ;;
*)
    echo "usage: bash relay/table1.sh data | train MODEL INPUT MINUTES | score" >&2
    exit 2
    ;;
esac
