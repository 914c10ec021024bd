"""The live cell re-plans when the person takes a robot task (issue 34 item 4): the hub's
observation gives the person a robot task the hub has not sent once they start it, the
re-planner drops it from the robot's rest, and the cycle is realised with the person doing it;
unit-level on the re-planner and the observation, and end to end on three processes (the hub,
the MuJoCo robot and a person on this process's link), one reactive painting cycle.

A pause is the overrun of tests/test_bridge_replan.py (the person's first task there runs three
times its drawn duration): the person here pauses the same way, then takes the brush."""

from __future__ import annotations

import time
from pathlib import Path

from test_bridge_replan import _replanner, _Slow, slow_person_cycle

from rapidds.bridge import ros2
from rapidds.bridge.link import Received
from rapidds.bridge.live import CycleObservation, LivePlan
from rapidds.bridge.nodes.sim_human import _Doing
from rapidds.bridge.ros2 import EVENTS_TOPIC, Event, event_message
from rapidds.worlds.base import body_points

TAKE = "brush"  # painting's one task either agent may do


def test_a_robot_task_the_person_starts_is_taken_and_replanned_without_it():
    rp = _replanner(["mix_l", "mix_r", "brush"])
    start = {"prep_vise": 0.0, "secure_piece": 4.0, "mix_l": 0.0, "mix_r": 7.0, "brush": 13.0}
    end = {"prep_vise": 4.0, "secure_piece": 10.0, "mix_l": 7.0, "mix_r": 13.0}
    assert rp.deviations(13.0, start, end, ["prep_vise", "secure_piece", "brush"]) == \
        [("took", "brush")]
    entry = rp.replan(13.0, "took", "brush", start, end, ["mix_l", "mix_r"])
    assert rp.order["robot"] == ["mix_l", "mix_r"] and rp.taken == {"brush"}
    assert entry["after"]["robot"] == [] and entry["reason"] == "took"


def _event(task: str, agent: str, kind: str, ns: int) -> Received:
    return Received(EVENTS_TOPIC, event_message(Event(task, agent, kind, ns)), ns)


def test_the_observation_gives_a_robot_task_to_the_person_only_where_the_hub_allows_it():
    plan = LivePlan(0, {"human": ["a"], "robot": ["b", "c"]}, {"a": [], "b": [], "c": []},
                    time.time_ns(), 1.0, 0.1)
    obs = CycleObservation(plan, ("p",), may_take=lambda t: t == "b")
    now = plan.stamp_ns + 10**8
    obs.event(_event("c", "human", "start", now))  # not allowed (say: sent): dropped
    obs.event(_event("b", "human", "start", now))
    obs.event(_event("b", "robot", "end", now + 10**8))  # the robot's end of it: not its task
    obs.event(_event("b", "human", "end", now + 2 * 10**8))
    assert "c" not in obs.start and obs.taken == {"b"}
    assert obs.doer("b") == "human" and obs.doer("c") == "robot"
    assert set(obs.durations("human")) == {"b"}
    assert abs(obs.durations("human")["b"] - 0.2) < 1e-6
    assert obs.durations("robot") == {}
    assert obs.faults.counts().get("event not in the plan", 0) == 2


class _Taker(_Slow):
    """The overrunning person of tests/test_bridge_replan.py (their first task runs SLOW times
    its drawn duration: a pause), who, as their last task of the plan ends, takes the robot's
    brush if everything before it has ended. The start of the brush is published just before
    the end of the last task, both stamped at that end: the events key keeps its order, so the
    hub sees the take before the end that would let it send the brush to the robot (otherwise
    the test would race the hub)."""

    def tick(self) -> float:
        plan, job = self.plan, self._doing
        last = (plan is not None and job is not None
                and self._next == len(plan.order["human"]) - 1
                and TAKE in plan.order["robot"]
                and (time.time_ns() - job.start_ns) * self.scale / 1e9 >= job.duration
                and all(x in self._ended or x == job.task for x in plan.after[TAKE]))
        if not last:
            return super().tick()
        assert plan is not None and job is not None and self._rng is not None
        end = job.start_ns + round(job.duration / self.scale * 1e9)
        self.link.publish(EVENTS_TOPIC, event_message(Event(TAKE, "human", "start", end)))
        wait = super().tick()  # the end of the last task
        d, path = self.teammate.at(plan.cycle).perform(TAKE, self._rng)
        self._doing = _Doing(TAKE, end, float(d), body_points(path))
        return wait


def test_the_live_cell_replans_when_the_person_takes_a_robot_task(tmp_path: Path) -> None:
    # seed 2 plans the brush for the robot (seed 0, the default: the person)
    cell = slow_person_cycle(tmp_path, _Taker, ("--seed", "2"))
    assert cell.code == 0, cell.err[-3000:]
    (rec,), seen = cell.records, cell.seen
    plan = LivePlan.parse(next(r for r in seen if r.topic == ros2.PLAN_TOPIC).msg.data)
    assert TAKE in plan.order["robot"], plan.order  # the plan gave the brush to the robot
    took = [r for r in rec["replans"] if r["reason"] == "took"]
    assert [r["task"] for r in took] == [TAKE], rec["replans"]
    assert TAKE not in took[0]["after"]["robot"]
    events = [ros2.parse_event(x.msg.data) for x in seen if x.topic == ros2.EVENTS_TOPIC]
    assert [(ev.agent, ev.event) for ev in events if ev.task == TAKE] == \
        [("human", "start"), ("human", "end")]  # the robot was never sent it
    assert rec["executed"]["human"][-1] == TAKE and TAKE not in rec["executed"]["robot"]
    assert "re-planned at" in cell.err and "took" in cell.err
