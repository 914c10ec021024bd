"""The study protocol for the browser: what a participant does next, the robot's plan for their
round, and every submit as one transaction of the study store.

:class:`StudySession` owns the :class:`~rapidds.experiments.study.store.StudyStore` and one
:class:`~rapidds.loop.run.AdaptiveRun` per participant x system attached to it, and must be used
from one thread (an SQLite connection belongs to the thread that opened it; the app gives it a
worker thread of its own). The store is the only state: the next step comes from
``store.next_step`` and a round's plan is planned again from (seed, round) and the stored models
whenever it is not in memory (after a restart, say), which gives the plan shown before the
restart, since the loop draws every random number of a cycle from (seed, cycle).

Each submit names the step its page answered (:attr:`View.step`): a page left open while the
study moved on (a second tab, a re-post) is refused with what comes next instead, never
recorded twice. A round is validated completely (tracker file, durations) before the loop sees
it, then executed, learned and recorded by the loop in one store transaction; if anything fails
after validation, the run is reloaded from the store, so memory never runs ahead of it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.errors import RapiddsError, StateError, StudyDataError
from rapidds.experiments.study.design import MAX_TASK_S_LIMIT
from rapidds.experiments.study.store import (
    STORE_NAME,
    Step,
    StudyStore,
    study_path,
    validate_durations,
)
from rapidds.loop.observation import Observation, Said
from rapidds.schedule import Timeline
from rapidds.web.study.pages import COMFORT_ITEM, DEMOGRAPHICS, gantt_svg
from rapidds.web.study.tracker import (
    TrackerError,
    group_teammate,
    parse_tracker,
    typed_execution,
)
from rapidds.worlds.base import HumanExecution, SimulatedTeammate, Teammate, World
from rapidds.worlds.capabilities import capability, lacks
from rapidds.worlds.registry import make_world

if TYPE_CHECKING:
    from rapidds.execution import CycleExecutor, Deployment, HumanSource
    from rapidds.loop.model import HumanModel
    from rapidds.loop.run import AdaptiveRun, CyclePlan
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.record import CycleRecord

__all__ = ["InputError", "OutOfTurn", "StudySession", "View", "parse_presses",
           "step_token"]

SOURCES = ("tracker", "bag", "simulated", "typed", "game")
"""Where a round's data come from; "game" (a world with browser_play): played at
``/p/{pid}/play``."""


class InputError(RapiddsError):
    """What the page sent cannot be used; the message says what to fix (shown on the page)."""


class OutOfTurn(RapiddsError):
    """The page answered a step that is not the participant's next one (already done, or not
    yet); ``next_step`` is the one that is."""

    def __init__(self, message: str, next_step: Step):
        super().__init__(message)
        self.next_step = next_step


COMFORT_FIELDS = ("comfort", "too_close")
"""The round form's fields of the comfort item: the answer and the presses' times."""


def parse_presses(text: str) -> list[float]:
    """The "too close" presses a round page sent: seconds on the round clock, comma-separated
    (empty: none), each in [0, :data:`CLOCK_LIMIT_S`], at most :data:`MAX_SIGNALS`; sorted."""
    parts = [p.strip() for p in text.split(",")] if text.strip() else []
    if len(parts) > MAX_SIGNALS:
        raise InputError(f"too close: {len(parts)} presses in one round, at most {MAX_SIGNALS}")
    times = []
    for p in parts:
        try:
            t = float(p) if re.fullmatch(r"[0-9]+(\.[0-9]*)?", p) else math.nan
        except ValueError:
            t = math.nan
        if not 0 <= t <= CLOCK_LIMIT_S:  # nan too
            raise InputError(f"too close: {p[:20]!r} is not a time in seconds from the round's "
                             f"start (0..{CLOCK_LIMIT_S:g})")
        times.append(t)
    return sorted(times)


def step_token(step: Step) -> str:
    """The step a page answers, as the page sends it back: e.g. ``round:full:3``."""
    if step.kind == "round":
        return f"round:{step.system}:{step.round}"
    if step.kind == "survey":
        return f"survey:{step.system}"
    return step.kind


@dataclass
class View:
    """What the round page shows: the plan of ``round`` (1-based) of the ``block``-th system."""

    step: str
    block: int
    blocks: int
    round: int
    rounds: int
    human: list[str]
    robot: list[str]
    routes: dict[str, str]
    expected: dict[str, float]
    makespan: float
    gantt: str

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


MAX_SIGNALS = 200
"""The most "too close" presses one round may send (one every 2 s of a long round; more is a
stuck key or a script)."""
CLOCK_LIMIT_S = MAX_TASK_S_LIMIT
"""The latest time a press may have on the round clock: the longest task any design allows."""


class _Unobserved:
    """The teammate of a participant whose priming group has no simulated person: the loop
    always gets what they did from the page, and asking it to act is an input error."""

    def __init__(self, name: str, why: str):
        self.name, self._why = name, why

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        raise InputError(self._why)


@dataclass(frozen=True)
class _Round:
    """A submitted round as the loop's :class:`~rapidds.loop.observation.Source`: what the
    page sent (``human``; None: the priming group's simulated person does the round, from the
    cycle's stream), the whole round when the game played it live (``played``), and what the
    participant said (``said``; None: the design does not ask)."""

    teammate: Teammate
    human: Mapping[str, HumanExecution] | None
    said: Said | None
    played: Deployment | None = None

    def observe(self, cycle: CyclePlan) -> Observation:
        if self.played is not None:
            return Observation(played=self.played, said=self.said)
        human = (self.human if self.human is not None else
                 self.teammate.execute(cycle.cycle, cycle.best.schedule.tasks("human"),
                                       cycle.rng))
        return Observation(human=human, said=self.said)


class StudySession:
    """The study in ``folder`` (its ``study.sqlite``), served to one experimenter's browser."""

    def __init__(self, folder: Path, *, policy: DiffusionPolicy | None = None,
                 policy_path: Path | None = None, world: World | None = None,
                 lock_as: str | None = "rapidds study serve"):
        path = study_path(folder)
        if not path.is_file():
            raise StateError(f"{folder} holds no study ({STORE_NAME}); create one with "
                             f"'rapidds study design --out {folder}'")
        self.store = StudyStore(path, lock_as=lock_as)
        try:
            base = self.store.base_config
            if world is not None and (world.name, world.variant) != (base.world, base.variant):
                raise StateError(f"the study runs on {base.world} ({base.variant}), not "
                                 f"{world.name} ({world.variant})")
            self.world: World = world or make_world(base.world, base.variant)
            if policy is None:
                from rapidds.loop.run import load_policy

                policy = load_policy(self.world, policy_path)
            self.policy = policy
        except BaseException:
            self.store.close()
            raise
        self._prior: HumanModel | None = None  # the population prior, computed once
        self._runs: dict[str, AdaptiveRun] = {}
        self._plans: dict[str, tuple[CyclePlan, View]] = {}

    def close(self) -> None:
        self.store.close()

    # -- reading ------------------------------------------------------------------------------
    @property
    def rounds(self) -> int:
        return self.store.design.rounds

    def next_step(self, pid: str) -> Step:
        return self.store.next_step(pid)

    def overview(self) -> list[dict[str, Any]]:
        """Every participant with their group, order of systems and next step."""
        return [{"participant": p.id, "group": p.group, "order": list(p.systems),
                 "next": self.store.next_step(p.id).describe()}
                for p in self.store.participants()]

    def items(self) -> list[dict[str, Any]]:
        return [{"id": i.id, "text": i.text} for i in self.store.items.items]

    @property
    def task_bound(self) -> float:
        """Seconds a person's task may take in this study (the design's ``max_task_s`` or the
        world's bound): longer typed durations and tracked tasks are refused."""
        return self.store.design.task_bound(self.world)

    def sources(self, pid: str) -> tuple[str, ...]:
        """The sources ``pid``'s round page offers: a tracker file and a bag always; the simulated
        cell and typed-in durations when their priming group names a simulated teammate of the
        world; the game when the world declares browser_play."""
        group = self.store.participant(pid).group in self.world.teammate_names
        return tuple(s for s in SOURCES if s in ("tracker", "bag")
                     or (s == "game" and self.has_game)
                     or (s in ("simulated", "typed") and group))

    def teammate(self, pid: str) -> SimulatedTeammate:
        """The simulated person of ``pid``'s priming group (TrackerError if the world has none
        of that name)."""
        return group_teammate(self.world, self.store.participant(pid).group)

    def prior(self) -> HumanModel:
        """The population prior every run starts from (the same for all of the study's runs:
        it depends on the world and the spatial settings only), computed once; the server
        computes it right after it starts, so the first page does not wait for it."""
        if self._prior is None:
            from rapidds.loop.model import prior_model

            self._prior = prior_model(self.world, self.store.base_config)
        return self._prior

    def _run(self, pid: str, system: str) -> AdaptiveRun:
        from rapidds.loop.run import AdaptiveRun

        rid = self.store.run_id(pid, system)
        run = self._runs.get(rid)
        if run is None:
            mate: Teammate
            try:
                mate = self.teammate(pid)
            except TrackerError as exc:
                mate = _Unobserved(pid, str(exc))
            run = AdaptiveRun(self.store.config_for(pid, system), self.policy, self.store,
                              self.world, teammate=mate, prior=self.prior())
            self._runs[rid] = run
        return run

    def live_executor(self, pid: str) -> Callable[[HumanSource], CycleExecutor] | None:
        """What builds the executor that drives the robot of ``pid``'s held round in the game
        under reactive execution (the one ``rapidds play --execution reactive`` uses); None
        under planned execution, or when their next step is not a round."""
        held = self.plan(pid)
        if held is None or not self.store.base_config.execution.in_cycle:
            return None
        step = self.store.next_step(pid)
        assert step.system is not None
        return self._run(pid, step.system).live_executor(held[0])

    def _forget(self, pid: str, system: str) -> None:
        rid = self.store.run_id(pid, system)
        self._runs.pop(rid, None)
        self._plans.pop(rid, None)

    def plan(self, pid: str) -> tuple[CyclePlan, View] | None:
        """The plan of ``pid``'s next round and what the page shows of it; None when their next
        step is not a round. Planned once and kept until the round is recorded."""
        step = self.store.next_step(pid)
        if step.kind != "round":
            return None
        assert step.system is not None and step.round is not None and step.block is not None
        rid = self.store.run_id(pid, step.system)
        held = self._plans.get(rid)
        if held is not None and held[0].cycle == step.round:
            return held
        run = self._run(pid, step.system)
        if run.next_cycle != step.round:  # stored by someone else meanwhile: reload
            self._forget(pid, step.system)
            run = self._run(pid, step.system)
        plan = run.plan()
        view = self._view(run, plan, step)
        self._plans[rid] = (plan, view)
        return plan, view

    def _view(self, run: AdaptiveRun, plan: CyclePlan, step: Step) -> View:
        best, problem = plan.best, run.problem
        idx = problem.index
        start, finish = best.expected_start, best.expected_finish
        timeline = Timeline(problem, best.schedule, start[None], finish[None])
        human = [str(x) for x in best.schedule.human]
        return View(
            step=step_token(step), block=int(step.block or 0),
            blocks=len(self.store.design.systems), round=int(step.round or 0) + 1,
            rounds=self.rounds, human=human, robot=[str(x) for x in best.schedule.robot],
            routes={j: self.world.motion_label(j, p.trajectory)
                    for j, p in best.motions.items() if p.trajectory is not None},
            expected={t: float(finish[idx[t]] - start[idx[t]])
                      for t in best.schedule.tasks("human")},
            makespan=float(np.max(finish)),
            gantt=gantt_svg(timeline, title="the robot's plan (expected times)"))

    # -- submits ------------------------------------------------------------------------------
    def _turn(self, pid: str, token: str, kind: str) -> Step:
        """``pid``'s next step, if it is the one the page answered and of ``kind``."""
        step = self.store.next_step(pid)
        if token != step_token(step) or step.kind != kind:
            raise OutOfTurn(f"this page is out of date (it answers '{token[:60]}' with a {kind} "
                            f"submit); {pid}'s next step is {step.describe()}: reload the page",
                            step)
        return step

    def submit_round(self, pid: str, token: str, source: str, fields: Mapping[str, str],
                     tracker: str | None = None,
                     played: Mapping[str, HumanExecution] | None = None,
                     live: Deployment | None = None) -> CycleRecord:
        """Record what the person did in their current round (one transaction) and return the
        cycle's (typed) record. played: what they did in the game (source "game"), as the
        :class:`~rapidds.web.player.BrowserPlayer` observed it; live: the whole game round
        under reactive execution, played on the run's executor (:meth:`live_executor`)."""
        step = self._turn(pid, token, "round")
        assert step.system is not None
        held = self.plan(pid)
        assert held is not None
        plan, _ = held
        tasks = plan.best.schedule.tasks("human")
        said = self._comfort(source, fields)
        if self.store.design.comfort:  # else they stay, and are refused as unknown fields
            fields = {k: v for k, v in fields.items() if k not in COMFORT_FIELDS}
        observed = self._observed(pid, source, fields, tracker, tasks, played, live)
        run = self._run(pid, step.system)
        try:
            return run.step(_Round(run.teammate, observed, said, live), plan).record
        finally:  # recorded or not, the next plan starts from the store
            self._plans.pop(run.config.run_id, None)
            if run.next_cycle != plan.cycle + 1:
                self._forget(pid, step.system)

    def _comfort(self, source: str, fields: Mapping[str, str]) -> Said | None:
        """The round's comfort answer and "too close" times (seconds on the round clock) when
        the design asks the item, else None; the fields are unknown to a design without it."""
        if not self.store.design.comfort:
            return None
        answer = str(fields.get("comfort", "")).strip()
        if not re.fullmatch(r"[1-7]", answer):
            raise InputError(f"\u201c{COMFORT_ITEM}\u201d: the answer must be 1..7, got "
                             f"{answer[:20]!r}" if answer else
                             f"please answer \u201c{COMFORT_ITEM}\u201d (1-7)")
        return Said(int(answer), tuple(parse_presses(str(fields.get("too_close", "")))))

    def _observed(self, pid: str, source: str, fields: Mapping[str, str], tracker: str | None,
                  tasks: Sequence[str], played: Mapping[str, HumanExecution] | None,
                  live: Deployment | None = None) -> dict[str, HumanExecution] | None:
        if source not in SOURCES:
            raise InputError(f"choose where the round's data come from: {', '.join(SOURCES)}")
        unknown = sorted(set(fields) - {f"d:{t}" for t in tasks} - {"bag"})
        if unknown:  # e.g. the duration of a robot task: the page never sends one
            raise InputError(f"unknown field(s) in the round: {', '.join(unknown[:5])[:200]} (the "
                             f"person's tasks: {', '.join(tasks) or 'none'})")
        if source == "game":
            return self._played(pid, tasks, played, live)
        if not tasks:
            return {}
        if source == "bag":
            return self._bag(str(fields.get("bag", "")).strip(), tasks)
        if source == "tracker":
            if not tracker:
                raise InputError("choose the tracker file of this round (CSV or JSON)")
            try:
                return parse_tracker(tracker.encode("utf-8"), self.world, tasks,
                                     self.task_bound)
            except TrackerError as exc:
                raise InputError(str(exc)) from None
        try:
            mate = self.teammate(pid)
        except TrackerError as exc:
            raise InputError(str(exc)) from None
        if source == "simulated":
            return None
        typed = {t: str(fields.get(f"d:{t}", "")).strip() for t in tasks}
        empty = [t for t, v in typed.items() if not v]
        if empty:
            raise InputError(f"type the duration of {', '.join(empty)} in seconds")
        for t, v in typed.items():
            try:
                ok = math.isfinite(float(v)) and float(v) > 0
            except ValueError:
                ok = False
            if not ok:
                raise InputError(f"duration of {t}: {v[:40]!r} is not a positive number of "
                                 "seconds")
        try:
            durations = validate_durations(typed, tasks, self.task_bound)
        except StudyDataError as exc:  # longer than any task: a typo (4500 for 4.5)
            raise InputError(str(exc)) from None
        return {t: typed_execution(self.world, mate, t, d) for t, d in durations.items()}

    def _bag(self, name: str, tasks: Sequence[str]) -> dict[str, HumanExecution]:
        """The round as recorded in the cell: a rosbag2 bag in the study folder's ``bags/``,
        named on the page (only there: the page never makes the server read other files),
        under the world's default tracking mapping (README, "In a real cell")."""
        from rapidds.bridge.recorded import observed_for, read_cycle

        if not name or name != Path(name).name or name.startswith("."):
            raise InputError("type the file name of the round's bag, which lies in the study "
                             "folder's bags/")
        folder = self.store.path.parent
        try:
            cycle = read_cycle(folder / "bags" / name, self.world)
            return observed_for(cycle, self.world, tasks)
        except RapiddsError as exc:  # the page names the bag as bags/NAME, never the server's
            raise InputError(str(exc).replace(str(folder / "bags"), "bags")
                             .replace(str(folder), "the study folder")) from None

    @property
    def has_game(self) -> bool:
        """Whether the round can be played in the browser game (the world declares it)."""
        return capability(self.world, "browser_play") is not None

    def _played(self, pid: str, tasks: Sequence[str],
                played: Mapping[str, HumanExecution] | None,
                live: Deployment | None) -> dict[str, HumanExecution] | None:
        """What the game observed of the person (None: a live round, ``live`` holds it all)."""
        if not self.has_game:
            raise InputError(f"no game source: {lacks(self.world, 'browser_play')}; choose "
                             f"{', '.join(SOURCES[:-1])}")
        if live is not None:
            if set(live.human) != set(tasks):
                raise InputError(f"the game played {sorted(live.human)}, the plan gave the "
                                 f"person {sorted(tasks)}")
            return None
        if played is None:
            raise InputError(f"a game round is recorded by the game itself: open /p/{pid}/play "
                             "and play the round there")
        if set(played) != set(tasks):
            raise InputError(f"the game played {sorted(played)}, the plan gave the person "
                             f"{sorted(tasks)}")
        return dict(played)

    def submit_survey(self, pid: str, token: str, fields: Mapping[str, str]) -> None:
        step = self._turn(pid, token, "survey")
        assert step.system is not None
        items = self.store.items.items
        unanswered = [i for i in items if not str(fields.get(i.id, "")).strip()]
        if unanswered:
            raise InputError(f"please answer every statement: {len(unanswered)} not answered "
                             f"yet (e.g. \u201c{unanswered[0].text}\u201d)")
        answers: dict[str, int] = {}
        for i in items:
            v = str(fields[i.id]).strip()
            if not re.fullmatch(r"[1-7]", v):
                raise InputError(f"\u201c{i.text}\u201d: the answer must be 1..7, got {v!r}")
            answers[i.id] = int(v)
        extra = sorted(set(fields) - {i.id for i in items})
        if extra:
            raise InputError(f"unknown survey item(s): {', '.join(extra[:5])}")
        try:
            self.store.submit_survey(pid, step.system, answers)
        except StudyDataError as exc:
            raise InputError(str(exc)) from None

    def submit_ranking(self, pid: str, token: str, fields: Mapping[str, str]) -> None:
        self._turn(pid, token, "ranking")
        systems = self.store.participant(pid).systems
        n = len(systems)
        extra = sorted(set(fields) - {f"rank{r}" for r in range(1, n + 1)})
        if extra:
            raise InputError(f"unknown field(s) in the ranking: {', '.join(extra[:5])}")
        chosen: list[int] = []
        for r in range(1, n + 1):
            v = str(fields.get(f"rank{r}", "")).strip()
            if not v:
                raise InputError(f"choose a system for every place: place {r} is empty")
            if not re.fullmatch(r"\d{1,3}", v) or not 1 <= int(v) <= n:
                raise InputError(f"place {r}: {v!r} is not one of the systems 1..{n}")
            chosen.append(int(v))
        twice = sorted({b for b in chosen if chosen.count(b) > 1})
        if twice:
            never = sorted(set(range(1, n + 1)) - set(chosen))
            raise InputError("each system exactly once: "
                             + ", ".join(f"system {b} is chosen twice" for b in twice)
                             + "; " + ", ".join(f"system {b} never" for b in never))
        try:
            self.store.submit_ranking(pid, [systems[b - 1] for b in chosen])
        except StudyDataError as exc:
            raise InputError(str(exc)) from None

    def submit_demographics(self, pid: str, token: str, fields: Mapping[str, str]) -> None:
        self._turn(pid, token, "demographics")
        known = {name for name, _, _ in DEMOGRAPHICS}
        extra = sorted(set(fields) - known)
        if extra:
            raise InputError(f"unknown field(s): {', '.join(extra[:5])}")
        clean = {k: str(v).strip() for k, v in fields.items() if str(v).strip()}
        age = clean.get("age")
        if age is not None and not (re.fullmatch(r"\d{1,3}", age) and 0 < int(age) <= 130):
            raise InputError(f"age: {age!r} is not a whole number of years")
        try:
            self.store.submit_demographics(pid, clean)
        except StudyDataError as exc:
            raise InputError(str(exc)) from None
