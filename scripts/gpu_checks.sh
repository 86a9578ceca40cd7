#!/bin/bash
# The checks that need an NVIDIA GPU, run from the repository root; results go under OUT_DIR:
#
#   scripts/gpu_checks.sh OUT_DIR tests   # the CUDA and Triton tests (they skip without a GPU)
#   scripts/gpu_checks.sh OUT_DIR bench   # `predict --device cuda` throughput against the CPU stream
#
# The bench simulates its recordings first, in parallel (about 3 minutes of simulation per minute
# of events on one core), so the timings cover prediction only; together about 8 minutes on a
# 16-core H100 machine. Needs `pip install -e '.[gpu,test]'` and a CUDA build of PyTorch.
set -eo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=.
[ $# -eq 2 ] || { sed -n '4,5p' "$0" | sed 's/^# *//' >&2; exit 2; }
OUT_DIR=$1
mkdir -p "$OUT_DIR"
case "$2" in
tests)
    python3 -m pytest -q -p no:cacheprovider tests/test_snn_triton.py tests/test_stream_batched.py \
        tests/test_events_binning_torch.py 2>&1 | tee "$OUT_DIR/gpu_tests.txt"
    ;;
bench)
    nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee "$OUT_DIR/gpu.txt"
    python3 bench/batched_predict.py --device cuda --sequences 4 --duration-ms 15000 \
        | tee "$OUT_DIR/batched_4x15s.txt"
    python3 bench/batched_predict.py --device cuda --sequences 1 --duration-ms 30000 \
        | tee "$OUT_DIR/batched_1x30s.txt"
    ;;
*)
    echo "usage: scripts/gpu_checks.sh OUT_DIR tests | bench" >&2
    exit 2
    ;;
esac
