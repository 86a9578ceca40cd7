#!/bin/bash
# The checks that only a GPU machine can run (issue 15, part 3; issue 18's Triton kernels), one
# device call each, results under $OUT:
#
#   bash relay/gpu_checks.sh tests   # the CUDA/Triton tests (skipped on machines without a GPU)
#   bash relay/gpu_checks.sh bench   # `predict --device cuda` throughput against the CPU stream
#
# The bench simulates its recordings first, in parallel (about 3 minutes of simulation per minute
# of events on one core), so the timings cover prediction only; together about 8 minutes on an H100
# machine's 16 cores. BENCHMARKS.md ("`predict --device`") is where the numbers go.
set -eo pipefail
export PYTHONUNBUFFERED=1 PYTHONPATH=.
case "$1" in
tests)
    python3 -m pytest -q -p no:cacheprovider tests/test_snn_triton.py tests/test_stream_batched.py \
        tests/test_events_binning_torch.py 2>&1 | tee "$OUT/gpu_tests.txt"
    ;;
bench)
    nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee "$OUT/gpu.txt"
    python3 bench/batched_predict.py --device cuda --sequences 4 --duration-ms 15000 \
        | tee "$OUT/batched_4x15s.txt"
    python3 bench/batched_predict.py --device cuda --sequences 1 --duration-ms 30000 \
        | tee "$OUT/batched_1x30s.txt"
    ;;
*)
    echo "usage: bash relay/gpu_checks.sh tests | bench" >&2
    exit 2
    ;;
esac
