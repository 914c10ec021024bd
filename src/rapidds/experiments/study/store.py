"""The user study's SQLite store: design, every participant x system run, survey, ranking,
demographics and where each participant stands.

API (all writes one transaction each; readers never block the writer):

* ``StudyStore.create(path, design, run, items=None)`` creates ``path`` (or opens it) and
  stores the design once: the :class:`~.design.StudyDesign`, the base
  :class:`~rapidds.loop.config.RunConfig` (world, variant resolved, gamma, search sizes) and
  the :class:`SurveyItems` (default: the packaged ``items.yaml``). A different design already
  there is refused (StateError), the same one is a no-op.
* ``StudyStore(path)`` opens for writing, ``StudyStore.open_readonly(path)`` for reading; a file
  that is not a study store (a plain run store, an ablation's, another SQLite file, a text
  file) is refused with one line.
* ``store.design``, ``store.base_config``, ``store.items``; ``store.participants()`` (list of
  :class:`Participant`: id, position, order row, group, systems in order, factor levels),
  ``store.participant(pid)``.
* Runs: one :class:`~rapidds.store.RunStore` run per participant x system. ``store.config_for(
  pid, system)`` is its RunConfig (human = pid, adapt = system, cycles = rounds, seed from the
  study seed and the participant), ``store.run_id(pid, system)`` its id, ``store.study_runs()``
  the (run_id, participant, system, block) table. Rounds are written by
  :class:`~rapidds.loop.run.AdaptiveRun` attached to this store (``record_cycle``, which here
  also refuses a round that is not the participant's next step) or, for a simulated trial, all
  at once with ``record_trial``. ``store.rounds_done(pid, system)``.
* ``store.next_step(pid)`` -> :class:`Step` (``round`` k of a system, its ``survey``, then
  ``ranking``, ``demographics``, ``done``): computed from what is stored, so it can never
  disagree with the data, and a server restarted at any moment resumes exactly there.
  ``store.progress()``: every participant's next step.
* ``store.submit_survey(pid, system, answers)``, ``store.submit_ranking(pid, ranking)`` (a
  permutation of the systems, best first), ``store.submit_demographics(pid, fields)``: validated
  with pydantic (Likert 1..7, every item answered once, ranking a permutation, free text fields)
  and allowed only as the participant's next step; the identical submit again (a browser
  re-posting) changes nothing and returns False. Bad input raises StudyDataError, a submit out
  of turn StateError, each with one line. The forms themselves (survey items, what a well
  formed answer is, ``validate_durations``) live in :mod:`~rapidds.experiments.study.forms`
  and are re-exported here.
* Folders: ``create_study(out, design, run, items)`` writes ``out/design.csv`` and
  ``out/study.sqlite`` (refusing a folder that holds a different design);
  ``study_path(out)`` is the store's path.
* Readers: ``store.survey_frame()`` (participant, system, item, value), ``store.rankings()``,
  ``store.demographics()``.
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import pandas as pd

from rapidds.errors import ConfigError, StateError, StudyDataError, StudyDesignError
from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.forms import (
    LIKERT,
    SurveyItem,
    SurveyItems,
    default_items,
    demographic_fields,
    survey_answers,
    validate_durations,
)
from rapidds.experiments.study.systems import ADAPTATION
from rapidds.loop.config import RunConfig
from rapidds.store import DEFAULT_TIMEOUT, RunStore

__all__ = [
    "LIKERT",
    "SEED_STRIDE",
    "Participant",
    "Step",
    "StudyStore",
    "SurveyItem",
    "SurveyItems",
    "check_study",
    "create_study",
    "default_items",
    "study_path",
    "validate_durations",
]

STORE_NAME = "study.sqlite"
DESIGN_NAME = "design.csv"
SEED_STRIDE = 10_000
"""A participant's run seed is ``study seed * SEED_STRIDE + position`` (1-based), the same for
all their systems (common random numbers within a person)."""
STUDY_SCHEMA = 1
_KIND = "rapidds-user-study"

_STUDY_SQL = f"""
CREATE TABLE IF NOT EXISTS study_participants (
    participant TEXT PRIMARY KEY,
    position INTEGER NOT NULL UNIQUE,
    row INTEGER NOT NULL,
    grp TEXT NOT NULL,
    systems TEXT NOT NULL,
    factors TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS study_runs (
    run_id TEXT PRIMARY KEY,
    participant TEXT NOT NULL REFERENCES study_participants(participant),
    system TEXT NOT NULL,
    block INTEGER NOT NULL,
    UNIQUE (participant, system)
);
CREATE TABLE IF NOT EXISTS survey (
    participant TEXT NOT NULL REFERENCES study_participants(participant),
    system TEXT NOT NULL,
    item TEXT NOT NULL,
    value INTEGER NOT NULL CHECK (value BETWEEN {LIKERT[0]} AND {LIKERT[1]}),
    created REAL NOT NULL,
    PRIMARY KEY (participant, system, item)
);
CREATE TABLE IF NOT EXISTS rankings (
    participant TEXT PRIMARY KEY REFERENCES study_participants(participant),
    ranking TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS demographics (
    participant TEXT PRIMARY KEY REFERENCES study_participants(participant),
    fields TEXT NOT NULL,
    created REAL NOT NULL
);
INSERT INTO meta VALUES ('kind', '{_KIND}');
INSERT INTO meta VALUES ('study_schema', '{STUDY_SCHEMA}');
"""
_STUDY_TABLES = frozenset({"study_participants", "study_runs", "survey", "rankings",
                           "demographics"})


# -- the store ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Participant:
    """One participant of the design: ``id`` (P01...), ``position`` (1-based), ``row`` of the
    Williams square, priming ``group`` (e.g. left-fast), ``systems`` in the order used,
    ``factors`` (factor -> level)."""

    id: str
    position: int
    row: int
    group: str
    systems: tuple[str, ...]
    factors: dict[str, str]


@dataclass(frozen=True)
class Step:
    """A participant's next step: ``round`` (0-based ``round`` of ``system``, the ``block``-th
    system they use), ``survey`` of ``system``, ``ranking``, ``demographics`` or ``done``."""

    kind: Literal["round", "survey", "ranking", "demographics", "done"]
    system: str | None = None
    block: int | None = None
    round: int | None = None

    def describe(self) -> str:
        if self.kind == "round":
            return f"round {(self.round or 0) + 1} with system '{self.system}'"
        if self.kind == "survey":
            return f"the survey about system '{self.system}'"
        return {"ranking": "the ranking", "demographics": "the demographics form",
                "done": "nothing (finished)"}[self.kind]


class StudyStore(RunStore):
    """A user study in one SQLite file (a :class:`RunStore` with the study's tables)."""

    KIND: ClassVar[str] = "study store"
    EXTRA_SCHEMA: ClassVar[str] = _STUDY_SQL
    TABLES: ClassVar[frozenset[str]] = RunStore.TABLES | _STUDY_TABLES

    def __init__(self, path: str | Path, *, readonly: bool = False,
                 timeout: float = DEFAULT_TIMEOUT, lock_as: str | None = None):
        super().__init__(path, readonly=readonly, timeout=timeout, lock_as=lock_as)
        self._cache: dict[str, Any] = {}

    @classmethod
    def open_readonly(cls, path: str | Path, *, timeout: float = DEFAULT_TIMEOUT) -> StudyStore:
        return cls(path, readonly=True, timeout=timeout)

    def _check_kind(self, db: sqlite3.Connection) -> None:
        row = db.execute("SELECT value FROM meta WHERE key='kind'").fetchone()
        if row is None or row[0] != _KIND:
            raise StateError(f"{self.path}: not a rapidds study store (a run store without a "
                             "study design)")
        row = db.execute("SELECT value FROM meta WHERE key='study_schema'").fetchone()
        if row is None or row[0] != str(STUDY_SCHEMA):
            raise StateError(f"{self.path}: study schema {row[0] if row else '?'}, this rapidds "
                             f"reads {STUDY_SCHEMA}")

    # -- the design ------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, design: StudyDesign, run: RunConfig,
               items: SurveyItems | None = None, *, lock_as: str | None = None) -> StudyStore:
        """Create (or open) the store at ``path`` holding this design (see :meth:`set_design`)."""
        store = cls(path, lock_as=lock_as)
        try:
            store.set_design(design, run, items)
        except BaseException:
            store.close()
            raise
        return store

    def set_design(self, design: StudyDesign, run: RunConfig,
                   items: SurveyItems | None = None) -> bool:
        """Store the design, the base run settings and the survey items in one transaction:
        True when written, False when this very design is already there; a different one is
        refused. ``run.variant`` must be resolved (the world's name for it), since run ids
        name it."""
        check_study(design, run)
        items = items or default_items()
        base = run.replace(human=None, adapt="full", cycles=design.rounds, seed=0)
        meta = {"design": design.model_dump_json(), "run": base.model_dump_json(),
                "items": items.model_dump_json()}
        table = design.assign()
        with self._tx() as db:
            stored = dict(db.execute(
                "SELECT key, value FROM meta WHERE key IN ('design', 'run', 'items')").fetchall())
            if stored:
                for key, value in meta.items():
                    if json.loads(stored.get(key, "null")) != json.loads(value):
                        raise StateError(
                            f"{self.path} already holds a different study ({key} differs); "
                            "choose another folder or the same settings")
                return False
            db.executemany("INSERT INTO meta VALUES (?, ?)", list(meta.items()))
            for pos, p in enumerate(table.itertuples(index=False), start=1):
                factors = {f: str(getattr(p, f)) for f in design.factors}
                db.execute("INSERT INTO study_participants VALUES (?, ?, ?, ?, ?, ?)",
                           (p.participant, pos, int(p.row), p.group, json.dumps(list(p.order)),
                            json.dumps(factors)))
                for block, system in enumerate(p.order, start=1):
                    cfg = self._config(base, design, p.participant, pos, system)
                    db.execute("INSERT INTO study_runs VALUES (?, ?, ?, ?)",
                               (cfg.run_id, p.participant, system, block))
        self._cache.clear()
        return True

    def _meta(self, key: str) -> str:
        rows = self._rows("SELECT value FROM meta WHERE key=?", (key,))
        if not rows:
            raise StateError(f"{self.path}: the study store holds no design yet "
                             "(run `rapidds study design` first)")
        return str(rows[0][0])

    @property
    def has_design(self) -> bool:
        return bool(self._rows("SELECT 1 FROM meta WHERE key='design'"))

    @property
    def design(self) -> StudyDesign:
        if "design" not in self._cache:
            self._cache["design"] = StudyDesign(**self._json(self._meta("design"), "design"))
        return self._cache["design"]

    @property
    def base_config(self) -> RunConfig:
        """The study's run settings; :meth:`config_for` fills in person, system and seed."""
        if "run" not in self._cache:
            self._cache["run"] = RunConfig(**self._json(self._meta("run"), "run settings"))
        return self._cache["run"]

    @property
    def items(self) -> SurveyItems:
        if "items" not in self._cache:
            self._cache["items"] = SurveyItems.parse(
                self._json(self._meta("items"), "survey items"), f"{self.path} survey items")
        return self._cache["items"]

    @staticmethod
    def _config(base: RunConfig, design: StudyDesign, pid: str, position: int,
                system: str) -> RunConfig:
        return base.replace(human=pid, adapt=system, cycles=design.rounds,
                            seed=design.seed * SEED_STRIDE + position)

    def participants(self) -> list[Participant]:
        if "participants" not in self._cache:
            self._meta("design")
            self._cache["participants"] = [
                Participant(pid, pos, row, grp, tuple(json.loads(systems)), json.loads(factors))
                for pid, pos, row, grp, systems, factors in self._rows(
                    "SELECT participant, position, row, grp, systems, factors "
                    "FROM study_participants ORDER BY position")]
        return list(self._cache["participants"])

    def participant(self, pid: str) -> Participant:
        for p in self.participants():
            if p.id == pid:
                return p
        ids = [p.id for p in self.participants()]
        raise StudyDataError(f"no participant '{pid}' in this study "
                             f"({ids[0]}..{ids[-1]})" if ids else f"no participant '{pid}'")

    def _system_of(self, p: Participant, system: str) -> int:
        if system not in p.systems:
            raise StudyDataError(f"{p.id}: no system '{system}'; the study's systems are "
                                 f"{', '.join(p.systems)}")
        return p.systems.index(system) + 1

    def config_for(self, pid: str, system: str) -> RunConfig:
        """The RunConfig of participant ``pid`` with ``system`` (attach an AdaptiveRun with it)."""
        p = self.participant(pid)
        self._system_of(p, system)
        return self._config(self.base_config, self.design, p.id, p.position, system)

    def run_id(self, pid: str, system: str) -> str:
        return self.config_for(pid, system).run_id

    def study_runs(self) -> pd.DataFrame:
        """run_id, participant, system, block (1 = the first system they used)."""
        return pd.DataFrame(self._rows(
            "SELECT run_id, participant, system, block FROM study_runs "
            "ORDER BY participant, block"), columns=["run_id", "participant", "system", "block"])

    # -- progress ----------------------------------------------------------------------------
    def rounds_done(self, pid: str, system: str) -> int:
        (n,) = self._rows("SELECT COUNT(*) FROM cycles WHERE run_id=?",
                          (self.run_id(pid, system),))[0]
        return int(n)

    def _next_step(self, db: sqlite3.Connection, p: Participant) -> Step:
        rounds = self.design.rounds
        done = dict(db.execute(
            "SELECT r.system, COUNT(c.cycle) FROM study_runs r LEFT JOIN cycles c "
            "ON c.run_id = r.run_id WHERE r.participant=? GROUP BY r.system", (p.id,)).fetchall())
        answered = {s for (s,) in db.execute(
            "SELECT DISTINCT system FROM survey WHERE participant=?", (p.id,)).fetchall()}
        for block, system in enumerate(p.systems, start=1):
            if done.get(system, 0) < rounds:
                return Step("round", system, block, int(done.get(system, 0)))
            if system not in answered:
                return Step("survey", system, block)
        if not db.execute("SELECT 1 FROM rankings WHERE participant=?", (p.id,)).fetchone():
            return Step("ranking")
        if not db.execute("SELECT 1 FROM demographics WHERE participant=?", (p.id,)).fetchone():
            return Step("demographics")
        return Step("done")

    def next_step(self, pid: str) -> Step:
        """What participant ``pid`` does next (resume point), from what is stored."""
        p = self.participant(pid)
        try:
            return self._next_step(self._db, p)
        except sqlite3.Error as exc:
            raise self._failure(exc) from None

    def progress(self) -> dict[str, Step]:
        return {p.id: self.next_step(p.id) for p in self.participants()}

    def _before_cycle(self, db: sqlite3.Connection, run_id: str, cycle: int) -> None:
        row = db.execute("SELECT participant, system FROM study_runs WHERE run_id=?",
                         (run_id,)).fetchone()
        if row is None:
            raise StateError(f"run '{run_id}' is not a run of the study in {self.path}")
        p = self.participant(row[0])
        step = self._next_step(db, p)
        if step != Step("round", row[1], p.systems.index(row[1]) + 1, cycle):
            raise StateError(f"{p.id}: the next step is {step.describe()}, not round "
                             f"{cycle + 1} with system '{row[1]}'")

    def _submit(self, p: Participant, step: Step, table: str, rows: list[tuple[Any, ...]],
                same: str, args: tuple[Any, ...], stored_as: Any) -> bool:
        """Insert ``rows`` in one transaction if ``step`` is the participant's next one; an
        identical earlier submit (``same`` query finds ``stored_as``) is a no-op."""
        with self._tx() as db:
            found = db.execute(same, args).fetchall()
            if found:
                if found == stored_as:
                    return False
                raise StateError(f"{p.id}: {step.describe()} was already submitted with other "
                                 "answers; a submit is final")
            now = self._next_step(db, p)
            if now != step:
                raise StateError(f"{p.id}: the next step is {now.describe()}, not "
                                 f"{step.describe()}")
            stamp = time.time()
            db.executemany(f"INSERT INTO {table} VALUES ({', '.join('?' * (len(rows[0]) + 1))})",
                           [(*r, stamp) for r in rows])
        return True

    def submit_survey(self, pid: str, system: str, answers: Mapping[str, Any]) -> bool:
        """The participant's survey about ``system``: every item answered once, 1..7."""
        p = self.participant(pid)
        block = self._system_of(p, system)
        got = survey_answers(answers, self.items.ids, f"{p.id} survey about '{system}'")
        rows = [(p.id, system, i, v) for i, v in got.items()]
        return self._submit(
            p, Step("survey", system, block), "survey", rows,
            "SELECT participant, system, item, value FROM survey WHERE participant=? AND "
            "system=? ORDER BY item", (p.id, system), sorted(rows, key=lambda r: r[2]))

    def submit_ranking(self, pid: str, ranking: Sequence[str]) -> bool:
        """The forced-choice ranking, best first: a permutation of the study's systems."""
        p = self.participant(pid)
        ranked = [str(s) for s in ranking]
        if sorted(ranked) != sorted(p.systems):
            raise StudyDataError(f"{p.id} ranking: must name each of {', '.join(p.systems)} "
                                 f"exactly once, got {', '.join(ranked) or 'nothing'}")
        text = json.dumps(ranked)
        return self._submit(p, Step("ranking"), "rankings", [(p.id, text)],
                            "SELECT participant, ranking FROM rankings WHERE participant=?",
                            (p.id,), [(p.id, text)])

    def submit_demographics(self, pid: str, fields: Mapping[str, Any]) -> bool:
        """Free fields (age, handedness, ...), text; an empty form is a valid answer."""
        p = self.participant(pid)
        text = json.dumps(demographic_fields(fields, f"{p.id} demographics"))
        return self._submit(p, Step("demographics"), "demographics", [(p.id, text)],
                            "SELECT participant, fields FROM demographics WHERE participant=?",
                            (p.id,), [(p.id, text)])

    # -- reading back ----------------------------------------------------------------------
    def survey_frame(self) -> pd.DataFrame:
        """participant, system, item, value: every stored answer."""
        return pd.DataFrame(self._rows(
            "SELECT participant, system, item, value FROM survey ORDER BY participant, system, "
            "item"), columns=["participant", "system", "item", "value"])

    def rankings(self) -> dict[str, tuple[str, ...]]:
        """participant -> systems, best first."""
        return {pid: tuple(self._json(r, f"ranking of {pid}")) for pid, r in self._rows(
            "SELECT participant, ranking FROM rankings ORDER BY participant")}

    def demographics(self) -> dict[str, dict[str, str]]:
        return {pid: self._json(f, f"demographics of {pid}") for pid, f in self._rows(
            "SELECT participant, fields FROM demographics ORDER BY participant")}


def check_study(design: StudyDesign, run: RunConfig) -> None:
    """What a design must satisfy to be stored with these run settings (before any file is
    made): systems the loop knows, a resolved variant, seeds that do not overlap."""
    unknown = [s for s in design.systems if s not in ADAPTATION]
    if unknown:
        raise StudyDesignError(f"system(s) {', '.join(unknown)} unknown; a study compares "
                               f"{', '.join(ADAPTATION)}")
    if run.variant is None:
        raise ConfigError("the study's run settings need the world's variant resolved "
                          "(RunConfig.resolved(world))")
    if design.participants >= SEED_STRIDE:
        raise StudyDesignError(f"at most {SEED_STRIDE - 1} participants")


def study_path(out: str | Path) -> Path:
    """The study store of folder ``out``."""
    return Path(out) / STORE_NAME


def create_study(out: str | Path, design: StudyDesign, run: RunConfig,
                 items: SurveyItems | None = None, *, lock_as: str | None = None) -> StudyStore:
    """Folder ``out`` with this study: ``design.csv`` (the assignment table, for the
    experimenter) and ``study.sqlite``; a folder holding another design is refused before
    anything is written, the same design is opened as it is. Returns the open store."""
    check_study(design, run)
    out = Path(out)
    csv = out / DESIGN_NAME
    if csv.exists():
        try:
            there = StudyDesign.from_csv(csv)
        except StudyDesignError as exc:
            raise StateError(f"{csv} exists and is not this study's design ({exc})") from None
        if there != design:
            raise StateError(f"{out} already holds a different study design ({csv}); choose "
                             "another --out or the same settings")
    store = StudyStore.create(study_path(out), design, run, items, lock_as=lock_as)
    try:
        if not csv.exists():
            design.to_csv(csv)
    except BaseException:
        store.close()
        raise
    return store
