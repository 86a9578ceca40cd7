#!/usr/bin/env bash
# Train in time-limited segments: one call trains one segment of a `spikegyro train` run, ends it
# with a checkpoint, and folds its log into the run's joined log (relay_log.csv, relay_curve.png).
# Call it again, on the same or another machine, to continue; nothing else to keep track of.
#
#   scripts/train_segments.sh OUT_DIR --minutes M [--total-minutes T] [--note TEXT] -- TRAIN_OPTIONS
#
#   OUT_DIR            the run directory (created by the first segment, resumed by the others)
#   --minutes M        training time of this segment; leave room in the job's limit for start-up
#                      and the final validation and checkpoint (a few minutes on a GPU)
#   --total-minutes T  stop for good once the run has trained T minutes (later calls exit at once)
#   --note TEXT        recorded with the segment in OUT_DIR/relay.json (e.g. the machine)
#   TRAIN_OPTIONS      `spikegyro train` options, e.g. --data DATA --preset paper; on later
#                      segments they override the stored configuration (the model may not change)
#
# SIGINT or SIGTERM (Ctrl-C, a spot instance's notice, Slurm's --signal) stops the segment after
# the current step with a checkpoint, as the time budget does. $SPIKEGYRO overrides the command
# (default: python3 -m spikegyro, or $PYTHON -m spikegyro). Runs on any CUDA machine or a CPU.
set -euo pipefail

usage() {
    sed -n '5,13p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
}

[ $# -ge 1 ] || usage
case "$1" in -h | --help) usage ;; esac
OUT_DIR=$1
shift
MINUTES="" TOTAL="" NOTE=""
while [ $# -gt 0 ]; do
    case "$1" in
    --minutes) MINUTES=$2; shift 2 ;;
    --total-minutes) TOTAL=$2; shift 2 ;;
    --note) NOTE=$2; shift 2 ;;
    --) shift; break ;;
    -h | --help) usage ;;
    *) echo "train_segments.sh: unknown option $1 (spikegyro train options go after --)" >&2; exit 2 ;;
    esac
done
[ -n "$MINUTES" ] || { echo "train_segments.sh: --minutes M is required" >&2; exit 2; }

PY=${PYTHON:-python3}
read -r -a SG <<<"${SPIKEGYRO:-$PY -m spikegyro}"

# Minutes the run has already trained (0 before the first segment); --max-minutes counts them.
stored=$("$PY" -c 'import sys; from spikegyro.train.relay import stored_minutes
print(f"{stored_minutes(sys.argv[1]):.3f}")' "$OUT_DIR")
budget=$("$PY" -c 'import sys; s, m, t = sys.argv[1:4]
b = float(s) + float(m)
b = min(b, float(t)) if t else b
print(f"{b:.3f}" if b > float(s) + 0.01 else "done")' "$stored" "$MINUTES" "$TOTAL")
if [ "$budget" = done ]; then
    echo "$OUT_DIR has trained $stored of $TOTAL minutes: nothing left to do."
    exit 0
fi

resume=()
[ -f "$OUT_DIR/last.pt" ] && [ -f "$OUT_DIR/resume.pt" ] && resume=(--resume)
echo "segment: $OUT_DIR from $stored to $budget minutes of training ${resume[*]:+(resumed)}"

# Run the trainer in the background so that a signal to this script reaches it as a graceful stop.
"${SG[@]}" train --out "$OUT_DIR" "${resume[@]}" --max-minutes "$budget" "$@" &
pid=$!
stop() { echo "train_segments.sh: stopping the segment with a checkpoint" >&2; kill -INT "$pid" 2>/dev/null || true; }
trap stop INT TERM
status=0
wait "$pid" || status=$?
# A trapped signal interrupts `wait`: wait again for the trainer to finish its checkpoint.
while [ "$status" -gt 128 ] && kill -0 "$pid" 2>/dev/null; do status=0; wait "$pid" || status=$?; done
trap - INT TERM

# 130: stopped by a signal after writing its checkpoint; the segment still counts.
if [ "$status" -ne 0 ] && [ "$status" -ne 130 ]; then
    echo "train_segments.sh: spikegyro train failed (exit $status); the log was not folded" >&2
    exit "$status"
fi
if [ -f "$OUT_DIR/log.csv" ]; then
    "${SG[@]}" relay-log "$OUT_DIR" --relay "$OUT_DIR" --note "$NOTE" ||
        echo "train_segments.sh: no new log rows to fold in" >&2
fi
echo "continue with the same command: $0 $OUT_DIR --minutes $MINUTES${TOTAL:+ --total-minutes $TOTAL} -- $*"
