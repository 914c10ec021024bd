#!/usr/bin/env bash
# Issue 36 on a machine with a CUDA GPU, in one run of about 6 minutes (under 10): the painting
# cycle and painting-policy training on cpu and cuda (bench_device.py: 2 seeds x 5 cycles, 300
# training steps per device, float32 and on cuda bf16), then one cycle's steering batch with
# the value on the host and on the device, with the host synchronisations inside it
# (bench_steer_device.py), then the painting cycle with the shipped distilled policy (bench_device.py
# --policy distilled) on cpu and cuda, 2 seeds x 5 cycles. Run from anywhere:
#     OUT=/some/dir PYTHON=.venv/bin/python benchmarks/gpu_check.sh
# Results: $OUT/device.json, $OUT/steer.json and the logs beside them. The GPU's numbers count
# only beside the CPU's of the same machine in the same run (docs/benchmarks.md).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python}
OUT=${OUT:-/tmp/gpu-check}
mkdir -p "$OUT"
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
git rev-parse --short HEAD 2>/dev/null | tee "$OUT/commit.txt" || true
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader \
    | tee "$OUT/gpu.txt" || echo "no nvidia-smi" | tee "$OUT/gpu.txt"
"$PY" -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
timeout 360 "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 300 \
    --json "$OUT/device.json" 2>&1 | tee "$OUT/device.log"
timeout 100 "$PY" benchmarks/bench_steer_device.py --repeat 5 --json "$OUT/steer.json" 2>&1 \
    | tee "$OUT/steer.log"
timeout 150 "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 0 \
    --policy distilled --json "$OUT/distilled.json" 2>&1 | tee "$OUT/distilled.log"
