"""Plan quality of this tree against an older one on the same device, where their arithmetic
differs there (issue 36: "paired plan costs over at least 8 seeds equal within their
intervals"). On a GPU the spatial belief's update runs on the card since `9b91310`, with the
card's rounding, so a cuda run's records differ from an older tree's that updated on the host.

    python benchmarks/gpu_quality.py run --device cuda --seeds 0-7 --json NEW.json
    PYTHONPATH=OLD/src:$PYTHONPATH python benchmarks/gpu_quality.py run ... --json OLD.json
    python benchmarks/gpu_quality.py report OLD.json NEW.json

``run``: the benchmark's painting run (left-slow, gamma 12, full adaptation, default search,
one torch thread; ``bench_painting_cycle.run_seed``) for each seed, all in this process (plan
quality, not timing), ``--cycles`` cycles: each cycle's realised cost and the records' digest,
the file rewritten after each seed. ``report``: the mean realised cost of the settled cycles
(4 on, as ``bench_painting_sampler.py``), NEW - OLD paired by seed with a 95 % bootstrap
interval, and how many seeds gave identical records.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import cpu_model, load_average, parse_seeds  # noqa: E402
from bench_painting_sampler import SETTLED  # noqa: E402
from bench_quality import paired_bootstrap  # noqa: E402


def run(args: argparse.Namespace) -> None:
    from bench_painting_cycle import run_seed

    import rapidds

    out: dict[str, object] = {"device": args.device, "cycles": args.cycles,
                              "rapidds": str(Path(rapidds.__file__).parent),
                              "machine": cpu_model(), "load": load_average(), "seeds": {}}
    for seed in parse_seeds(args.seeds):
        r = run_seed(seed, args.cycles, device=args.device)
        out["seeds"][str(seed)] = {"realised": r["realised"], "digest": r["digest"]}  # type: ignore[index]
        args.json.write_text(json.dumps(out, indent=1))
        print(seed, r["digest"], [round(c, 3) for c in r["realised"]], flush=True)


def report(args: argparse.Namespace) -> None:
    old, new = (json.loads(Path(f).read_text()) for f in (args.old, args.new))
    seeds = sorted(set(old["seeds"]) & set(new["seeds"]), key=int)
    if not seeds:
        raise SystemExit("the two files share no seed")

    def settled(res: dict, s: str) -> float:
        return statistics.mean(res["seeds"][s]["realised"][SETTLED:])

    diff = np.array([settled(new, s) - settled(old, s) for s in seeds])
    lo, hi = paired_bootstrap(diff)
    same = sum(old["seeds"][s]["digest"] == new["seeds"][s]["digest"] for s in seeds)
    print(f"{new['device']}, {len(seeds)} seeds ({seeds[0]}-{seeds[-1]}), {new['cycles']} "
          f"cycles; realised cost of cycles {SETTLED}.. (mean over seeds): old "
          f"{statistics.mean(settled(old, s) for s in seeds):.3f}, new "
          f"{statistics.mean(settled(new, s) for s in seeds):.3f}; new - old {diff.mean():+.3f} "
          f"[95 % bootstrap {lo:+.3f}, {hi:+.3f}]; identical records in {same} of {len(seeds)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--device", default="cuda")
    r.add_argument("--seeds", default="0-7")
    r.add_argument("--cycles", type=int, default=7)
    r.add_argument("--json", type=Path, required=True)
    p = sub.add_parser("report")
    p.add_argument("old")
    p.add_argument("new")
    args = ap.parse_args()
    run(args) if args.cmd == "run" else report(args)


if __name__ == "__main__":
    main()
