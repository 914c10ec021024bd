"""Plan first, record after: ``rapidds plan-next`` writes the next cycle's plan and robot
trajectories; a lab executes it (written here from the bag's contract, read back by
mcap-ros2-support: the plan's ``after`` lists order the tasks), records events and tracking,
and ``rapidds observe`` learns that cycle: the same plan, the person's recorded durations."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cli_helpers import run_main
from test_bridge_bags import read_ros2

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage, write_bag
from rapidds.bridge.export import human_task_messages
from rapidds.bridge.profiles import robot_profile
from rapidds.worlds.registry import make_world

CONFIG = {"world": "painting", "cycles": 2, "population": 4, "generations": 2, "samples": 8,
          "particles": 2, "candidates": 2, "human": "left-fast"}
_NS = 1_000_000_000
EPOCH = 1_795_000_000


def _seconds(d: Any) -> float:
    return d.sec + d.nanosec * 1e-9


def _lab_cycle(plan_bag: Path, out: Path, seed: int) -> dict[str, float]:
    """Execute a plan as a lab would: read the plan and trajectories, start each task when its
    ``after`` tasks have ended, the robot's taking its trajectory's time, the person's what a
    simulated person draws; record task events and the person's body points on /tf."""
    msgs = read_ros2(plan_bag)
    (plan,) = [json.loads(m.data) for ch, m in msgs if ch.topic == ros2.PLAN_TOPIC]
    profile = robot_profile("franka-fr3")
    robot = [m for ch, m in msgs if ch.topic == profile.trajectory_topic]
    assert [list(m.joint_names) for m in robot] == [[f"fr3_joint{k}" for k in range(1, 8)]] * len(
        plan["order"]["robot"])
    took = {t: _seconds(m.points[-1].time_from_start)
            for t, m in zip(plan["order"]["robot"], robot, strict=True)}
    world = make_world("painting")
    person = world.teammate("left-fast")
    done = person.execute(plan["cycle"], plan["order"]["human"], np.random.default_rng(seed))
    took.update({t: done[t].duration for t in plan["order"]["human"]})
    start: dict[str, float] = {}
    end: dict[str, float] = {}
    while len(end) < len(plan["agents"]):
        for task in plan["agents"]:
            if task not in end and all(a in end for a in plan["after"][task]):
                start[task] = max((end[a] for a in plan["after"][task]), default=0.0)
                end[task] = start[task] + took[task]
    base = plan["stamp_ns"]
    out_msgs: list[BagMessage] = []
    for task, agent in plan["agents"].items():
        at = base + round(start[task] * _NS)
        if agent == "human":
            out_msgs += human_task_messages(world, task, done[task].trajectory,
                                            done[task].duration, at)
        else:
            for kind, t in (("start", at), ("end", base + round(end[task] * _NS))):
                out_msgs.append(BagMessage(ros2.EVENTS_TOPIC, "std_msgs/msg/String", t,
                                           ros2.event_message(ros2.Event(task, "robot", kind))))
    write_bag(out, sorted(out_msgs, key=lambda m: m.time_ns))
    return {t: done[t].duration for t in plan["order"]["human"]}


def test_plan_next_then_observe_learns_the_planned_cycle(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "run.yaml"
    cfg.write_text(yaml.safe_dump(CONFIG))
    cell = tmp_path / "cell"
    for cycle in (0, 1):
        plan_bag = tmp_path / f"plan{cycle}.mcap"
        args = ["--config", str(cfg)] if cycle == 0 else []
        code, stdout, err = run_main(capsys, "plan-next", str(cell), "--out", str(plan_bag),
                                     "--robot", "franka-fr3", "--epoch", str(EPOCH + cycle),
                                     "--json", *args)
        assert code == 0, err
        planned = json.loads(stdout)
        assert planned["cycle"] == cycle
        assert not (cell / "run.sqlite").exists() or cycle == 1  # plan-next stores nothing
        observed = _lab_cycle(plan_bag, tmp_path / f"lab{cycle}.mcap", seed=cycle)
        code, stdout, err = run_main(capsys, "observe", str(cell), "--bag",
                                     str(tmp_path / f"lab{cycle}.mcap"), "--json", *args)
        assert code == 0, err
        rec = json.loads(stdout)
        assert rec["cycle"] == cycle
        # the plan observe made is the one plan-next wrote, and it learned what was recorded
        order = planned["plan"]["order"]
        assert [x for x in rec["human"] if not x.startswith("wait")] == order["human"]
        assert [x for x in rec["robot"] if not x.startswith("wait")] == order["robot"]
        assert rec["observed"] == pytest.approx(observed, abs=1e-6)
        # the robot's planned durations are its parameterized trajectories' (honest plans)
        times = planned["plan"]["times"]
        for task in order["robot"]:
            planned_d = times[task]["end"] - times[task]["start"]
            realised = rec["realised"]["timeline"][task]
            assert realised[1] - realised[0] == pytest.approx(planned_d, abs=1e-6)


def test_plan_next_refusals(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "run.yaml"
    cfg.write_text(yaml.safe_dump(CONFIG))
    for args, says in (([], "holds no run"),
                       (["--config", str(cfg), "--robot", "kuka"], "unknown robot profile"),
                       (["--config", str(cfg), "--epoch", "soon"], "--epoch 'soon'")):
        code, _, err = run_main(capsys, "plan-next", str(tmp_path / "cell"), "--out",
                                str(tmp_path / "p.mcap"), *args)
        assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "p.mcap").exists() and not (tmp_path / "cell").exists()
