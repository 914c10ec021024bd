"""Scheduler scaling, 8-128 tasks: the GA of a baseline commit and of this tree, side by side.

    .venv/bin/python benchmarks/bench_scaling.py                 # full run (about 25 min)
    .venv/bin/python benchmarks/bench_scaling.py --quick         # 8-32 tasks, one instance
    .venv/bin/python benchmarks/bench_scaling.py --baseline REF  # compare with another commit
    .venv/bin/python benchmarks/bench_scaling.py --ladder 32     # each commit of the work
    .venv/bin/python benchmarks/bench_scaling.py --big --baseline REF  # 32-128 tasks, CPU s

Each GA run is a subprocess (``--worker``) with ``PYTHONPATH`` on the sources it measures: the
baseline's come from ``git archive REF src``, the current ones from this tree; the instances
come from this tree's ``bench_scheduler.random_instance`` for both. Runs alternate between the
two codes, instance by instance, so both see the same load. A worker reports every improvement
of the best objective as it happens (it wraps the GA's ``evaluate_population``), so "time to
within 1 %" is exact for both codes, and a baseline run stopped at its cap still reports its
best so far. Writes the "## Scheduler scaling" section of docs/benchmarks.md and
docs/figures/scheduler_scaling.png unless ``--no-write``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from _common import cpu_model, load_average, update_docs_section

ROOT = Path(__file__).resolve().parents[1]
PLOT = ROOT / "docs" / "figures" / "scheduler_scaling.png"
BASELINE = "6967d1e"  # the last commit before the scaling work (GA of docs/design-notes.md 8)


# ------------------------------------------------------------------------------- worker


def worker(n: int, r: int, std: float, overrides: dict[str, object]) -> None:
    """One GA run on instance (n, r) of the benchmark generator, with the ``rapidds`` found on
    the path. Prints ``P seconds objective rss_mb cpu_seconds`` per improvement, then
    ``R {json}``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_scheduler import human_samples, random_instance

    from rapidds.motion.interface import FixedDurationMotion
    from rapidds.scheduler import GAConfig, GeneticScheduler

    rng = np.random.default_rng(17 * n + r)
    problem = random_instance(rng, n, std_frac=std)
    config = GAConfig(**overrides)  # type: ignore[arg-type]
    samples, mean = human_samples(rng, problem, config.samples)
    best = [float("inf")]
    t0, c0 = time.perf_counter(), time.process_time()
    try:  # where the GA calls Algorithm 2: its evaluator since the split of ga.py
        import rapidds.scheduler.evaluator as ga_module
    except ImportError:  # an older checkout (--base)
        import rapidds.scheduler.ga as ga_module  # type: ignore[no-redef]
    evaluate = ga_module.evaluate_population

    def traced(*args: object, **kwargs: object) -> list:
        out = evaluate(*args, **kwargs)  # type: ignore[arg-type]
        low = min((e.objective for e in out), default=float("inf"))
        if low < best[0]:
            best[0] = low
            print(f"P {time.perf_counter() - t0:.4f} {low!r} {_rss_mb():.0f} "
                  f"{time.process_time() - c0:.4f}", flush=True)
        return out

    ga_module.evaluate_population = traced  # type: ignore[assignment]
    result = GeneticScheduler(problem, FixedDurationMotion(problem), config).solve(samples, mean)
    print("R " + json.dumps({
        "objective": result.best.objective, "makespan": result.best.makespan_mean,
        "seconds": result.seconds, "evaluations": result.evaluations,
        "generations": result.generations_run, "rss_mb": _rss_mb(),
        "cpu": time.process_time() - c0,
    }), flush=True)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# --------------------------------------------------------------------------------- runs


@dataclass
class Run:
    code: str  # "old", "new" or "new, no CP-SAT seed"
    n: int
    r: int
    std: float
    objective: float = float("inf")
    seconds: float = float("nan")
    capped: bool = False
    evaluations: int = 0
    rss_mb: float = float("nan")
    cpu: float = float("nan")
    trace: list[tuple[float, float]] = field(default_factory=list)
    cpu_trace: list[float] = field(default_factory=list)  # CPU seconds at each trace entry

    def time_to(self, target: float) -> float:
        """Seconds until the best objective was within ``target``; inf if never."""
        return next((t for t, v in self.trace if v <= target + 1e-9), float("inf"))

    def cpu_to(self, target: float) -> float:
        """CPU seconds until the best objective was within ``target``; inf if never."""
        return next((c for (_, v), c in zip(self.trace, self.cpu_trace, strict=True)
                     if v <= target + 1e-9), float("inf"))


