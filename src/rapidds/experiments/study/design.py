"""Counterbalancing for the user study: Williams squares, orders per participant, priming groups.

Every participant uses every system once, in the order of one row of a balanced Latin square
(Williams 1949): for an even number of systems one square, for an odd number the square and its
mirror, so that each system immediately follows each other system equally often across the rows
(first-order carry-over balanced). Participants are also split into priming groups, the
factorial of named factors (by default hand for Secure Piece x brushing speed).

Balance: each (order row, priming group) pair is one *cell*; participants are dealt the cells in
permuted blocks, one block = every cell once, in an order the seed shuffles. So every complete
block is balanced on its own (a study stopped after 16 of 32 participants is still balanced), and
the seed changes which participant gets which cell, never how often a cell occurs. A participant
count that is not a multiple of the block is refused unless ``require_balance=False``; then the
last block is cut from a cell sequence whose every prefix keeps the rows, and the groups, within
one participant of each other, and :attr:`StudyDesign.balanced` says False.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    field_validator,
    model_serializer,
    model_validator,
)

from rapidds.errors import StudyDesignError
from rapidds.experiments.study.systems import SYSTEMS
from rapidds.fileio import atomic_write_text
from rapidds.settings import error_line
from rapidds.worlds.bounds import world_task_bound
from rapidds.worlds.capabilities import capability

if TYPE_CHECKING:
    from rapidds.worlds.base import World

HEADER = "# rapidds study design: "
"""First line of a design CSV; the design's JSON follows it on the same line."""
TABLE_COLUMNS: tuple[str, ...] = ("participant", "row", "order", "group")
"""Columns of :meth:`StudyDesign.assign` before the one column per priming factor."""
_NAME = r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$"  # no separators: names go into CSV cells and group names
_ORDER_SEP = ";"
MAX_TASK_S_LIMIT = 3600.0
"""The largest ``max_task_s`` a design may set: an hour, far beyond a task of any world here,
and still a small path (24 000 rows at painting's dt)."""


def priming_factors(world: World) -> dict[str, tuple[str, ...]]:
    """The priming factors of a study on ``world``: its ``priming`` capability's (factors
    whose factorial names its simulated teammates, painting ``left-fast`` ..., fetch
    ``fast-middle`` ..., so a group's simulated cell and typed-in rounds have a person to act),
    else one factor ``teammate`` whose levels are the world's simulated teammates."""
    own = capability(world, "priming")
    return dict(own.priming_factors if own else {"teammate": tuple(world.teammate_names)})


