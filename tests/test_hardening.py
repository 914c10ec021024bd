"""The live cell under attack and fault (issue 35), each probe re-run: forged event stamps (H1),
implausible tracking on every source (M2), a forged stop and a node that leaves (M3), sizes and
the fault log's rate limit, a busy port, and the CLI's last unguarded inputs. Allocations are
measured with tracemalloc (numpy's buffers included) against a stated bound."""

from __future__ import annotations

import logging
import socket
import threading
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import run_main

from rapidds.bridge import ros2
from rapidds.bridge.faults import MAX_SMALL_BYTES, FaultLog
from rapidds.bridge.link import Link, Received
from rapidds.bridge.live import CycleObservation, LivePlan, live_plan_payload, tracking_topic
from rapidds.worlds.base import body_point_names
from rapidds.worlds.bounds import MAX_BODY_SPEED, Plausibility, plausible_mask, world_task_bound
from rapidds.worlds.registry import make_world

POINTS = body_point_names(make_world("painting"))  # the left wrist first
MiB = 2**20


@pytest.fixture(scope="module")
def painting():  # type: ignore[no-untyped-def]
    return make_world("painting")


def _plan(painting, start_ns: int | None = None) -> LivePlan:  # type: ignore[no-untyped-def]
    payload = live_plan_payload(painting.problem(), 0, ["prep_vise", "secure_piece", "brush"],
                                ["mix_l", "mix_r"], {}, start_ns=start_ns or time.time_ns(),
                                time_scale=4.0, dt=0.15)
    return LivePlan.parse(ros2.string_message(payload).data)


def _event(plan: LivePlan, task: str, kind: str, stamp_ns: int, arrives_ns: int) -> Received:
    return Received(ros2.EVENTS_TOPIC, ros2.event_message(ros2.Event(
        task, "human", kind, stamp_ns)), arrives_ns)  # type: ignore[arg-type]


def _point(plan: LivePlan, name: str, pos: Any, at: float) -> Received:
    return Received(tracking_topic(name), ros2.point_stamped(pos, plan.wall_ns(at)),
                    plan.wall_ns(at))


def _peak(fn: Callable[[], Any]) -> tuple[Any, int]:
    """fn()'s result and the peak bytes it allocated (tracemalloc)."""
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "rapidds.bridge"]


# -- H1: a forged event pair ----------------------------------------------------------------------
@pytest.mark.parametrize("apart_s", [1e15, 1e5])
def test_a_forged_event_pair_far_apart_is_dropped_in_one_line_without_allocating(
        painting, caplog, apart_s: float) -> None:
    """Probe H1: a start now and an end 1e15 s (47 PiB of path) or 1e5 s (807 MiB) later.
    The end is dropped in one line (1e15 s: its stamp is past ROS 2's int64 ns; 1e5 s: far
    ahead of its arrival); nothing is allocated past 1 MiB; the task stays open (the real end
    still counts)."""
    plan = _plan(painting)
    obs = CycleObservation(plan, POINTS, window=120.0, task_bound=world_task_bound(painting))
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    now = plan.wall_ns(1.0)
    forged = [_event(plan, "prep_vise", "start", now, now),
              _event(plan, "prep_vise", "end", now + int(apart_s * 1e9), now + 1000)]

    def run() -> dict[str, Any]:
        for rec in forged:
            obs.handle(rec)
        return obs.human_executions(0.15)

    got, peak = _peak(run)
    assert got == {} and "prep_vise" not in obs.end and peak < MiB
    lines = _lines(caplog)
    said = "should be less than 9223372036854775808" if apart_s > 1e10 else \
        "stamped 1e+05 s ahead of its arrival"
    assert len(lines) == 1 and "\n" not in lines[0] and said in lines[0], lines


