"""Execution as a registered, typed setting (issue 32): the registry is the one place that knows
what a mode does; everyone else asks its entry, and a run stores it as it always did."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Literal

import pytest
from conftest import SMALL_SEARCH as SMALL

from rapidds.bridge.reactive import DELIVERY, SpeedMonitor
from rapidds.errors import ConfigError, RapiddsError
from rapidds.execution import OpenLoop, PlannedRobot, SimulatedHuman, SpeedSeparation
from rapidds.execution.registry import (
    ExecutionSetting,
    Monitored,
    Planned,
    Reactive,
    execution_names,
    execution_setting,
    register_execution,
)
from rapidds.loop import AdaptiveRun, RunConfig
from rapidds.loop.execute import CycleSetup, cycle_executor
from rapidds.worlds.reactions import cell_reactions
from rapidds.worlds.registry import make_world

SRC = Path(__file__).resolve().parents[1] / "src" / "rapidds"
REGISTRY = SRC / "execution" / "registry.py"
BUILT_IN = {"planned", "reactive", "monitored", "replanning"}


def _mode_strings(node: ast.AST) -> list[str]:
    return [n.value for n in ast.walk(node)
            if isinstance(n, ast.Constant) and n.value in BUILT_IN]


def test_no_string_test_of_an_execution_mode_outside_its_registry() -> None:
    """No comparison with a mode's name (``== "reactive"``, ``in ("planned", ...)``) and no list
    of mode names anywhere in the library but the registry: what a mode does is its entry's
    switches (``config.execution.monitor``), so a new entry needs no edit elsewhere."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path == REGISTRY:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare) and _mode_strings(node):
                found.append(f"{path.relative_to(SRC)}:{node.lineno}: {ast.unparse(node)}")
            elif isinstance(node, ast.Tuple | ast.List | ast.Set) and len(
                    _mode_strings(node)) >= 2:
                found.append(f"{path.relative_to(SRC)}:{node.lineno}: a list of modes")
    assert not found, "ask the execution entry instead:\n" + "\n".join(found)


def test_the_entries_are_separate_switches() -> None:
    limits = cell_reactions(make_world("fetch"))[1]
    switches = {n: (execution_setting(n).monitor, execution_setting(n).replan)
                for n in BUILT_IN}
    assert switches == {"planned": (False, False), "monitored": (True, False),
                        "replanning": (False, True), "reactive": (True, True)}
    for name, (monitor, replan) in switches.items():
        entry = execution_setting(name)
        assert isinstance(entry.policy(limits), SpeedSeparation) == monitor
        assert (entry.policy(limits) is None) == (not monitor)
        assert (entry.replanner(_replanning) is not None) == replan
        assert entry.in_cycle == (monitor or replan) and str(entry) == name
    assert set(execution_names()) >= BUILT_IN


def test_a_run_stores_its_execution_by_name_as_before() -> None:
    """The stored config is the one earlier stores hold; parameters other than the entry's
    defaults are stored as a mapping and read back."""
    for name in BUILT_IN:
        cfg = RunConfig(execution=name)
        assert cfg.model_dump()["execution"] == name
        assert RunConfig(**cfg.model_dump()) == cfg
    assert RunConfig().model_dump()["execution"] == "planned"
    assert RunConfig(execution="reactive").cell_suffix == "-reactive"
    assert RunConfig(execution="planned").cell_suffix == ""
    tuned = RunConfig(execution={"kind": "reactive", "steer_max": 3})
    assert tuned.model_dump()["execution"] == {"kind": "reactive", "overrun_z": 1.2816,
                                               "steer_max": 3}
    assert RunConfig(**tuned.model_dump()).execution == Reactive(steer_max=3)
    assert tuned.execution.replanner(_replanning).steer_max == 3


def _replanning():  # a stand-in for what the loop builds from its beliefs
    from rapidds.execution import Replanning

    return Replanning(mean={}, std={}, robot={}, spatial=lambda j, c: 0.0, gamma=1.0)


@pytest.mark.parametrize(("value", "says"), [
    ("sideways", "--execution: must be one of planned, reactive, monitored, replanning"),
    ({"kind": "reactive", "steer_max": -1}, "steer_max"),
    ({"kind": "planned", "steer_max": 1}, "unknown field"),
])
def test_a_bad_execution_is_one_line(value, says) -> None:
    with pytest.raises(ConfigError) as err:
        RunConfig(execution=value)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_name_is_registered_once() -> None:
    with pytest.raises(ValueError, match="registered already"):
        @register_execution
        class Again(ExecutionSetting):
            kind: Literal["reactive"] = "reactive"
    with pytest.raises(TypeError, match="its name as default"):
        register_execution(type("Nameless", (ExecutionSetting,), {}))
    assert register_execution(Planned) is Planned  # the same class again: nothing changes


def test_the_executor_and_the_live_monitor_get_their_policy_from_the_entry(
        fetch_policy) -> None:
    """One factory: the simulated (and browser) executor's policy and re-planner, and the live
    cell's monitor's policy (with its latencies in T_r) are what the entry builds."""
    run = AdaptiveRun(RunConfig(human="slow-middle", cycles=1, **SMALL), fetch_policy)
    plan = run.plan()
    beliefs = (run.model.temporal.mean(), run.model.temporal.std())
    human = run.teammate.execute(0, plan.best.schedule.tasks("human"), plan.rng)
    for name in BUILT_IN:
        cfg = run.config.replace(execution=name, slowdowns=None)
        person = SimulatedHuman(run.world, human, lambda t: (0.0, None), None, None)
        ex = cycle_executor(CycleSetup(run.world, run.problem, cfg, 0, plan.gamma,
                                       plan.best.schedule, plan.best.motions, beliefs,
                                       run.model.spatial, 1.0), person)
        assert isinstance(ex.robot, PlannedRobot)
        assert isinstance(ex.policy, SpeedSeparation if cfg.execution.monitor else OpenLoop)
        assert (ex.replanning is not None) == cfg.execution.replan
    limits = cell_reactions(run.world)[1]
    monitor = SpeedMonitor(run.world, {}, period=0.05, execution=Monitored())
    live = monitor.policy_now(0.1)
    assert isinstance(live, SpeedSeparation)
    assert live.limits.reaction_time == pytest.approx(limits.reaction_time + 0.15 + DELIVERY)
    with pytest.raises(RapiddsError, match="does not monitor"):
        SpeedMonitor(run.world, {}, execution=Planned())
