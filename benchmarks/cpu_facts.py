"""What decides a painting network's speed on this machine's CPU: the processor's vector units,
torch's and oneDNN's settings, the kernels oneDNN picks, and one pass of each shipped network.

    .venv/bin/python benchmarks/cpu_facts.py [--rows 192,288] [--repeats 15] [--out FILE]

Part of ``gpu_check.sh``: on a lent machine, whose CPU is not this project's AMD EPYC, it says
how fast each network's pass is there and whether anything (a precision mode, a reference
kernel, subnormal floats) makes that CPU a special case. Per network and batch size it times one
pass (one torch thread, median of ``--repeats``) with and without flush-to-zero (Intel cores
slow down on subnormal floats, AMD's far less), counts the convolutions' floating-point
operations, so a rate beyond the core's float32 peak shows reduced precision, and lists the
implementations oneDNN ran (``ONEDNN_VERBOSE``, in a child process), where a reference
kernel (``ref``, ``gemm:ref``) would be the slow path. Then, at 192 rows, the pass in reduced
precision, which the product does not use (its records are float32's): oneDNN's bf16 mode for
float32 convolutions and torch's bf16 autocast, with their relative error against float32. Here
(AVX-512 with bf16, no AMX) autocast saved about a quarter of a pass; a CPU with AMX tiles may
save far more, which would make a reduced-precision option worth measuring for plan quality.
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import child_env, cpu_model, middle_start  # noqa: E402

NETWORKS = ("paper", "distilled")
ENV = re.compile(r"^(ONEDNN|DNNL|MKL|OMP|KMP|GOMP|ATEN|TORCH|OPENBLAS)_")


def _flags() -> list[str]:
    """The vector extensions that matter to oneDNN (AVX-512 kinds, AMX, AVX2, FMA)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return []
    line = next((x for x in text.splitlines() if x.startswith("flags")), "")
    keep = ("avx512", "amx", "avx2", "fma", "avx_vnni")
    return sorted({f for f in line.split() if f.startswith(keep)})


def _network(name: str):
    from rapidds.loop.run import load_policy
    from rapidds.worlds.registry import make_world

    return load_policy(make_world("painting"), None if name == "paper" else name, device="cpu")


def _inputs(policy, rows: int):
    import torch

    gen = torch.Generator().manual_seed(0)
    cfg = policy.config
    tasks = [cfg.task_names[i % len(cfg.task_names)] for i in range(rows)]
    cond = policy.condition(tasks, rows, middle_start(policy, rows))
    x = torch.randn(rows, cfg.horizon, cfg.state_dim, generator=gen)
    return x, cond


def _conv_flops(policy, x, cond) -> int:
    """Multiply-adds x 2 of every convolution in one pass (counted by hooking F.conv1d)."""
    import torch.nn.functional as F

    import rapidds.motion.inference as inference

    total = 0
    real = F.conv1d

    def counted(h, w, b=None, stride=1, padding=0, *rest):
        nonlocal total
        out = real(h, w, b, stride, padding, *rest)
        total += 2 * out.numel() * w.shape[1] * w.shape[2]
        return out

    inference.F.conv1d = counted
    try:
        policy.predict_noise(x, 5, cond)
    finally:
        inference.F.conv1d = real
    return total


def time_pass(name: str, rows: int, repeats: int, flush: bool) -> dict[str, float]:
    import torch

    torch.set_num_threads(1)
    torch.set_flush_denormal(flush)
    policy = _network(name)
    x, cond = _inputs(policy, rows)
    flops = _conv_flops(policy, x, cond)
    for _ in range(3):
        policy.predict_noise(x, 5, cond)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        policy.predict_noise(x, 5, cond)
        times.append(time.perf_counter() - t0)
    ms = 1000 * statistics.median(times)
    return {"ms": round(ms, 2), "conv_gflop": round(flops / 1e9, 3),
            "conv_gflops_per_s_if_all_time": round(flops / 1e9 / (ms / 1000), 1)}


PRECISIONS = ("onednn-bf16", "autocast-bf16")