def test_events_outside_the_cycles_window_or_the_task_bound_are_dropped(painting,
                                                                        caplog) -> None:
    plan = _plan(painting)
    bound = world_task_bound(painting)  # 120 s on painting
    obs = CycleObservation(plan, POINTS, window=1000.0, task_bound=bound)
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    late = plan.wall_ns(2000.0)
    obs.handle(_event(plan, "brush", "start", 0, plan.wall_ns(1.0)))  # the epoch: before t0
    obs.handle(_event(plan, "brush", "start", late, late))  # after the cycle's 1000 s
    assert obs.start == {}
    # inside the window, but an end 500 s after its start: longer than any painting task
    obs.handle(_event(plan, "prep_vise", "start", plan.wall_ns(1.0), plan.wall_ns(1.0)))
    obs.handle(_event(plan, "prep_vise", "end", plan.wall_ns(501.0), plan.wall_ns(501.0)))
    assert "prep_vise" not in obs.end
    lines = _lines(caplog)
    assert [("before the cycle's start" in x, "after the cycle's" in x,
             f"longer than any task of this world ({bound:g} s)" in x) for x in lines] == [
        (True, False, False), (False, True, False), (False, False, True)]
    obs.handle(_event(plan, "prep_vise", "end", plan.wall_ns(7.0), plan.wall_ns(7.0)))
    assert obs.durations("human") == {"prep_vise": pytest.approx(6.0)}
    # a stamp past ROS 2's int64 ns (1e300 would overflow a float) is no event at all
    obs.handle(Received(ros2.EVENTS_TOPIC, ros2.string_message(
        {"task": "brush", "agent": "human", "event": "start", "stamp_ns": 10**400}), late))
    assert "should be less than 9223372036854775808" in _lines(caplog)[-1] and obs.start.keys() == {
        "prep_vise"}


def test_a_plan_a_node_cannot_keep_is_refused(painting) -> None:
    """A forged plan read by the nodes: a clock 1e300 times fast or rows of 1e9 s."""
    payload = live_plan_payload(painting.problem(), 0, ["prep_vise"], ["mix_l"], {},
                                start_ns=time.time_ns(), time_scale=4.0, dt=0.15)
    for bad in ({"time_scale": 1e300}, {"dt": 1e9}, {"stamp_ns": 2**70}):
        with pytest.raises(ros2.MessageError, match="not a live plan"):
            LivePlan.parse(ros2.string_message({**payload, **bad}).data)


# -- the fault log and sizes ----------------------------------------------------------------------
def test_faults_are_counted_per_kind_and_summed_in_one_line_per_cycle(caplog) -> None:
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    faults = FaultLog()
    for i in range(30_000):
        faults.warn("malformed", "dropped message %d", i)
    faults.warn("oversized", "dropped a big one")
    assert faults.summary("cycle 3") == {"malformed": 30_000, "oversized": 1}
    lines = _lines(caplog)
    assert len(lines) == faults.lines_per_kind + 2
    assert lines[-1] == "cycle 3: dropped 30001 message(s): malformed 30000, oversized 1"
    assert faults.summary("cycle 4") == {} and len(_lines(caplog)) == len(lines)


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def test_an_oversized_message_is_dropped_before_it_is_decoded(caplog) -> None:
    ep = _endpoint()
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    with Link({ros2.EVENTS_TOPIC: "std_msgs/msg/String"}, listen=ep) as hub, \
            Link({}, connect=ep) as peer:
        big = ros2.string_message({"task": "x" * (MAX_SMALL_BYTES + 10)})
        ok = ros2.event_message(ros2.Event("brush", "human", "start"))
        deadline, rec = time.monotonic() + 20, None
        while rec is None and time.monotonic() < deadline:  # until the subscription is known
            peer.publish(ros2.EVENTS_TOPIC, big)
            peer.publish(ros2.EVENTS_TOPIC, ok)
            rec = hub.receive(0.3)
        assert rec is not None and rec.msg.data == ok.data  # the big ones never came through
        assert hub.faults.counts().get("oversized", 0) >= 1
    assert any("bytes on /rapidds/events: at most 65536" in x for x in _lines(caplog))


