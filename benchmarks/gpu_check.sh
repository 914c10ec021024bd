#!/usr/bin/env bash
# Issue 36 on a machine with a CUDA GPU, in one run of about 7-8 minutes: the painting cycle and
# painting-policy training on cpu and cuda (bench_device.py: 2 seeds x 5 cycles; 300 training
# steps, float32, and on cuda also float32 op by op and bf16), the painting cycle with the
# shipped distilled policy on cpu and cuda, then one cycle's steering batch with the value on
# the host and on the device, each without and with the monitor's predicted hold, with the host
# synchronisations inside it (bench_steer_device.py).
# Most important first; a part that fails or runs out of time is logged and the next one still
# runs. From anywhere (a GPU machine lacking packages: PAYLOAD from benchmarks/gpu_payload.sh):
#     OUT=/some/dir PYTHON=python3 [PAYLOAD=.dev/site312.tar.xz] [TRAIN_ON=cuda] \
#         [COMMIT=$(git rev-parse --short HEAD)] benchmarks/gpu_check.sh
# On the H200 of 2026-11-27 (docs/benchmarks.md, "The GPU measured"): unpacking and imports 28 s,
# the device part 174 s with TRAIN_ON=cuda (expect about 50 s more now: the paper's network's
# cpu runs really on the CPU, a 4-thread CPU run and a warmed-up cuda run), the distilled part
# over 100 s (its CPU cycles took 0.8-1.1 s on that Xeon), the steering batch about 40 s (80 s
# now, with the hold's two runs). COMMIT: a device's copy of .git can be stale (it was there),
# so name the commit measured.
# First, about 25 s here (up to twice that on a slower core): the CPU's facts (cpu_facts.py: its
# vector units, torch's and oneDNN's settings and kernels, one pass of each network on that CPU,
# and in bf16, which an AMX Xeon may run far faster). Results: $OUT/cpu_facts.json,
# $OUT/device.json, $OUT/distilled.json, $OUT/steer.json and $OUT/gpu_check.log (a device
# session brings back 8). The GPU's numbers count only beside the CPU's of the same machine in
# the same run (docs/benchmarks.md); before 2026-11-27's last session, the paper's network's
# "cpu" runs ran on the GPU (bench_painting_cycle loaded it on "auto").
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python}
OUT=${OUT:-/tmp/gpu-check}
LOG="$OUT/gpu_check.log"
mkdir -p "$OUT"
if [ -n "${PAYLOAD:-}" ]; then
    mkdir -p /tmp/rapidds-site && tar xJf "$PAYLOAD" -C /tmp/rapidds-site
    export PYTHONPATH="/tmp/rapidds-site${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
part() {  # part SECONDS NAME COMMAND...: run, log, and go on whatever its exit status
    local limit=$1 name=$2; shift 2
    echo "== $name ($(date -u +%T), load $(cut -d' ' -f1 /proc/loadavg))" | tee -a "$LOG"
    timeout "$limit" "$@" 2>&1 | tee -a "$LOG"
    echo "== $name: exit ${PIPESTATUS[0]}" | tee -a "$LOG"
}
{ echo "commit ${COMMIT:-$(git rev-parse --short HEAD 2>/dev/null || echo unknown)}"; nproc
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader \
      || echo "no nvidia-smi"; } 2>&1 | tee -a "$LOG"
part 30 versions "$PY" -c "import torch, diffusers, mujoco, rapidds; print('torch', \
torch.__version__, 'cuda', torch.cuda.is_available(), 'diffusers', diffusers.__version__, \
'mujoco', mujoco.__version__)"
part 90 cpu_facts "$PY" benchmarks/cpu_facts.py --repeats 7 --out "$OUT/cpu_facts.json"
# TRAIN_ON=cuda: skip the CPU's training steps (about 40 s), measured once per machine kind
part 280 device "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 300 \
    --train-on "${TRAIN_ON:-cpu,cuda}" --json "$OUT/device.json"
part 150 distilled "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 0 \
    --policy distilled --json "$OUT/distilled.json"
part 120 steer "$PY" benchmarks/bench_steer_device.py --repeat 3 --json "$OUT/steer.json"
