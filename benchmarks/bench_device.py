"""The painting cycle and painting-policy training on the CPU and, when there is one, on a CUDA
GPU, in one run: the one script a session with a card runs (design notes, section 11).

    .venv/bin/python benchmarks/bench_device.py [--seeds 0,1] [--cycles 5] [--train-steps 300]
        [--devices cpu,cuda] [--policy distilled] [--eager] [--json OUT.json]

Per device, each in a fresh process (a CUDA context or a warmed allocator must not carry over):

- the benchmark's painting run (``rapidds run painting --human left-slow --gamma 12``, full
  adaptation, default search), one torch thread: wall and process CPU seconds of the first
  cycle and the median of the later ones, the planning part, and the records' digest; on cuda
  also the first cycle of a run (the first seed, 2 cycles) after a small batch through the
  network on the card, to tell the kernels' loading from the rest of a first cycle; on the CPU
  also the first seed's later cycles with 4 torch threads (a workstation's cores);
- ``train-policy --world painting`` at the shipped network size and batch (64): milliseconds
  per optimiser step after a warm-up of 20 steps: float32 (on cuda a captured CUDA graph,
  train_policy's default there) and on cuda also float32 launched op by op, float32 captured
  with cudnn.benchmark, float32 captured with the network compiled, and float32 captured at
  batch 256 of the shipped policy's 384 demonstrations (a batch chosen for the device; bf16
  autocast, slower on the H200 twice, is no longer measured); and the mean loss of the last 50
  steps (``--train-steps 0``: not measured).

``--policy``: the runs plan with that checkpoint, or one the world ships by name
(``rapidds run --policy``); training stays the shipped network's. On cuda the runs replay the
network's passes and the steering value's calls from CUDA graphs (``DiffusionPolicy.cuda_graphs``,
the default since 2026-11-28); ``--eager``: they launch them one by one instead, the same
kernels on the same inputs, so their records' digests must be the default's.

A GPU's numbers count only beside the CPU's of the same machine in the same run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from _common import child_env, cpu_model, load_average, parse_seeds, sync

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def cycles_on(device: str, seed: int, cycles: int, policy: str | None = None,
              warm_up: bool = False, threads: int = 1, cuda_graphs: bool | None = None
              ) -> dict[str, object]:
    """One painting run on ``device`` (in this process): per-cycle wall, CPU and plan seconds;
    ``warm_up``: a small batch through the network first; ``threads``: torch's intra-op
    threads; ``cuda_graphs``: whether the network's passes and the value's calls replay CUDA
    graphs (None: the policy's default; bench_painting_cycle.run_seed)."""
    from bench_painting_cycle import run_seed

    return run_seed(seed, cycles, device=device, policy=policy, warm_up=warm_up,
                    threads=threads, cuda_graphs=cuda_graphs)


def training_on(device: str, steps: int, amp: bool, graph: bool | None = None,
                cudnn_benchmark: bool = False, compiled: bool = False,
                batch_size: int | None = None, flags: dict[str, object] | None = None,
                gemm_convs: bool = False) -> dict[str, object]:
    """ms per optimiser step of the painting policy at its shipped size on ``device``;
    ``graph``: train_policy's cuda_graph (None: its default, a captured step on a GPU);
    ``cudnn_benchmark``: let cuDNN time its convolution algorithms first (not rapidds's
    default: the choice can differ between runs, and so can the weights); ``compiled``: the
    network compiled (``nn.Module.compile``, inductor's default mode) inside the step, a probe
    of what fusing its elementwise work would buy (not a train_policy option: compiling takes
    longer than a short training saves); its compiles are counted, so a timed run that
    compiled again shows; ``batch_size``: another than the shipped 64 (what a batch chosen
    for the device would cost per step, and its loss after as many steps); ``flags``:
    ``torch.backends`` settings by dotted name (``{"cudnn.enabled": False}``), a probe of
    other convolution kernels (``--train-probes``); ``gemm_convs``: the network's stride-1
    convolutions computed as one matrix product over the unfolded input (a probe: a network
    of 24-96 channels over 16 steps is all latency, and cuDNN picked FFT convolutions for its
    backward pass, about 0.1 ms a call on the H200)."""
    import torch

    torch.backends.cudnn.benchmark = cudnn_benchmark
    for name, value in (flags or {}).items():
        *path, attr = name.split(".")
        owner = torch.backends
        for part in path:
            owner = getattr(owner, part)
        setattr(owner, attr, value)

    from rapidds.cli.motion import _world_demos
    from rapidds.motion import train as train_module
    from rapidds.motion.config import DiffusionConfig
    from rapidds.motion.train import train_policy

    if gemm_convs:  # this process only: every stride-1 Conv1d
        import torch.nn.functional as F

        plain = torch.nn.Conv1d._conv_forward

        def gemm(self, x, weight, bias):  # type: ignore[no-untyped-def]
            if self.stride != (1,) or self.dilation != (1,) or self.groups != 1:
                return plain(self, x, weight, bias)
            k, pad = weight.shape[-1], self.padding[0]
            cols = F.pad(x, (pad, pad)).unfold(2, k, 1)  # (B, C, L, k), a view
            y = torch.einsum("bclk,ock->bol", cols, weight)
            return y if bias is None else y + bias[:, None]

        torch.nn.Conv1d._conv_forward = gemm  # type: ignore[method-assign]
    if compiled:  # this process only: every network train_policy builds is compiled
        build = train_module.DiffusionPolicy.from_config

        def build_compiled(*args, **kwargs):  # type: ignore[no-untyped-def]
            policy = build(*args, **kwargs)
            policy.model.compile()
            return policy

        train_module.DiffusionPolicy.from_config = build_compiled  # type: ignore[method-assign]

    torch.set_num_threads(1)
    # 96 demonstrations, or the shipped policy's 384 for a batch larger than 96
    demos, fields = _world_demos("painting", 16 if (batch_size or 0) <= 96 else 64, 0)
    fields.update(horizon=demos.horizon, state_dim=demos.state_dim,
                  task_names=list(demos.task_names), steps=20, device=device,
                  **({} if batch_size is None else {"batch_size": batch_size}))
    warm = DiffusionConfig.from_dict(fields)
    train_policy(demos, warm, mixed_precision=amp, cuda_graph=graph)  # allocator, kernels
    cfg = warm.replace(steps=steps)

    def compiles() -> int:
        from torch._dynamo.utils import counters

        return int(counters["stats"]["unique_graphs"])

    before = compiles()
    w0, c0 = time.perf_counter(), time.process_time()
    _, history = train_policy(demos, cfg, mixed_precision=amp, cuda_graph=graph)
    sync(device)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    return {"ms_per_step": 1000 * wall / steps, "cpu_ms_per_step": 1000 * cpu / steps,
            "steps": steps, "final_loss": history.mean_loss(last=50),
            "cuda_graph": history.cuda_graph, "graph_note": history.graph_note,
            "compiles_while_timed": compiles() - before}


SRC = ROOT / "src"  # the rapidds the runs import (--src: an older checkout's, for a before)


def _child(what: str, *args: object, probe: bool = False) -> dict:
    """``what(*args)`` in a fresh process. ``probe``: a row never run on a card before, whose
    failure is reported as its result ({"error": ...}) rather than ending the measurement."""
    env = child_env(SRC, HERE)
    code = (f"import json, bench_device as b; print(json.dumps(b.{what}"
            f"({', '.join(map(repr, args))})))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=not probe)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["no message"])[-1][:300]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure(devices: list[str], seeds: list[int], cycles: int, steps: int,
            policy: str | None = None, train_on: list[str] | None = None,
            eager: bool = False, save: Callable[[dict], None] | None = None) -> dict:
    """Every device's rows; ``save`` is given what is measured so far after each row, so a
    part cut short by its time limit keeps what it had."""
    out: dict[str, dict] = {}

    def done(dev: str, key: str, value: object) -> None:
        out[dev][key] = value
        if save is not None:
            save(out)

    for dev in devices:
        graphs = False if eager and dev == "cuda" else None  # None: the policy's default
        runs = [_child("cycles_on", dev, s, cycles, policy, False, 1, graphs) for s in seeds]
        first = [r["cpu"][0] for r in runs]
        later = [c for r in runs for c in r["cpu"][1:]]
        later_wall = [c for r in runs for c in r["wall"][1:]]
        out[dev] = {
            "first_cycle_wall": statistics.median(r["wall"][0] for r in runs),
            "first_cycle_cpu": statistics.median(first),
            "later_wall_median": statistics.median(later_wall),
            "later_cpu_median": statistics.median(later),
            "later_plan_median": statistics.median(p for r in runs for p in r["plan"][1:]),
            # the belief's update (on a GPU its distances are found there since this was added)
            "later_update_median": statistics.median(u for r in runs for u in r["update"][1:]),
            "later_requests": [q for r in runs for q in r.get("requests", [])[1:]],
            "digests": [r["digest"] for r in runs],
            # the run's construction: its prior and, on a GPU, its warm-up (older trees: none)
            "construct_wall": [c for r in runs for c in r.get("construct", [])],
        }
        if any("graphs" in r for r in runs):  # per run: the shapes captured, why one failed
            out[dev]["graphs"] = [r.get("graphs") for r in runs]
        if graphs is False:
            out[dev]["eager"] = True
        if save is not None:
            save(out)
        if dev == "cpu":  # a workstation's CPU with more than one core for torch
            four = _child("cycles_on", dev, seeds[0], cycles, policy, False, 4)
            done(dev, "later_wall_median_4_threads", statistics.median(four["wall"][1:]))
        # the first cycle after a batch through the network before the run as well (the run
        # warms up its own kernels on a GPU: equal to the plain first cycle unless it misses some)
        if dev == "cuda":
            warmed = _child("cycles_on", dev, seeds[0], 2, policy, True, 1, graphs)
            out[dev]["first_cycle_wall_after_warm_up"] = warmed["wall"][0]
            done(dev, "digests_after_warm_up", warmed["digest"])
        if steps > 0 and (train_on is None or dev in train_on):
            done(dev, "train_fp32", _child("training_on", dev, steps, False))
        # on cuda: launched op by op beside the captured step, train_policy's default there
        if "train_fp32" in out[dev] and dev == "cuda":
            done(dev, "train_fp32_eager", _child("training_on", dev, steps, False, False))
            done(dev, "train_fp32_cudnn_benchmark",
                 _child("training_on", dev, steps, False, None, True))
            # bf16 autocast, slower than float32 on the H200 twice, gave way to these
            done(dev, "train_fp32_compiled",
                 _child("training_on", dev, steps, False, None, False, True, probe=True))
            done(dev, "train_fp32_batch256",
                 _child("training_on", dev, steps, False, None, False, False, 256, probe=True))
        print(f"{dev}: {json.dumps(out[dev])}", flush=True)
    return out


# where a captured step's 10-16 ms go on the H200 (2026-11-28: 6-13 ms of kernels, cuDNN
# choosing FFT convolutions for these length-16 sequences): other kernels for the same step
# (batch size, torch.backends flags, the stride-1 convolutions as matrix products)
PROBES: dict[str, tuple[int | None, dict[str, object], bool]] = {
    "train_fp32": (None, {}, False),
    # the painting network is tiny (24-96 channels, length 16): a step is latency, so one
    # matrix product per convolution is the candidate, in float32 and in TF32 (cuDNN's own
    # default for its convolutions)
    "train_fp32_gemm_convs": (None, {}, True),
    "train_fp32_gemm_convs_tf32": (None, {"cuda.matmul.allow_tf32": True}, True),
    "train_fp32_cudnn_off": (None, {"cudnn.enabled": False}, False),  # ATen's own kernels
    "train_fp32_cudnn_deterministic": (None, {"cudnn.deterministic": True}, False),
    "train_fp32_tf32_matmul": (None, {"cuda.matmul.allow_tf32": True}, False),
}


def train_probes(steps: int, save: Callable[[dict], None]) -> dict:
    """The captured training step on cuda with each of :data:`PROBES`' settings, each in a
    fresh process; a failure is that row's result."""
    out: dict[str, dict] = {"cuda": {}}
    for key, (batch, flags, gemm) in PROBES.items():
        out["cuda"][key] = _child("training_on", "cuda", steps, False, None, False, False,
                                  batch, flags, gemm, probe=True)
        print(key, json.dumps(out["cuda"][key]), flush=True)
        save(out)
    return out


def markdown(res: dict, seeds: list[int], cycles: int, load0: str,
             policy: str | None = None) -> str:
    rows = []
    for dev, r in res.items():
        train = ("-" if "train_fp32" not in r else
                 f"{r['train_fp32']['ms_per_step']:.1f} (loss {r['train_fp32']['final_loss']:.4f})")
        for key, label in (("train_fp32_eager", "fp32 eager"),
                           ("train_fp32_cudnn_benchmark", "fp32 cudnn.benchmark"),
                           ("train_fp32_compiled", "fp32 compiled"),
                           ("train_fp32_batch256", "fp32 batch 256")):
            if key in r and "error" in r[key]:
                train += f"; {label} failed: {r[key]['error']}"
            elif key in r:
                train += (f"; {label} {r[key]['ms_per_step']:.1f} "
                          f"(loss {r[key]['final_loss']:.4f})")
        warmed = ("" if "first_cycle_wall_after_warm_up" not in r else
                  f" ({r['first_cycle_wall_after_warm_up']:.2f} wall after a warm-up)")
        if r.get("construct_wall"):
            warmed += f" (run made in {statistics.median(r['construct_wall']):.2f} s)"
        four = ("" if "later_wall_median_4_threads" not in r else
                f" ({r['later_wall_median_4_threads']:.2f} wall with 4 threads)")
        name = f"{dev}, eager" if r.get("eager") else dev
        rows.append(f"| {name} | {r['first_cycle_wall']:.2f} / "
                    f"{r['first_cycle_cpu']:.2f}{warmed} | "
                    f"{r['later_wall_median']:.2f} / {r['later_cpu_median']:.2f}{four} | "
                    f"{r['later_plan_median']:.2f} / {r['later_update_median']:.3f} | "
                    f"{sum(r['later_requests'])} | {train} |")
    gpu = ""
    if "cuda" in res:
        import torch

        gpu = f", GPU {torch.cuda.get_device_name(0)}"
    chosen = "" if policy is None else f" --policy {policy}"
    return (f"`benchmarks/bench_device.py --seeds {','.join(map(str, seeds))} --cycles "
            f"{cycles}{chosen}`: {cpu_model()}{gpu}, one torch thread; 1-min load average "
            f"{load0} at start, {load_average()} at end.\n\n"
            "| device | first cycle wall / CPU s | later cycles wall / CPU s (median) | "
            "plan / learn wall s (median) | later cycles' steering requests | "
            "training ms per step (final loss) |\n|---|---:|---:|---:|---:|---|\n"
            + "\n".join(rows) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--train-steps", type=int, default=300)
    ap.add_argument("--devices", default=None, help="default: cpu, and cuda when available")
    ap.add_argument("--train-on", default=None,
                    help="train on these of the devices only (default: all of them)")
    ap.add_argument("--policy", default=None,
                    help="plan with this checkpoint or shipped policy name (distilled)")
    ap.add_argument("--eager", action="store_true",
                    help="on cuda, launch the network's passes and the value's calls one by one "
                         "instead of replaying CUDA graphs (DiffusionPolicy.cuda_graphs = False); "
                         "the records must equal the default's")
    ap.add_argument("--train-probes", action="store_true",
                    help="only the captured training step on cuda with other kernels (PROBES)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--src", type=Path, default=None,
                    help="measure the rapidds of this src directory (an older checkout's: "
                         "the before of a change, on the same machine in the same run)")
    args = ap.parse_args()
    global SRC
    if args.src is not None:
        SRC = args.src.resolve()
    import torch

    devices = (args.devices.split(",") if args.devices
               else ["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
    load0 = load_average()
    seeds = parse_seeds(args.seeds)
    def save(res: dict) -> None:  # after every row: a part cut short keeps what it had
        if args.json is not None:
            tmp = args.json.with_suffix(".partial")
            tmp.write_text(json.dumps(res, indent=2) + "\n")
            tmp.replace(args.json)

    if args.train_probes:
        save(train_probes(args.train_steps, save))
        return
    res = measure(devices, seeds, args.cycles, args.train_steps, args.policy,
                  args.train_on.split(",") if args.train_on else None, args.eager, save)
    print(markdown(res, seeds, args.cycles, load0, args.policy))
    save(res)


if __name__ == "__main__":
    main()
