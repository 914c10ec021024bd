"""CLI start-up: CPU time of ``rapidds --help`` and of ``rapidds plan examples/fetch.yaml``.

Each command runs ``--repeat`` times in a fresh process; the CPU time (user + system) of the
child is read with getrusage, so other load on the machine changes it little. Also lists which
heavy libraries each command imports.

    .venv/bin/python benchmarks/bench_cli.py [--repeat 10] [--update-docs]
    .venv/bin/python benchmarks/bench_cli.py --base /tmp/old-checkout [--repeat 10]

``--base DIR`` measures the checkout at DIR (its ``src``) beside this one, runs interleaved
(old, new, old, new, ...), so both see the same load; the table then has both.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## CLI start-up"
COMMANDS = {
    "rapidds --help": ["--help"],
    "rapidds run --help": ["run", "--help"],
    "rapidds plan examples/fetch.yaml": ["plan", str(ROOT / "examples" / "fetch.yaml"),
                                         "--seed", "0"],
}
HEAVY = ("torch", "diffusers", "distributed", "matplotlib", "ortools", "pandas", "mujoco")
PROBE = ("import sys\nfrom rapidds.cli import main\ntry:\n    main()\n"
         "except SystemExit:\n    pass\n"
         f"print(','.join(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)")


def _env(src: Path | None) -> dict[str, str] | None:
    """The environment that imports rapidds from ``src`` (None: as this process does)."""
    return None if src is None else {**os.environ, "PYTHONPATH": str(src)}


def cpu_seconds(argv: list[str], src: Path | None = None) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from rapidds.cli import main; main()", *argv],
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True,
                   env=_env(src))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--update-docs", action="store_true")
    ap.add_argument("--base", type=Path, help="an older checkout to measure beside this one")
    args = ap.parse_args()
    load0 = load_average()
    trees: list[tuple[str, Path | None]] = [("", ROOT / "src")]
    if args.base is not None:
        trees = [(" (base)", args.base.resolve() / "src"), (" (this tree)", ROOT / "src")]
    rows = []
    for label, argv in COMMANDS.items():
        runs: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in trees}
        for _, src in trees:
            cpu_seconds(argv, src)  # warm the file cache
        for _ in range(args.repeat):
            for name, src in trees:
                runs[name].append(cpu_seconds(argv, src))
        for name, src in trees:
            probe = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True,
                                   text=True, env=_env(src)).stderr.strip().splitlines()
            heavy = probe[-1] if probe else ""
            got = runs[name]
            rows.append((f"`{label}`{name}", statistics.median(c for c, _ in got),
                         max(c for c, _ in got), statistics.median(w for _, w in got),
                         heavy or "none"))
            print(f"{rows[-1][0]}: CPU median {rows[-1][1]:.3f} s, max {rows[-1][2]:.3f} s, "
                  f"wall {rows[-1][3]:.3f} s, heavy imports: {rows[-1][4]}", flush=True)
    body = (
        f"`benchmarks/bench_cli.py --repeat {args.repeat}"
        + (f" --base {args.base}`" if args.base else "`")
        + ": each command in a fresh process, CPU "
        f"time (user + system) of the child. Machine: {cpu_model()}, 2 cores; 1-min load average "
        f"{load0} at start, {load_average()} at end. Goals: `rapidds --help` under "
        "0.5 s of CPU, `rapidds plan examples/fetch.yaml` under 0.6 s"
        + (", base and this tree interleaved run by run" if args.base else "") + ".\n\n"
        "| command | CPU s (median) | CPU s (max) | wall s (median) | heavy libraries imported |\n"
        "|---|---:|---:|---:|---|\n"
        + "".join(f"| {r[0]} | {r[1]:.2f} | {r[2]:.2f} | {r[3]:.2f} | {r[4]} |\n" for r in rows)
    )
    if args.update_docs:
        update_docs_section(SECTION, body)
    print(body)


if __name__ == "__main__":
    main()