def williams_square(n: int) -> list[tuple[int, ...]]:
    """Rows of a Williams design for ``n`` conditions, numbered 0..n-1.

    n rows for even n, 2n for odd n (the square and its mirror). Each condition appears once
    per row and equally often at each position, and each ordered pair (a, b) of conditions
    occurs as neighbours (b right after a) equally often: once for even n, twice for odd n.
    """
    if n < 2:
        raise StudyDesignError(f"a Williams square needs at least 2 conditions, got {n}")
    # first row 0, 1, n-1, 2, n-2, ...: its successive differences are all distinct mod n
    first = [0] + [(j + 1) // 2 if j % 2 else n - j // 2 for j in range(1, n)]
    rows = [tuple((c + r) % n for c in first) for r in range(n)]
    if n % 2:
        rows += [row[::-1] for row in rows]
    return rows


def cell_sequence(rows: int, groups: int) -> list[tuple[int, int]]:
    """All ``rows x groups`` (row, group) cells, ordered so that every prefix keeps the row
    counts within one of each other and the group counts within one of each other.

    Rows cycle; groups cycle too, shifted by one after every lcm(rows, groups) cells, which
    after gcd(rows, groups) such runs has visited every pair.
    """
    run = math.lcm(rows, groups)
    return [(k % rows, (k + k // run) % groups) for k in range(rows * groups)]


class StudyDesign(BaseModel):
    """A counterbalanced within-subject study: who uses which systems in which order, and who is
    primed how. Invalid or impossible designs raise :class:`~rapidds.errors.StudyDesignError`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    participants: int = Field(32, ge=1, strict=True, description="number of participants")
    systems: tuple[str, ...] = Field(SYSTEMS, min_length=2, description="systems to compare")
    rounds: int = Field(7, ge=1, strict=True, description="rounds (task cycles) per system")
    factors: dict[str, tuple[str, ...]] = Field(
        default_factory=lambda: {"hand": ("left", "right"), "speed": ("fast", "slow")},
        description="priming factors and their levels; the groups are their factorial",
    )
    seed: int = Field(0, strict=True, description="which participant gets which cell")
    require_balance: bool = Field(
        True, description="refuse participant counts that cannot balance rows x groups"
    )
    max_task_s: float | None = Field(
        None, gt=0, le=MAX_TASK_S_LIMIT, allow_inf_nan=False,
        description="longest a person's task may take, seconds (None: the world's bound, "
        "world_task_bound)",
    )
    comfort: bool = Field(
        False, strict=True,
        description="ask the comfort item on every round page (\"the robot came too close to "
        "me\", 1-7, and a 'too close' button); its evidence goes to the run's gamma learner",
    )

    @model_serializer(mode="wrap")
    def _without_unset_bound(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """An unset ``max_task_s`` and an unasked comfort item are left out, so a design stored
        before those fields existed reads back, and compares, exactly as before."""
        data = handler(self)
        if data.get("max_task_s") is None:
            data.pop("max_task_s", None)
        if not data.get("comfort"):
            data.pop("comfort", None)
        return data

    def task_bound(self, world: World) -> float:
        """Seconds a person's task may take in this study: ``max_task_s`` or the world's."""
        return self.max_task_s if self.max_task_s is not None else world_task_bound(world)

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise StudyDesignError(f"study design: {error_line(exc)}") from None

    @field_validator("systems")
    @classmethod
    def _systems_named_once(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        _check_names(v, "system")
        return v

    @field_validator("factors")
    @classmethod
    def _factors_valid(cls, v: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
        _check_names(tuple(v), "factor")
        for name, levels in v.items():
            if name in TABLE_COLUMNS:
                raise ValueError(f"factor '{name}' would clash with the table column of that name")
            if not levels:
                raise ValueError(f"factor '{name}' has no levels")
            _check_names(levels, f"level of factor '{name}'")
        return v

    @model_validator(mode="after")
    def _balanced_if_required(self) -> StudyDesign:
        if self.require_balance and not self.balanced:
            n, rows, groups = self.participants, len(self.square()), len(self.groups())
            block = rows * groups
            lower, upper = n // block * block, (n // block + 1) * block
            near = f"{lower} or {upper}" if lower else f"{upper}"
            why = "a Williams square and its mirror" if len(self.systems) % 2 else "Williams"
            raise ValueError(
                f"{n} participants cannot balance {rows} order rows ({why}, {len(self.systems)}"
                f" systems) x {groups} priming groups: every (row, group) pair must occur"
                f" equally often, so participants must be a multiple of {block} (e.g. {near});"
                " --allow-unbalanced (require_balance=False) accepts near-balance"
            )
        return self

    # --- the design ---------------------------------------------------------------------------

    def square(self) -> list[tuple[str, ...]]:
        """The order rows: a Williams square over :attr:`systems` (row 0 starts with the first)."""
        return [tuple(self.systems[i] for i in row) for row in williams_square(len(self.systems))]

    def groups(self) -> list[tuple[str, ...]]:
        """Priming groups: one level per factor, factorial in the order of :attr:`factors`."""
        return list(itertools.product(*self.factors.values()))

    def group_name(self, levels: tuple[str, ...]) -> str:
        return "-".join(levels) if levels else "all"

    @property
    def block_size(self) -> int:
        """Participants per balanced block: order rows x priming groups."""
        return len(self.square()) * len(self.groups())

    @property
    def balanced(self) -> bool:
        """Whether every (order row, priming group) pair occurs equally often."""
        return self.participants % self.block_size == 0

    def assign(self) -> pd.DataFrame:
        """One row per participant: ``participant`` (P01...), ``row`` (index into
        :meth:`square`), ``order`` (tuple of systems, first used first), ``group`` (e.g.
        ``left-fast``) and one column per priming factor. Deterministic for the seed."""
        square, groups = self.square(), self.groups()
        cells = cell_sequence(len(square), len(groups))
        rng = np.random.default_rng(self.seed)
        dealt: list[tuple[int, int]] = []
        for start in range(0, self.participants, len(cells)):
            block = cells[: min(len(cells), self.participants - start)]
            dealt += [block[i] for i in rng.permutation(len(block))]
        width = max(2, len(str(self.participants)))
        records = []
        for k, (row, g) in enumerate(dealt):
            levels = groups[g]
            records.append(
                {
                    "participant": f"P{k + 1:0{width}d}",
                    "row": row,
                    "order": square[row],
                    "group": self.group_name(levels),
                    **dict(zip(self.factors, levels, strict=True)),
                }
            )
        return pd.DataFrame.from_records(records, columns=[*TABLE_COLUMNS, *self.factors])

    def sessions(self) -> pd.DataFrame:
        """The run sheet: one row per participant, block (1 = first system used) and round."""
        table = self.assign()
        rows = [
            {
                "participant": p.participant,
                "group": p.group,
                "block": b + 1,
                "system": system,
                "round": r + 1,
            }
            for p in table.itertuples(index=False)
            for b, system in enumerate(p.order)
            for r in range(self.rounds)
        ]
        return pd.DataFrame.from_records(
            rows, columns=["participant", "group", "block", "system", "round"]
        )

    # --- files ----------------------------------------------------------------------------------

    def to_csv(self, path: str | Path) -> None:
        """Write the assignment table, with the design as JSON on a first comment line
        (atomically: a crash leaves the old file or the new one)."""
        atomic_write_text(path, HEADER + self.model_dump_json() + "\n" + _table_csv(self.assign()))

    @classmethod
    def from_csv(cls, path: str | Path) -> StudyDesign:
        """Read a file written by :meth:`to_csv`. The table must be exactly the one its design
        generates: a file edited by hand is refused rather than silently regenerated."""
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise StudyDesignError(f"{path}: cannot read: {exc.strerror or exc}") from None
        header, _, body = text.partition("\n")
        if not header.startswith(HEADER):
            raise StudyDesignError(f"{path}: first line must start with '{HEADER.strip()}'")
        try:
            raw = json.loads(header.removeprefix(HEADER))
        except json.JSONDecodeError as exc:
            raise StudyDesignError(f"{path}: design header is not valid JSON: {exc.msg}") from None
        if not isinstance(raw, dict):
            raise StudyDesignError(f"{path}: design header must be a JSON object")
        try:
            design = cls(**raw)
        except StudyDesignError as exc:
            raise StudyDesignError(f"{path}: {exc}") from None
        expected = _table_csv(design.assign())
        if body != expected:
            got, want = body.splitlines(), expected.splitlines()
            line = next(
                (i for i, (a, b) in enumerate(zip(got, want, strict=False)) if a != b),
                min(len(got), len(want)),
            )
            raise StudyDesignError(
                f"{path}: line {line + 2} differs from the assignment its design header generates"
                " (edited by hand, or written by another version)"
            )
        return design


def _table_csv(table: pd.DataFrame) -> str:
    return table.assign(order=table["order"].map(_ORDER_SEP.join)).to_csv(index=False)


def _check_names(names: tuple[str, ...], what: str) -> None:
    for name in names:
        if not re.match(_NAME, name):
            raise ValueError(
                f"{what} '{name}' must be letters, digits, '_', '.', '+' or '-' (no separators)"
            )
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f"{what} named twice: {', '.join(dupes)}")
