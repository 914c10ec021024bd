"""Plan first, record after: the next cycle's plan and robot trajectories as a bag
(``rapidds plan-next``), for a cell without the live link. The lab executes it with its own
executive (a robot task starts when every task in its ``after`` list has ended), records the
cycle as ``rapidds observe`` reads it (task events, tracked body points), and hands the bag to
``observe``, which plans the same cycle again (same run, same state, same seeds: the same plan)
and learns it from what was recorded.

Nothing is stored: the run's folder is only read. Topics (bag clock from ``epoch_ns``, the
plan's expected timeline):

- ``/rapidds/plan`` (String JSON, :func:`~rapidds.bridge.live.live_plan_payload`): the cycle,
  each agent's order and waits, ``after`` (task -> the tasks that must end before it), the
  expected start and end of every task, ``stamp_ns`` (the epoch), ``dt``;
- ``/rapidds/robot/trajectory`` (JointTrajectory) per robot task at the epoch, header stamp
  its expected start; the same on the robot profile's ``/<controller>/joint_trajectory`` at
  its expected start, header stamp 0 ("start now"). Cut to the task, time-parameterized
  within the profile's limits, the driver's names and offsets.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rapidds.bridge import ros2
from rapidds.bridge.bag import BagMessage, write_bag
from rapidds.bridge.live import live_plan_payload
from rapidds.bridge.profiles import RobotProfile
from rapidds.errors import RapiddsError

__all__ = ["NextPlan", "plan_messages", "plan_next"]

_NS = 1_000_000_000
_TRAJ = "trajectory_msgs/msg/JointTrajectory"


@dataclass(frozen=True)
class NextPlan:
    """What ``plan-next`` wrote: the run, its next cycle, the plan's JSON, the bag."""

    run_id: str
    cycle: int
    payload: dict[str, Any]
    out: Path
    messages: int


def _next_run(run_dir: Path, config: Any, run_id: str | None, policy: Path | None) -> Any:
    """The run's AdaptiveRun at its next cycle, attached to nothing (the store only read)."""
    from rapidds.bridge.recorded import RecordedTeammate
    from rapidds.loop.config import RunConfig
    from rapidds.loop.model import HumanModel
    from rapidds.loop.run import AdaptiveRun, load_policy
    from rapidds.store import RunStore
    from rapidds.worlds.registry import make_world

    path = run_dir / "run.sqlite"
    stored, state, last = None, None, None
    if path.exists():
        with RunStore.open_readonly(path) as store:
            rid = store.pick_run(run_id) if store.run_ids() or run_id else None
            if rid is not None:
                stored = store.run_config(rid)
                last = store.last_cycle(rid)
                state = None if last is None else store.state(rid, last)
    if stored is None and config is None:
        raise RapiddsError(f"{run_dir} holds no run; plan its first cycle with --config RUN.yaml")
    cfg = config if config is not None else RunConfig(**stored)
    world = make_world(cfg.world, cfg.variant)
    if stored is not None and config is not None and cfg.resolved(world).run_id != \
            RunConfig(**stored).resolved(world).run_id:
        raise RapiddsError(f"{run_dir} holds another run than --config's; plan into another "
                           "folder")
    run = AdaptiveRun(cfg, load_policy(world, policy), None, world,
                      teammate=RecordedTeammate())
    if last is not None:
        if state is None:
            raise RapiddsError(f"run '{cfg.run_id}' cycle {last} has no stored model")
        run.model, run.next_cycle = HumanModel.from_bytes(state), last + 1
    if run.finished:
        raise RapiddsError(f"run '{cfg.run_id}' is finished ({cfg.cycles} cycles); nothing to "
                           "plan")
    return run


def plan_messages(run: Any, plan: Any, profile: RobotProfile,
                  epoch_ns: int) -> tuple[dict[str, Any], list[BagMessage]]:
    """The plan's JSON and its messages (module docstring)."""
    best, problem, world = plan.best, run.problem, run.world
    idx = problem.index
    expected = {t: (float(best.expected_start[idx[t]]), float(best.expected_finish[idx[t]]))
                for t in problem.ids if t in idx and len(best.expected_start)}
    payload = live_plan_payload(problem, plan.cycle, best.schedule.human, best.schedule.robot,
                                expected, start_ns=epoch_ns, time_scale=1.0, dt=world.dt)
    out = [BagMessage(ros2.PLAN_TOPIC, "std_msgs/msg/String", epoch_ns,
                      ros2.string_message(payload))]
    for task in payload["order"]["robot"]:
        timed = profile.timed(world, task, best.motions[task].trajectory)
        begin = epoch_ns + round(expected[task][0] * _NS)
        out.append(BagMessage(ros2.TRAJECTORY_TOPIC, _TRAJ, epoch_ns,
                              profile.trajectory(world, timed, stamp_ns=begin)))
        out.append(BagMessage(profile.trajectory_topic, _TRAJ, begin,
                              profile.trajectory(world, timed)))
    return payload, sorted(out, key=lambda m: m.time_ns)


def plan_next(run_dir: Path, out: Path, profile: RobotProfile, epoch_ns: int,
              config: Any = None, run_id: str | None = None,
              policy: Path | None = None) -> NextPlan:
    """Plan the run's next cycle and write it to the MCAP file ``out`` (never overwritten).
    config: a RunConfig to start a new run with (a folder without one)."""
    if out.exists():
        raise RapiddsError(f"{out} exists; choose another --out")
    run = _next_run(run_dir, config, run_id, policy)
    profile.limits(run.world)  # a profile that does not fit: one line, before planning
    plan = run.plan()
    payload, msgs = plan_messages(run, plan, profile, epoch_ns)
    path = write_bag(out, msgs)
    return NextPlan(run.config.run_id, plan.cycle, payload, Path(path), len(msgs))