def time_precision(name: str, rows: int, repeats: int, mode: str) -> dict[str, float]:
    """One pass in reduced precision ``mode`` against float32: ms of each (median, one torch
    thread) and the relative error of the noise prediction."""
    import contextlib

    import torch

    torch.set_num_threads(1)
    policy = _network(name)
    x, cond = _inputs(policy, rows)
    conv = getattr(torch.backends.mkldnn, "conv", None)
    if mode == "onednn-bf16" and not hasattr(conv, "fp32_precision"):
        return {"unsupported": 1.0}

    def run(reduced: bool) -> torch.Tensor:
        if not reduced:
            return policy.predict_noise(x, 5, cond)
        if mode == "autocast-bf16":
            with torch.autocast("cpu", dtype=torch.bfloat16):
                return policy.predict_noise(x, 5, cond).float()
        old = conv.fp32_precision
        conv.fp32_precision = "bf16"
        try:
            return policy.predict_noise(x, 5, cond)
        finally:
            conv.fp32_precision = old

    out: dict[str, float] = {}
    for reduced in (False, True):
        for _ in range(3):
            run(reduced)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            run(reduced)
            times.append(time.perf_counter() - t0)
        out["ms_" + (mode if reduced else "float32")] = round(1000 * statistics.median(times), 2)
    with contextlib.suppress(Exception):
        ref, low = run(False), run(True)
        out["relative_error"] = float((low - ref).norm() / ref.norm())
    return out


def kernels(name: str, rows: int) -> dict[str, int]:
    """oneDNN's primitives and implementations in one pass (a child with ONEDNN_VERBOSE=1)."""
    code = (f"import sys; sys.path.insert(0, {str(HERE)!r}); import cpu_facts as c, torch; "
            f"torch.set_num_threads(1); p = c._network({name!r}); x, k = c._inputs(p, {rows}); "
            "print('--pass--', flush=True); p.predict_noise(x, 5, k)")
    env = {**child_env(ROOT / "src", HERE), "ONEDNN_VERBOSE": "1", "DNNL_VERBOSE": "1"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=300)
    lines = proc.stdout.split("--pass--", 1)[-1].splitlines()
    seen: collections.Counter[str] = collections.Counter()
    for line in lines:
        parts = line.split(",")
        if len(parts) > 5 and parts[0].endswith("_verbose") and "exec" in parts:
            at = parts.index("exec")
            seen[f"{parts[at + 2]}:{parts[at + 3]}"] += 1  # primitive:implementation
    return dict(seen.most_common())


def facts() -> dict[str, object]:
    import torch

    out: dict[str, object] = {
        "cpu": cpu_model(), "machine": platform.machine(), "flags": _flags(),
        "torch": torch.__version__,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "mkldnn": torch.backends.mkldnn.is_available(),
        "env": {k: v for k, v in os.environ.items() if ENV.match(k)},
    }
    for kind in ("conv", "matmul"):
        backend = getattr(torch.backends.mkldnn, kind, None)
        out[f"mkldnn_{kind}_fp32_precision"] = getattr(backend, "fp32_precision", None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rows", default="192,288")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    res: dict[str, object] = {"facts": facts()}
    for name in NETWORKS:
        for rows in (int(r) for r in args.rows.split(",")):
            for flush in (False, True):
                key = f"{name}/{rows} rows/{'flush-to-zero' if flush else 'default'}"
                res[key] = time_pass(name, rows, args.repeats, flush)
                print(key, res[key], file=sys.stderr, flush=True)
        res[f"{name}/kernels"] = kernels(name, 192)
        for mode in PRECISIONS:
            key = f"{name}/192 rows/{mode}"
            try:  # a mode this torch or CPU refuses is a fact too, not the end of the part
                res[key] = time_precision(name, 192, args.repeats, mode)
            except (RuntimeError, ValueError, TypeError) as exc:
                res[key] = {"error": str(exc).splitlines()[0]}
            print(key, res[key], file=sys.stderr, flush=True)
    text = json.dumps(res, indent=1)
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