def run(src: Path, code: str, n: int, r: int, std: float, cap: float,
        overrides: dict[str, object] | None = None) -> Run:
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(n), str(r), str(std),
           json.dumps(overrides or {})]
    out = Run(code, n, r, std)
    t0 = time.perf_counter()
    with subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True) as proc:
        try:
            stdout, _ = proc.communicate(timeout=cap)
        except subprocess.TimeoutExpired:
            proc.kill()
            stdout, _ = proc.communicate()
            out.capped, out.seconds = True, time.perf_counter() - t0
    for line in stdout.splitlines():
        if line.startswith("P "):
            _, t, v, rss, cpu = line.split()
            out.trace.append((float(t), float(v)))
            out.cpu_trace.append(float(cpu))
            out.objective, out.rss_mb = float(v), float(rss)
        elif line.startswith("R "):
            res = json.loads(line[2:])
            out.objective, out.seconds = res["objective"], res["seconds"]
            out.evaluations, out.rss_mb = res["evaluations"], res["rss_mb"]
            out.cpu = res["cpu"]
    if out.capped:
        out.seconds = cap
    print(f"  {code:>24} n={n} r={r} std={std}: {out.objective:.4f} in {out.seconds:.1f} s "
          f"({out.cpu:.1f} CPU s, load {load_average()})"
          f"{' (capped)' if out.capped else ''}, {out.rss_mb:.0f} MB", file=sys.stderr)
    return out


