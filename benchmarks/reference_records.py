"""Reference records: what a refactor must leave unchanged, timings aside (issue 32).

``write OUT`` runs a planned and a reactive fetch run, a painting run and the committed ablation
store's report with the tree on ``PYTHONPATH``, and writes each run's stored records (timings
removed), a hash of each stored array and the report's table and summary to ``OUT/*.json``.
``compare A B`` says which differ, and where, exit 1 if any does.

    PYTHONPATH=src python benchmarks/reference_records.py write /tmp/ref-before
    (change the code)
    PYTHONPATH=src python benchmarks/reference_records.py write /tmp/ref-after
    python benchmarks/reference_records.py compare /tmp/ref-before /tmp/ref-after
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--population", "8", "--generations", "4", "--particles", "2", "--candidates", "4"]
CASES: dict[str, list[str]] = {
    "fetch-planned": ["run", "fetch", "--cycles", "3", "--seed", "11", *SMALL],
    "fetch-reactive": ["run", "fetch", "--cycles", "3", "--seed", "12", "--execution",
                       "reactive", "--reacts", "--human", "slow-middle", *SMALL],
    "painting": ["run", "painting", "--cycles", "2", "--seed", "13", *SMALL],
}
# Keys whose values are clock readings, not results.
TIMING = {"seconds", "latency", "latency_s", "wall", "wall_s", "elapsed", "created",
          "steer_s", "plan_s", "search_s"}


def _strip(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in TIMING}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _rapidds(args: list[str]) -> None:
    main = "import sys; from rapidds.cli import main; sys.exit(main())"
    exe = [sys.executable, "-c", main, *args]
    subprocess.run(exe, check=True, stdout=subprocess.DEVNULL, env={**os.environ})


def _dump_store(path: Path) -> dict[str, Any]:
    from rapidds.store import RunStore

    out: dict[str, Any] = {}
    with RunStore.open_readonly(path) as store:
        for rid in store.run_ids():
            recs = store.records(rid)
            arrays = {}
            for rec in recs:
                c = int(rec["cycle"])
                arrays[str(c)] = {k: hashlib.sha256(v.tobytes()).hexdigest()[:16]
                                  for k, v in sorted(store.arrays(rid, c).items())}
            out[rid] = {"config": _strip(store.run_config(rid)), "records": _strip(recs),
                        "arrays": arrays}
    return out


def write(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in CASES.items():
            d = Path(tmp) / name
            _rapidds([*args, "--out", str(d)])
            (out / f"{name}.json").write_text(json.dumps(_dump_store(d / "run.sqlite"),
                                                         indent=1, sort_keys=True))
            print(f"{name}: written")
        study = Path(tmp) / "ablation"
        study.mkdir()
        shutil.copy(ROOT / "tests" / "data" / "ablation-130e392.sqlite", study / "study.sqlite")
        _rapidds(["report", str(study)])
        report = {p.name: p.read_text().replace(str(study), "STUDY")
                  for p in sorted(study.iterdir()) if p.suffix in {".md", ".json"}}
        (out / "ablation-report.json").write_text(json.dumps(report, indent=1, sort_keys=True))
        print("ablation-report: written")


def _diff(a: Any, b: Any, where: str = "") -> str | None:
    if type(a) is not type(b):
        return f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, dict):
        if a.keys() != b.keys():
            return f"{where}: keys {sorted(set(a) ^ set(b))}"
        return next((d for k in a if (d := _diff(a[k], b[k], f"{where}.{k}"))), None)
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: length {len(a)} != {len(b)}"
        return next((d for i, (x, y) in enumerate(zip(a, b, strict=True))
                     if (d := _diff(x, y, f"{where}[{i}]"))), None)
    return None if a == b else f"{where}: {str(a)[:80]} != {str(b)[:80]}"


def compare(a: Path, b: Path) -> int:
    bad = 0
    for fa in sorted(a.glob("*.json")):
        fb = b / fa.name
        d = "missing" if not fb.exists() else _diff(json.loads(fa.read_text()),
                                                     json.loads(fb.read_text()))
        print(f"{fa.stem}: {'identical' if d is None else 'DIFFERS at ' + d}")
        bad += d is not None
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("write").add_argument("out", type=Path)
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    ns = ap.parse_args()
    if ns.cmd == "write":
        write(ns.out)
        return 0
    return compare(ns.a, ns.b)


if __name__ == "__main__":
    sys.exit(main())