# -- M2: implausible tracking ---------------------------------------------------------------------
def test_the_plausibility_check_bounds_place_and_speed(painting) -> None:
    check = Plausibility(painting)
    assert check.check("a", 0.0, (0.1, -0.3, 0.0)) is None
    assert "outside the workspace" in check.check("a", 0.15, (4.94, -0.3, 0.0))
    assert "faster than 8 m/s" in check.check("a", 0.01, (0.6, -0.3, 0.0))  # 0.5 m in 10 ms
    assert check.check("a", 0.5, (0.6, -0.3, 0.0)) is None  # 0.5 m in 0.5 s: a reach
    assert pytest.approx(8.0) == MAX_BODY_SPEED
    # a wrong first sample is left behind once the allowed step reaches the real stream
    keep, _ = plausible_mask(painting, np.arange(8) * 0.05,
                             np.array([[0.6, 0, 0]] + [[-0.6, 0, 0]] * 7))
    assert keep.tolist() == [True, False, False, True, True, True, True, True]


def _tracked_task(painting, obs: CycleObservation, jump_every: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The left-slow person does prep_vise; every ``jump_every``-th sample of the left wrist
    jumps 5 m (0: none). Returns their true path."""
    plan = obs.plan
    d, path = painting.teammate("left-slow").perform("prep_vise", np.random.default_rng(0))
    obs.handle(_event(plan, "prep_vise", "start", plan.wall_ns(0.0), plan.wall_ns(0.0)))
    for k, row in enumerate(path):
        at = min(k * 0.15, d)
        for j, (name, p) in enumerate(zip(POINTS, row, strict=True)):
            jumped = j == 0 and jump_every and k % jump_every == 1
            obs.handle(_point(plan, name, p + np.array([5.0, 0, 0]) if jumped else p, at))
    obs.handle(_event(plan, "prep_vise", "end", plan.wall_ns(d), plan.wall_ns(d)))
    return path


def test_a_wrist_jumping_5_m_is_dropped_in_one_line_live(painting, caplog) -> None:
    """Probe M2 on the live hub: the 5 m jumps are dropped (one line for the body point), the
    path learned is the person's; a task whose wrist mostly jumps is not learned."""
    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    obs = CycleObservation(_plan(painting), POINTS, plausible=Plausibility(painting))
    truth = _tracked_task(painting, obs, jump_every=5)
    got = obs.human_executions(0.15)["prep_vise"].trajectory
    assert np.abs(got[..., 0]).max() < 0.7
    np.testing.assert_allclose(got[:, 1:], truth[:, 1:], atol=1e-9)
    lines = _lines(caplog)
    assert len(lines) == 1 and f"implausible tracking of {POINTS[0]!r}" in lines[0]
    assert obs.faults.counts()[f"implausible {POINTS[0]}"] == sum(k % 5 == 1
                                                               for k in range(len(truth)))

    mostly = CycleObservation(_plan(painting), POINTS, plausible=Plausibility(painting))
    plan = mostly.plan
    mostly.handle(_event(plan, "prep_vise", "start", plan.wall_ns(0.0), plan.wall_ns(0.0)))
    for k in range(20):
        for j, name in enumerate(POINTS):
            far = j == 0 and k > 2  # the wrist lost after three samples
            mostly.handle(_point(plan, name, (5.0, 0, 0) if far else (0.0, -0.3, 0.0),
                                 k * 0.15))
    mostly.handle(_event(plan, "prep_vise", "end", plan.wall_ns(2.85), plan.wall_ns(2.85)))
    with pytest.raises(ros2.MessageError, match=f"{POINTS[0]} during prep_vise was mostly "
                                                "implausible"):
        mostly.human_executions(0.15)


def test_observe_drops_implausible_samples_and_unlearnable_tasks(painting, caplog,
                                                                 tmp_path: Path) -> None:
    """Probe M2 on ``observe`` (a bag): the same jumps, the same answer."""
    from rapidds.bridge.recorded import RecordedCycle, _Reader, default_mapping, human_executions

    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    d, path = painting.teammate("left-slow").perform("prep_vise", np.random.default_rng(0))
    reader = _Reader(painting, default_mapping(painting).check(painting), "bag")
    ns = (np.minimum(np.arange(len(path)) * 0.15, d) * 1e9).astype(np.int64) + 10**9
    for k, t in enumerate(ns):
        for j, name in enumerate(POINTS):
            jumped = j == 0 and k % 5 == 1
            jump = np.array([5.0, 0, 0]) if jumped else 0.0
            reader.samples[name].append((int(t), path[k, j] + jump))
    reader.out.tasks["prep_vise"] = ("human", int(ns[0]), int(ns[-1]))
    cycle: RecordedCycle = reader.finish()
    got = human_executions(cycle, painting)["prep_vise"].trajectory
    assert np.abs(got[..., 0]).max() < 0.7
    assert sum(f"implausible sample(s) of body point {POINTS[0]!r}" in x
               for x in _lines(caplog)) == 1
    # mostly implausible: the task is dropped with one line
    cycle.implausible[POINTS[0]] = np.repeat(ns, 2)
    assert human_executions(cycle, painting) == {}
    assert "mostly implausible" in _lines(caplog)[-1]


# -- M3: a forged stop, a node that leaves --------------------------------------------------------
class _Nodes:
    """A robot and a tracker as the hub sees them: joint states and the person's body points
    every 20 ms, from a peer holding the robot's liveliness token, until ``close``."""

    def __init__(self, ep: str, painting: Any):
        from rapidds.worlds.base import joint_names

        self.link = Link({}, connect=ep, alive="robot")
        self.joints = joint_names(painting)
        self.q = np.zeros(len(self.joints))
        self.rest = np.asarray(painting.human_rest(), float)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.is_set():
            now = time.time_ns()
            self.link.publish(ros2.JOINT_STATE_TOPIC, ros2.joint_state(self.joints, self.q,
                                                                      stamp_ns=now))
            for name, p in zip(POINTS, self.rest, strict=True):
                self.link.publish(tracking_topic(name), ros2.point_stamped(p, now))
            time.sleep(0.02)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.link.close()


@pytest.fixture(scope="module")
def hub(painting):  # type: ignore[no-untyped-def]
    """A live hub on painting with a small search (its first plan warms the policy)."""
    from rapidds.bridge.cell import CellOptions, LinkTeammate, LiveCell, hub_topics
    from rapidds.loop.config import RunConfig
    from rapidds.loop.run import AdaptiveRun
    from rapidds.worlds.base import body_point_names

    ep = _endpoint()
    cfg = RunConfig(world="painting", human="live", cycles=2, population=8, generations=4,
                    samples=8, particles=2, candidates=4)
    with Link(hub_topics(body_point_names(painting)), listen=ep, watch=True) as link:
        run = AdaptiveRun(cfg, world=painting, teammate=LinkTeammate())
        yield ep, LiveCell(run, link, CellOptions(time_scale=4.0, robot_timeout=30.0,
                                                   startup_timeout=60.0, cycle_timeout=400.0))


def _fault_when(hub: Any, act: Callable[[_Nodes], None]) -> str:
    """Run a cycle on the hub with ``act`` done to the nodes once the plan is out; the
    CellFault's message."""
    from rapidds.bridge.cell import CellFault

    ep, cell = hub
    nodes = _Nodes(ep, cell.run.world)
    peer = Link({ros2.PLAN_TOPIC: "std_msgs/msg/String"}, connect=ep)
    try:
        cell.wait_ready()

        def watch() -> None:
            if peer.receive(120.0) is not None:  # the plan is out: the cycle runs
                act(nodes)

        threading.Thread(target=watch, daemon=True).start()
        with pytest.raises(CellFault) as err:
            cell.cycle()
        return str(err.value)
    finally:
        nodes.close()
        peer.close()


def test_a_stop_the_hub_did_not_send_ends_the_cycle_at_once(hub) -> None:
    """Probe M3: a forged stop mid-cycle; the hub stops with the stop's reason and sender (the
    cycle would otherwise run to its 400 s timeout: the nodes here never end a task)."""
    from rapidds.bridge.live import STOP_TOPIC, stop_payload

    def forge(nodes: _Nodes) -> None:
        stop = stop_payload(0, "forged\nstop", "mallory")
        nodes.link.publish(STOP_TOPIC, ros2.string_message(stop))

    said = _fault_when(hub, forge)
    assert said.startswith("cycle 0 stopped, not recorded: a stop from mallory: forged stop;")
    assert hub[1].run.next_cycle == 0  # not recorded


def test_the_hub_drops_a_forged_event_pair_and_runs_on(hub, caplog) -> None:
    """Probe H1 on the hub itself: the forged pair (start now, end 1e15 s later) from a peer
    mid-cycle is one line, the cycle runs on (here until a stop ends it), and the hub's peak
    resident memory does not grow past 64 MiB."""
    import resource

    from rapidds.bridge.live import STOP_TOPIC, stop_payload

    caplog.set_level(logging.WARNING, logger="rapidds.bridge")
    cell = hub[1]

    def forge(nodes: _Nodes) -> None:
        now = time.time_ns()
        for kind, stamp in (("start", now), ("end", now + 10**24)):
            nodes.link.publish(ros2.EVENTS_TOPIC, ros2.event_message(
                ros2.Event("prep_vise", "human", kind, stamp)))  # type: ignore[arg-type]
        deadline = time.monotonic() + 60
        while not cell.link.faults.counts().get("malformed event") \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        nodes.link.publish(STOP_TOPIC, ros2.string_message(stop_payload(0, "done", "test")))

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB
    said = _fault_when(hub, forge)
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert "a stop from test: done" in said and grown < 64 * 1024
    forged = [x for x in _lines(caplog) if "prep_vise" in x]
    assert len(forged) == 1 and "should be less than 9223372036854775808" in forged[0]
    assert any(x.startswith("cycle 0: dropped 1 message(s): malformed event 1")
               for x in _lines(caplog))


def test_a_node_that_leaves_the_link_ends_the_cycle_at_once(hub) -> None:
    said = _fault_when(hub, lambda nodes: nodes.close())
    assert "the robot node left the link" in said


# -- the CLI: a busy port, huge demonstrations, an option that does not apply ----------------------
def test_a_hub_on_a_busy_port_says_so_and_leaves_no_store(capsys, tmp_path: Path) -> None:
    ep = _endpoint()
    with Link({}, listen=ep):
        code, _, err = run_main(capsys, "deploy", "painting", "--listen", ep, "--out",
                                str(tmp_path / "run"))
    assert code == 2 and err.count("\n") == 1 and "cannot open the Zenoh link" in err
    assert not (tmp_path / "run" / "run.sqlite").exists()


def test_train_policy_on_huge_finite_demonstrations_is_one_line(capsys, tmp_path: Path) -> None:
    demos = tmp_path / "big.npz"
    np.savez(demos, trajectories=np.random.default_rng(0).uniform(-1, 1, (4, 8, 2)) * 1e308,
             task_index=np.zeros(4, int), task_names=np.array(["a"]))
    code, _, err = run_main(capsys, "train-policy", "--demos", str(demos), "--out",
                            str(tmp_path / "p"), "--steps", "1")
    assert code == 2 and err.count("\n") == 1 and "float32's 3.4e38" in err


def test_sample_refuses_a_steer_cost_it_would_ignore(capsys) -> None:
    code, _, err = run_main(capsys, "sample", "--task", "t0", "--world", "fetch",
                            "--steer-cost", "5,6;x")
    assert code == 2 and err.count("\n") == 1 and "--steer-cost only without --world" in err
