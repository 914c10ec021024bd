"""Hostile input against the study server and the live hub (issue 35): time to answer and memory.

Study server: designs a painting study in a temporary folder, starts ``rapidds study serve`` in a
process of its own, opens P01's first round and posts hostile tracker files to it: JSON objects
each with different fields (the bypass of the wide-file fix: pandas built objects x all fields),
its variants (many objects, many distinct fields, 5000-digit numbers) and a 7.6 MiB file.
Reported per file: the status, the seconds to answer, the server's CPU seconds over it and its
resident memory (VmRSS) before and after. Live hub: a forged event pair 1e15 s and 1e5 s
apart fed to a cycle's observation in this process, with its peak allocation (tracemalloc).

    .venv/bin/python benchmarks/bench_hostile.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "from rapidds.cli import main; main()"]


def _files() -> dict[str, str]:
    row = '"zz",0,1.000,1.000,1.000\n'
    return {
        "2000 objects x 30 own fields (139 KB probe)": json.dumps(
            [{f"k{i}_{j}": 1 for j in range(30)} for i in range(2000)]),
        "60 000 distinct fields": json.dumps([{f"c{i}": 1} for i in range(60_000)]),
        "200 000 objects, one own field each": json.dumps([{f"c{i}": 1}
                                                           for i in range(200_000)]),
        "5000-digit numbers": json.dumps([{"task": "prep_vise", "point": 0, "t": 0,
                                           "x": 1, "y": 1, "z": 0}])[:-2] + ', "w": '
        + "1" * 5000 + "}]",
        "7.6 MiB CSV": "task,point,t,x,y,z\n" + row * int(7.6 * 2**20 / len(row)),
    }


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _post(url: str, body: dict) -> tuple[int, str]:
    req = urllib.request.Request(url, data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=600) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def study_server() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "study"
        subprocess.run([*CLI, "study", "design", "painting", "--participants", "16",
                        "--rounds", "2", "--out", str(folder)], check=True, env=env,
                       capture_output=True)
        proc = subprocess.Popen([*CLI, "study", "serve", str(folder), "--port", "0", "--json"],
                                stdout=subprocess.PIPE, text=True, env=env)
        try:
            assert proc.stdout is not None
            url = json.loads(proc.stdout.readline())["url"].rstrip("/")
            with urllib.request.urlopen(url + "/p/P01", timeout=900) as r:
                step = r.read().decode().split("data-step='", 1)[1].split("'", 1)[0]
            print("| tracker file | status | answer (s) | server CPU (s) | server RSS before -> "
                  "after (MiB) | load |\n|---|---|---|---|---|---|")
            for name, text in _files().items():
                before = _rss_mib(proc.pid)
                t, c = time.perf_counter(), _cpu_s(proc.pid)
                status, answer = _post(f"{url}/api/p/P01/round", {
                    "step": step, "fields": {"source": "tracker"}, "tracker": text})
                wall, cpu = time.perf_counter() - t, _cpu_s(proc.pid) - c
                print(f"| {name} | {status} | {wall:.3f} | {cpu:.3f} | {before:.0f} -> "
                      f"{_rss_mib(proc.pid):.0f} | {os.getloadavg()[0]:.2f} |", flush=True)
                assert len(answer) < 1000, answer[:200]
        finally:
            proc.terminate()
            proc.wait(60)


def live_hub() -> None:
    from rapidds.bridge import ros2
    from rapidds.bridge.link import Received
    from rapidds.bridge.live import CycleObservation, LivePlan, live_plan_payload
    from rapidds.worlds.base import body_point_names
    from rapidds.worlds.bounds import world_task_bound
    from rapidds.worlds.registry import make_world

    world = make_world("painting")
    print("\n| forged event pair | wall (s) | CPU (s) | peak allocation (KiB) |\n|---|---|---|---|")
    for apart in (1e15, 1e5):
        payload = live_plan_payload(world.problem(), 0, ["prep_vise"], [], {},
                                    start_ns=time.time_ns(), time_scale=4.0, dt=world.dt)
        plan = LivePlan.parse(ros2.string_message(payload).data)
        obs = CycleObservation(plan, body_point_names(world), window=120.0,
                               task_bound=world_task_bound(world))
        now = plan.wall_ns(1.0)
        t, c = time.perf_counter(), time.process_time()
        tracemalloc.start()
        for kind, stamp in (("start", now), ("end", now + int(apart * 1e9))):
            obs.handle(Received(ros2.EVENTS_TOPIC, ros2.event_message(ros2.Event(
                "prep_vise", "human", kind, stamp)), now))  # type: ignore[arg-type]
        obs.human_executions(world.dt)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"| {apart:g} s apart | {time.perf_counter() - t:.4f} | "
              f"{time.process_time() - c:.4f} | {peak / 1024:.0f} |")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "src"))
    study_server()
    live_hub()
