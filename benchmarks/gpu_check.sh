#!/usr/bin/env bash
# Issue 36 on a machine with a CUDA GPU, most important first (on the H200 of 2026-11-28 one
# call's 590 s reached the distilled part; the rest in a second call, PARTS):
#   device      the painting cycle and painting-policy training on cpu and cuda (bench_device.py:
#               2 seeds x 5 cycles; 300 training steps, float32 captured, and on cuda also
#               float32 op by op, with cudnn.benchmark, with the network compiled and at
#               batch 256), about 290 s with TRAIN_ON=cuda (compiling about 40 s of it);
#   graph_check whether replayed CUDA graphs give the eager results bit for bit (the network,
#               sample, a steering batch's value) and what a replayed pass saves
#               (gpu_graph_check.py), about 30 s;
#   eager       the cuda cycles with the network's passes and the steering value's calls
#               launched one by one, not replayed from CUDA graphs as by default
#               (bench_device.py --eager): their digests must be the device part's, about 60 s;
#   base        with BASE (an older checkout's src as a tarball: git archive --format=tar
#               <commit> src | xz > .dev/base-src.tar.xz), the same cuda cycles of that tree,
#               the before of this tree's change on the same card in the same run, about 80 s;
#   profile     where the device's time goes: the kernels of a training step (op by op) and of
#               a steering batch with and without CUDA graphs, by device time, beside the wall
#               time (gpu_profile.py), about 60 s;
#   steer       one cycle's steering batch with the value on the host and on the device, each
#               without and with the monitor's predicted hold, the device's also with CUDA
#               graphs: seconds, host synchronisations, the kernels it launches and the plans'
#               digests (bench_steer_device.py), about 110 s;
#   steer-base  the same steering batch of the BASE tree, on cuda, about 60 s;
#   distilled   the painting cycle with the shipped distilled policy on cpu and cuda, over 100 s;
#   quality     plan quality on cuda: 8 seeds x 7 cycles of the painting run in one process
#               (gpu_quality.py), each cycle's realised cost, about 35 s;
#   quality-base the same for the BASE tree (its belief updated on the host), to pair with
#               quality (gpu_quality.py report), about 35 s;
#   probes      the captured training step with other convolution kernels (each stride-1
#               convolution one matrix product, in float32 and TF32; cuDNN off; cuDNN
#               deterministic; TF32 matmuls; bench_device.py --train-probes), about 70 s:
#               what the training goal needs next (docs/benchmarks.md, "The GPU measured
#               again"), so PARTS="profile probes" first in a session with a card;
#   cpu_facts   the CPU's facts (cpu_facts.py: vector units, torch's and oneDNN's settings and
#               kernels, one pass of each network, also in bf16), about 25 s.
# A part that fails or runs out of time is logged and the next one still runs; PARTS picks
# some (a second call for what one call's 10 minutes did not reach). From anywhere (a GPU
# machine lacking packages: PAYLOAD from benchmarks/gpu_payload.sh):
#     OUT=/some/dir PYTHON=python3 [PAYLOAD=.dev/site312.tar.xz] [TRAIN_ON=cuda] \
#         [BASE=.dev/base-src.tar.xz] [PARTS="device steer"] \
#         [COMMIT=$(git rev-parse --short HEAD)] benchmarks/gpu_check.sh
# On the H200 of 2026-11-27 (docs/benchmarks.md, "The GPU measured") unpacking and imports
# took 28 s. COMMIT: a device's copy of .git can be stale (it was there), so name the commit
# measured. Results: $OUT/device.json, graph_check.json, eager.json, base.json, steer.json,
# profile.json, steer-base.json, distilled.json, cpu_facts.json, quality.json,
# quality-base.json, probes.json and gpu_check.log. The GPU's
# numbers count only beside the CPU's of the same machine in the same run
# (docs/benchmarks.md); before 2026-11-27's last session, the paper's network's "cpu" runs ran
# on the GPU (bench_painting_cycle loaded it on "auto").
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
PARTS=${PARTS:-device graph_check eager base profile steer steer-base distilled quality \
    quality-base probes cpu_facts}
part() {  # part SECONDS NAME COMMAND...: run, log, and go on whatever its exit status
    local limit=$1 name=$2; shift 2
    case " versions $PARTS " in *" $name "*) ;; *) return 0 ;; esac
    echo "== $name ($(date -u +%T), load $(cut -d' ' -f1 /proc/loadavg))" | tee -a "$LOG"
    timeout "$limit" "$@" 2>&1 | tee -a "$LOG"
    echo "== $name: exit ${PIPESTATUS[0]}" | tee -a "$LOG"
}
BASE_SRC=
if [ -n "${BASE:-}" ]; then
    mkdir -p /tmp/rapidds-base && tar xJf "$BASE" -C /tmp/rapidds-base && BASE_SRC=/tmp/rapidds-base/src
fi
{ echo "commit ${COMMIT:-$(git rev-parse --short HEAD 2>/dev/null || echo unknown)}"; nproc
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader \
      || echo "no nvidia-smi"; } 2>&1 | tee -a "$LOG"
part 30 versions "$PY" -c "import torch, diffusers, mujoco, rapidds; \
print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'diffusers', \
diffusers.__version__, 'mujoco', mujoco.__version__)"
# TRAIN_ON=cuda: skip the CPU's training steps (about 40 s), measured once per machine kind
part 330 device "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 300 \
    --train-on "${TRAIN_ON:-cpu,cuda}" --json "$OUT/device.json"
part 60 graph_check "$PY" benchmarks/gpu_graph_check.py --json "$OUT/graph_check.json"
part 120 eager "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 0 \
    --devices cuda --eager --json "$OUT/eager.json"
[ -n "$BASE_SRC" ] && part 120 base "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 \
    --train-steps 0 --devices cuda --src "$BASE_SRC" --json "$OUT/base.json"
part 120 profile "$PY" benchmarks/gpu_profile.py --json "$OUT/profile.json"
part 150 steer "$PY" benchmarks/bench_steer_device.py --repeat 3 --json "$OUT/steer.json"
[ -n "$BASE_SRC" ] && part 90 steer-base env PYTHONPATH="$BASE_SRC:$PYTHONPATH" "$PY" \
    benchmarks/bench_steer_device.py --devices cuda --repeat 3 --json "$OUT/steer-base.json"
part 150 distilled "$PY" benchmarks/bench_device.py --seeds 0,1 --cycles 5 --train-steps 0 \
    --policy distilled --json "$OUT/distilled.json"
part 90 quality "$PY" benchmarks/gpu_quality.py run --device cuda --seeds 0-7 --cycles 7 \
    --json "$OUT/quality.json"
[ -n "$BASE_SRC" ] && part 90 quality-base env PYTHONPATH="$BASE_SRC:$PYTHONPATH" "$PY" \
    benchmarks/gpu_quality.py run --device cuda --seeds 0-7 --cycles 7 \
    --json "$OUT/quality-base.json"
part 120 probes "$PY" benchmarks/bench_device.py --train-probes --train-steps 300 \
    --json "$OUT/probes.json"
part 90 cpu_facts "$PY" benchmarks/cpu_facts.py --repeats 7 --out "$OUT/cpu_facts.json"
exit 0