def baseline_sources(ref: str, into: Path) -> Path:
    """``src`` of commit ``ref``, unpacked under ``into``."""
    archive = into / "baseline.tar"
    with archive.open("wb") as fh:
        subprocess.run(["git", "-C", str(ROOT), "archive", ref, "src"], stdout=fh, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into / "src"


# ------------------------------------------------------------------------------- report


def _fmt_s(x: float, capped: bool = False) -> str:
    if not np.isfinite(x):
        return "never"
    return f"{x:.1f}" + (" (cap)" if capped else "")


def _pct(x: float) -> str:
    return f"{0.0 if abs(x) < 1e-11 else 100 * x:+.2f} %"


def report(stochastic: list[Run], exact: list[dict], args: argparse.Namespace,
           load: tuple[str, str]) -> str:
    out = [f"Machine: {os.cpu_count()} cores, {cpu_model()}, Python "
           f"{sys.version.split()[0]}. Measured {time.strftime('%Y-%m-%d')} with "
           f"`benchmarks/bench_scaling.py{' --quick' if args.quick else ''}`; baseline = "
           f"commit `{args.baseline}` (the GA before this work), new = this tree. 1-min load "
           f"average {load[0]} at start, {load[1]} at end: the machine was shared, so seconds "
           "are upper bounds; old and new ran alternately, one run at a time, so they saw the "
           "same load. Default `GAConfig`, K = 64 samples, fixed robot durations "
           "(`FixedDurationMotion`).", ""]
    out += ["### Stochastic instances (std 15 % of the mean)", "",
            "Target: within 1 % of the old code's final objective. \"to 1 %\" = seconds until "
            "the best objective was within 1 % of the OLD run's final objective on the same "
            "instance; \"final\" = new final objective vs old, in %. Old runs stopped at their "
            "cap report their best so far (marked).", "",
            "| tasks | instance | old total (s) | old to 1 % | new total (s) | new to 1 % "
            "| new final vs old | old / new peak RSS (MB) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    by = {(x.code, x.n, x.r): x for x in stochastic}
    for n in sorted({x.n for x in stochastic}):
        for r in sorted({x.r for x in stochastic if x.n == n}):
            old, new = by[("old", n, r)], by[("new", n, r)]
            target = 1.01 * old.objective
            out.append(
                f"| {n} | {r} | {_fmt_s(old.seconds, old.capped)} | "
                f"{_fmt_s(old.time_to(target))} | {_fmt_s(new.seconds)} | "
                f"{_fmt_s(new.time_to(target))} | "
                f"{_pct(new.objective / old.objective - 1)} | "
                f"{old.rss_mb:.0f} / {new.rss_mb:.0f} |")
    if exact:
        out += ["", "### Deterministic instances (std 0) against CP-SAT", "",
                "CP-SAT with the agent-load bound, 1 worker, 60 s; gap = (GA makespan - CP-SAT "
                "makespan) / CP-SAT makespan (negative when CP-SAT did not prove its optimum "
                "and the GA found better). \"new, no seed\" is the GA with "
                "`exact_seed_work=0`: the search on its own.", "",
                "| tasks | instance | CP-SAT makespan | proven | CP-SAT s | old gap | old s "
                "| new gap | new s | new, no seed: gap | s |",
                "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for e in exact:
            cells = []
            for code in ("old", "new", "new, no CP-SAT seed"):
                x = e[code]
                cells += [_pct(x.objective / e["cp_makespan"] - 1),
                          _fmt_s(x.seconds, x.capped)]
            out.append(f"| {e['n']} | {e['r']} | {e['cp_makespan']:.2f} | "
                       f"{'yes' if e['cp_optimal'] else 'no'} | {e['cp_seconds']:.1f} | "
                       + " | ".join(cells) + " |")
    out += ["", f"![GA scaling]({PLOT.relative_to(ROOT / 'docs').as_posix()})", ""]
    return "\n".join(out)


def plot(stochastic: list[Run], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    sizes = sorted({x.n for x in stochastic})
    for code, colour in (("old", "tab:red"), ("new", "tab:blue")):
        totals, firsts = [], []
        for n in sizes:
            pairs = [(x, next(o for o in stochastic if o.code == "old" and o.n == n
                              and o.r == x.r)) for x in stochastic if x.code == code and x.n == n]
            totals.append(statistics.mean(x.seconds for x, _ in pairs))
            firsts.append(statistics.mean(
                min(x.time_to(1.01 * o.objective), x.seconds) for x, o in pairs))
        left.plot(sizes, totals, "o-", color=colour, label=f"{code}: total")
        left.plot(sizes, firsts, "s--", color=colour, label=f"{code}: to within 1 % of old")
    left.set(xscale="log", yscale="log", xlabel="tasks", ylabel="seconds (mean)",
             title="GA time (old capped where marked in the table)")
    left.set_xticks(sizes, [str(n) for n in sizes])
    left.legend(fontsize=8)
    for n in sizes:
        for x in (x for x in stochastic if x.code == "new" and x.n == n):
            old = next(o for o in stochastic if o.code == "old" and o.n == n and o.r == x.r)
            right.plot(n, 100 * (x.objective / old.objective - 1), "o", color="tab:blue")
    right.axhline(0, color="grey", lw=0.8)
    right.set(xscale="log", xlabel="tasks", ylabel="new final vs old final (%)",
              title="Final objective, new against old")
    right.set_xticks(sizes, [str(n) for n in sizes])
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


# ------------------------------------------------------------------------------- ladder

# The commits of the scaling work that change speed, in order, and what each changed.
LADDER = (
    (BASELINE, "baseline: the GA of docs/design-notes.md item 8"),
    ("7d685fc", "timelines of a whole batch in one vectorised pass (ScheduleBatch)"),
    ("c603b84", "slim copies of cached evaluations (memory)"),
    ("e0f4a19", "polish window 10; order search places children when popped; faster C_j"),
    ("e0a8e4c", "C_j of a whole batch at once; cyclic GC off during a solve"),
    ("3268c14", "CP-SAT seed (1 unit, up to 40 tasks); 4 MiB batch chunks"),
    ("8a6fcd3", "cached evaluations without timelines; searched allocations as bit masks"),
)


def ladder(n: int, instances: int, cap: float, load: str) -> str:
    """Each commit of ``LADDER`` on the same instances, one after the other, in one run."""
    rows: list[tuple[str, str, list[Run]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        trees = []
        for k, (ref, what) in enumerate(LADDER):
            into = Path(tmp) / str(k)
            into.mkdir()
            trees.append((ref, what, baseline_sources(ref, into)))
        runs: dict[str, list[Run]] = {ref: [] for ref, _, _ in trees}
        for r in range(instances):  # instance by instance, so every commit sees the same load
            for ref, _, src in trees:
                runs[ref].append(run(src, ref, n, r, 0.15, cap))
        rows = [(ref, what, runs[ref]) for ref, what, _ in trees]
    base = rows[0][2]
    out = [f"{n} tasks, stochastic (std 15 %), instances 0-{instances - 1} of "
           f"`bench_scaling.py`, default `GAConfig` of each commit, one run at a time in one "
           f"invocation (`bench_scaling.py --ladder`); 1-min load average {load} at start, "
           f"{load_average()} at end. \"to 1 %\" = seconds until within 1 % of the "
           "baseline's final objective on the same instance.", "",
           "| commit | change | total s (mean) | to 1 % s (mean) | final vs baseline (mean) "
           "| evaluations (mean) | peak RSS MB (max) |", "|---|---|---:|---:|---:|---:|---:|"]
    for ref, what, rs in rows:
        pairs = list(zip(rs, base, strict=True))
        to = [x.time_to(1.01 * b.objective) for x, b in pairs]
        out.append(
            f"| `{ref}` | {what} | {statistics.mean(x.seconds for x in rs):.1f} | "
            f"{statistics.mean(to):.1f} | "
            f"{_pct(statistics.mean(x.objective / b.objective - 1 for x, b in pairs))} | "
            f"{statistics.mean(x.evaluations for x in rs):,.0f} | "
            f"{max(x.rss_mb for x in rs):.0f} |")
    return "\n".join(out)


# ---------------------------------------------------------------------------------- big

BIG_SECTION = "## GA on big jobs: the screened polish"


def cp_bound(n: int, r: int, seconds: float) -> float:
    """CP-SAT's lower bound on the makespan of instance (n, r) on the mean of the worker's
    samples: a lower bound on every schedule's expected makespan (Jensen: a makespan is
    convex in the durations), up to CP-SAT's rounding to 1/100 s."""
    from bench_scheduler import human_samples, random_instance

    from rapidds.scheduler import solve_exact

    rng = np.random.default_rng(17 * n + r)
    problem = random_instance(rng, n, std_frac=0.15)
    samples, _ = human_samples(rng, problem, 64)
    mean = samples.mean(axis=0)
    return solve_exact(problem, time_limit_s=seconds, human_mean=mean, load_bound=True).bound


def big(baseline: str, cp_seconds: float, sizes: dict[int, int]) -> str:
    """The default GA of ``baseline`` and of this tree on the 32-128-task stochastic instances,
    alternating run by run: whole-run wall and CPU seconds, wall and CPU seconds to within
    1 % of the best known (the better final of the two), and the gap to CP-SAT's bound."""
    load0 = load_average()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        old_src = baseline_sources(baseline, Path(tmp))
        new_src = Path(tmp) / "new" / "src"
        shutil.copytree(ROOT / "src", new_src, ignore=shutil.ignore_patterns("__pycache__"))
        for n, count in sizes.items():
            for r in range(count):
                old = run(old_src, "base", n, r, 0.15, 600)
                new = run(new_src, "this tree", n, r, 0.15, 600)
                rows.append((n, r, old, new, cp_bound(n, r, cp_seconds)))
    out = [f"Default `GAConfig`, K = 64, stochastic instances (std 15 %) of `bench_scaling.py`, "
           f"base = `{baseline}` and this tree alternating run by run in fresh processes "
           f"(`bench_scaling.py --big`), {os.cpu_count()} cores ({cpu_model()}) shared with "
           f"other sessions; 1-min load average {load0} at start, {load_average()} at end. "
           "Best known = the better final objective of the two runs; \"to 1 %\" = until "
           "within 1 % of it; CP-SAT bound = CP-SAT's lower bound on the makespan on the "
           f"samples' mean durations ({cp_seconds:.0f} s, 1 worker), a lower bound on every "
           "schedule's expected makespan.", "",
           "| tasks | inst. | code | wall s | CPU s | to 1 %: wall s | CPU s | final vs best "
           "| gap to CP-SAT bound | evaluations |",
           "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for n, r, old, new, bound in rows:
        best = min(old.objective, new.objective)
        for x in (old, new):
            out.append(f"| {n} | {r} | {x.code} | {_fmt_s(x.seconds, x.capped)} | "
                       f"{x.cpu:.1f} | {_fmt_s(x.time_to(1.01 * best))} | "
                       f"{_fmt_s(x.cpu_to(1.01 * best))} | {_pct(x.objective / best - 1)} | "
                       f"{_pct(x.objective / bound - 1)} | {x.evaluations:,} |")
    return "\n".join(out)


# --------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--worker":
        worker(int(argv[1]), int(argv[2]), float(argv[3]), json.loads(argv[4]))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8-32 tasks, one instance each")
    parser.add_argument("--baseline", default=BASELINE, help="git commit of the old GA")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--ladder", type=int, metavar="N", default=0,
                        help="instead: each commit of the work, one by one, on N-task jobs")
    parser.add_argument("--instances", type=int, default=2, help="instances for --ladder")
    parser.add_argument("--big", action="store_true",
                        help="instead: 32-128 tasks against --baseline, CPU seconds beside")
    parser.add_argument("--cp-seconds", type=float, default=30.0, help="CP-SAT's limit, --big")
    parser.add_argument("--big-sizes", default="32:3,64:4,128:2",
                        help="tasks:instances for --big, comma separated")
    args = parser.parse_args(argv)
    if args.big:
        sys.path.insert(0, str(ROOT / "src"))
        sizes = dict(tuple(map(int, x.split(":"))) for x in args.big_sizes.split(","))
        text = big(args.baseline, args.cp_seconds, sizes)
        print(text)
        if not args.no_write:
            update_docs_section(BIG_SECTION, text)
        return 0
    if args.ladder:
        text = ladder(args.ladder, args.instances, 600, load_average())
        print(text)
        if not args.no_write:
            update_docs_section(f"## Scheduler, change by change ({args.ladder} tasks)", text)
        return 0
    load = (load_average(), "")
    sizes = {8: 3, 16: 3, 32: 3, 64: 2, 128: 1}
    caps = {8: 120, 16: 120, 32: 240, 64: 240, 128: 240}  # old code; the new runs get 600 s
    exact_sizes = {8: 2, 16: 2, 32: 2}
    if args.quick:
        sizes, exact_sizes = {8: 1, 16: 1, 32: 1}, {16: 1}
    sys.path.insert(0, str(ROOT / "src"))
    from rapidds.scheduler import solve_exact

    stochastic: list[Run] = []
    exact: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        old_src = baseline_sources(args.baseline, Path(tmp))
        new_src = Path(tmp) / "new" / "src"  # a snapshot: edits during the run do not leak in
        shutil.copytree(ROOT / "src", new_src, ignore=shutil.ignore_patterns("__pycache__"))
        for n, count in sizes.items():
            print(f"{n} tasks, stochastic ...", file=sys.stderr)
            for r in range(count):
                stochastic.append(run(old_src, "old", n, r, 0.15, caps[n]))
                stochastic.append(run(new_src, "new", n, r, 0.15, 600))
        for n, count in exact_sizes.items():
            print(f"{n} tasks, deterministic ...", file=sys.stderr)
            from bench_scheduler import random_instance

            for r in range(count):
                problem = random_instance(np.random.default_rng(17 * n + r), n)
                t0 = time.perf_counter()
                cp = solve_exact(problem, time_limit_s=60.0, load_bound=True)
                row: dict = {"n": n, "r": r, "cp_makespan": cp.makespan,
                             "cp_optimal": cp.optimal, "cp_seconds": time.perf_counter() - t0}
                row["old"] = run(old_src, "old", n, r, 0.0, caps[n])
                row["new"] = run(new_src, "new", n, r, 0.0, 600)
                row["new, no CP-SAT seed"] = run(new_src, "new, no CP-SAT seed", n, r, 0.0,
                                                 600, {"exact_seed_work": 0})
                exact.append(row)
    load = (load[0], load_average())
    text = report(stochastic, exact, args, load)
    print(text)
    if not args.no_write:
        plot(stochastic, PLOT)
        update_docs_section("## Scheduler scaling", text)
        print(f"wrote {PLOT} and the Scheduler scaling section of docs/benchmarks.md",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
