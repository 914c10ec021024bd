"""Where the suite's time goes, in CPU seconds as well as wall: a pytest plugin writing one JSON
line per test (setup, call and teardown together) with its wall seconds, this process's CPU
seconds, its finished child processes' CPU seconds and the 1-minute load average. On a machine
shared with other work the wall seconds say little; the CPU seconds say what a test costs.

    PYTHONPATH=src:benchmarks pytest -p suite_cpu tests/...   # SUITE_CPU_OUT=suite-cpu.jsonl
    python benchmarks/suite_cpu.py suite-cpu.jsonl [BEFORE.jsonl]  # per file, slowest first

Children count once they are reaped (a hub or CLI run the test waited for; not the workers of
a process group killed with SIGKILL, whose parent never waited for them)."""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from collections import defaultdict
from collections.abc import Generator
from pathlib import Path
from typing import Any

import pytest

OUT = "SUITE_CPU_OUT"


def _children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: Any) -> Generator[None, None, None]:
    w0, c0, k0 = time.perf_counter(), time.process_time(), _children()
    yield
    rec = {"id": item.nodeid, "wall": time.perf_counter() - w0,
           "cpu": time.process_time() - c0, "child": _children() - k0,
           "load": os.getloadavg()[0]}
    with open(os.environ.get(OUT, "suite-cpu.jsonl"), "a") as f:
        f.write(json.dumps(rec) + "\n")


def per_file(path: Path) -> dict[str, list[float]]:
    """test file -> [tests, wall s, own CPU s, children's CPU s]."""
    out: dict[str, list[float]] = defaultdict(lambda: [0, 0.0, 0.0, 0.0])
    for line in path.read_text().splitlines():
        r = json.loads(line)
        row = out[r["id"].split("::")[0]]
        row[0] += 1
        row[1] += r["wall"]
        row[2] += r["cpu"]
        row[3] += r["child"]
    return dict(out)


def main(argv: list[str]) -> int:
    if not 1 <= len(argv) <= 2:
        print("usage: suite_cpu.py AFTER.jsonl [BEFORE.jsonl]", file=sys.stderr)
        return 2
    after = per_file(Path(argv[0]))
    before = per_file(Path(argv[1])) if len(argv) == 2 else {}
    print(f"{'file':45} {'tests':>5} {'wall':>7} {'cpu':>6} {'child':>6} {'total':>6}"
          + (f" {'before':>6}" if before else ""))
    for name, (n, wall, cpu, child) in sorted(after.items(), key=lambda kv: -kv[1][2] - kv[1][3]):
        old = before.get(name)
        print(f"{name:45} {n:5d} {wall:7.1f} {cpu:6.1f} {child:6.1f} {cpu + child:6.1f}"
              + (f" {old[2] + old[3]:6.1f}" if old else (" " * 7 if before else "")))
    total = [sum(v[i] for v in after.values()) for i in range(4)]
    print(f"{'all':45} {int(total[0]):5d} {total[1]:7.1f} {total[2]:6.1f} {total[3]:6.1f} "
          f"{total[2] + total[3]:6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
