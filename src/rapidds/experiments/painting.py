"""The paper's painting case study: its four settings (unconstrained gamma 12, constrained
gamma 12, unconstrained gamma 25 and 85), each one run of the loop with full adaptation, and
the table the paper's text reads: per cycle the robot's sequence with waits, which mix overlaps
Secure Piece, the chosen motions' modes and durations, expected and realised spatial cost,
minimum separation, who brushes, and whether the paper's behaviour shows
(:mod:`rapidds.worlds.painting.cycles`).

Each setting is a :class:`~rapidds.loop.config.RunConfig`; the CLI runs it resumably in its own
folder (``DIR/<setting>/run.sqlite``: the run id does not name gamma, so settings cannot share
a store), and :func:`run_setting` runs it in memory (benchmarks, tests).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rapidds.errors import RapiddsError
from rapidds.loop.config import RunConfig
from rapidds.record import CycleRecord
from rapidds.worlds.painting.cycles import (
    LoopBehaviour,
    faster_brusher,
    loop_behaviours,
    summarize_record,
)

if TYPE_CHECKING:
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.worlds.painting.world import PaintingWorld

__all__ = [
    "SETTINGS",
    "Setting",
    "expectations",
    "run_setting",
    "setting_behaviours",
    "table_csv",
    "table_markdown",
    "table_rows",
]


@dataclass(frozen=True)
class Setting:
    """One of the paper's settings: the job's variant and the proximity weight."""

    variant: str
    gamma: float

    @property
    def name(self) -> str:
        return f"{self.variant}-g{self.gamma:g}"

    def config(self, human: str, seed: int, cycles: int, execution: str = "planned",
               **search: Any) -> RunConfig:
        """The run of this setting: full adaptation, the world's lambda, ``search`` settings;
        ``execution`` "reactive" for the reactive column (the paper's robot: "planned")."""
        return RunConfig(world="painting", variant=self.variant, human=human, adapt="full",
                         cycles=cycles, gamma=self.gamma, seed=seed, execution=execution,
                         **search)


SETTINGS: tuple[Setting, ...] = (Setting("unconstrained", 12.0), Setting("constrained", 12.0),
                                 Setting("unconstrained", 25.0), Setting("unconstrained", 85.0))


def expectations(world: PaintingWorld, human: str) -> tuple[str, str]:
    """(near mix, faster brusher) for a teammate: the mix whose tray their Secure Piece hand
    passes, and the agent whose true mean brushing is shorter."""
    person = world.teammate(human)
    near = "mix_l" if person.hand == "left" else "mix_r"
    robot = world.robot_duration("brush", world.robot_trajectory("brush"))
    return near, faster_brusher(person.true_mean_durations()["brush"], robot)


def setting_behaviours(world: PaintingWorld, setting: Setting, human: str,
                       records: Sequence[CycleRecord]) -> list[LoopBehaviour]:
    """The paper's behaviours of ``setting`` tested on a run's records, with Brush going to
    the faster agent in the unconstrained gamma 12 setting (the paper's temporal claim)."""
    near, brusher = expectations(world, human)
    brush = brusher if setting == SETTINGS[0] else None
    return loop_behaviours(records, setting.variant, setting.gamma, near, brush)


def run_setting(setting: Setting, human: str, seed: int, cycles: int = 7,
                policy: DiffusionPolicy | None = None, **search: Any) -> list[CycleRecord]:
    """The records of one run of ``setting`` in memory (no store)."""
    from rapidds.loop.run import AdaptiveRun

    return AdaptiveRun(setting.config(human, seed, cycles, **search), policy).run()


_COLUMNS = ("setting", "cycle", "lambda", "robot", "person", "first mix",
            "mix during Secure Piece (planned)", "mix during Secure Piece (realised)",
            "motions (mode, s)", "waits", "brush", "exp. spatial", "real. spatial",
            "min sep. (m)", "makespan (s)", "behaviour")
# the same setting with --execution reactive, its cycle beside the paper's
_REACTIVE = ("reactive makespan (s)", "reactive min sep. (m)", "reactive pauses/replans")


def _columns(rows: Sequence[Mapping[str, str]]) -> tuple[str, ...]:
    return _COLUMNS + _REACTIVE if rows and _REACTIVE[0] in rows[0] else _COLUMNS


def _reactive_cells(rec: CycleRecord | None) -> dict[str, str]:
    """The reactive column of one cycle, read from the reactive run's stored record."""
    if rec is None:
        return dict.fromkeys(_REACTIVE, "-")
    real, ic = rec.realised, rec.execution.in_cycle
    acts = f"{len(ic.pauses)}/{len(ic.replans)}" if ic is not None else "-"
    return {_REACTIVE[0]: f"{real.makespan:.2f}", _REACTIVE[1]: f"{real.min_separation:.3f}",
            _REACTIVE[2]: acts}


def table_rows(world: PaintingWorld, human: str,
               runs: Mapping[Setting, Sequence[CycleRecord]],
               reactive: Mapping[Setting, Sequence[CycleRecord]] | None = None
               ) -> list[dict[str, str]]:
    """One row per setting per cycle; "behaviour" names the paper's behaviours tested on that
    cycle with yes/no (empty on exploration cycles after the first). ``reactive``: the same
    settings' runs with ``--execution reactive``, whose cycles fill the reactive columns."""
    rows = []
    for setting, records in runs.items():
        react = None if reactive is None else {
            r.cycle: r for r in reactive.get(setting, ())}
        tested = setting_behaviours(world, setting, human, records)
        for rec in records:
            s = summarize_record(rec)
            verdicts = [f"{b.name}: {'yes' if s.cycle in b.shown else 'no'}"
                        for b in tested if s.cycle in b.cycles]
            rows.append({
                "setting": setting.name, "cycle": str(s.cycle), "lambda": f"{s.lam:g}",
                "robot": " ".join(s.plan.robot), "person": " ".join(s.plan.human),
                "first mix": s.plan.first,
                "mix during Secure Piece (planned)": " ".join(
                    f"{j} {m}" for j, m in s.plan.during.items()) or "-",
                "mix during Secure Piece (realised)": " ".join(s.during_realised) or "-",
                "motions (mode, s)": " ".join(f"{j} {s.modes[j][0]} {s.durations[j]:.2f}"
                                              for j in s.modes),
                "waits": "; ".join(s.waits) or "-", "brush": s.brusher,
                "exp. spatial": f"{s.expected_spatial:.3f}",
                "real. spatial": f"{s.realised_spatial:.3f}",
                "min sep. (m)": f"{s.min_separation:.3f}", "makespan (s)": f"{s.makespan:.2f}",
                "behaviour": "; ".join(verdicts),
                **({} if react is None else _reactive_cells(react.get(s.cycle))),
            })
    return rows


def table_markdown(rows: Sequence[Mapping[str, str]]) -> str:
    """The rows as a Markdown table (``|`` in cells escaped)."""
    cols = _columns(rows)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(r[c].replace("|", "\\|") for c in cols) + " |")
    return "\n".join(lines) + "\n"


def table_csv(rows: Sequence[Mapping[str, str]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=_columns(rows), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def check_setting_names(names: Sequence[str]) -> tuple[Setting, ...]:
    """The settings named (``unconstrained-g12`` ...); an unknown name is a one-line error."""
    known = {s.name: s for s in SETTINGS}
    bad = [n for n in names if n not in known]
    if bad:
        raise RapiddsError(f"unknown painting setting(s) {', '.join(bad)}; settings are "
                           f"{', '.join(known)}")
    return tuple(known[n] for n in names)


def write_tables(out: Path, rows: Sequence[Mapping[str, str]]) -> tuple[Path, Path]:
    """table.md and table.csv in ``out``, each written atomically."""
    from rapidds.fileio import atomic_write_text

    md, cs = out / "table.md", out / "table.csv"
    atomic_write_text(md, table_markdown(rows))
    atomic_write_text(cs, table_csv(rows))
    return md, cs


# -- pictures ---------------------------------------------------------------------------------

def cell_state(world: PaintingWorld, record: CycleRecord,
               arrays: Mapping[str, Any], t: float) -> tuple[Any, Any]:
    """((7,) arm joints, (4, 3) body points) at time ``t`` of a stored cycle: the row of the
    robot motion / human task running then (a motion's rows are ``world.dt`` apart, a finished
    one leaves the arm at rest), rest otherwise."""
    import numpy as np

    from rapidds.store import cycle_paths

    times = record.realised.timeline
    q, body = world.robot_rest(), world.human_rest()
    for kind, paths in cycle_paths(arrays).items():
        for task, arr in sorted(paths.items()):
            start, finish = times[task]
            if not start <= t <= finish:
                continue
            a = np.asarray(arr, dtype=float)
            row = min(round((t - start) / world.dt), len(a) - 1)
            if kind == "robot":
                q = a[row]
            else:
                body = a[row].reshape(-1, 3)
    return q, body


def secure_piece_moment(world: PaintingWorld, record: CycleRecord,
                        arrays: Mapping[str, Any]) -> float:
    """The time in Secure Piece when the arm comes closest to the person's hands (its middle
    when no arm motion runs then): the moment the paper's behaviours are about."""
    import numpy as np

    start, finish = record.realised.timeline["secure_piece"]
    best_t, best_d = (start + finish) / 2, np.inf
    for t in np.arange(start, finish, world.dt):
        q, body = cell_state(world, record, arrays, float(t))
        if np.allclose(q, world.robot_rest()):
            continue
        d = float(np.linalg.norm(world.robot_points(q[None])[0][:, None] - body[None],
                                 axis=-1).min())
        if d < best_d:
            best_t, best_d = float(t), d
    return best_t


def save_frames(world: PaintingWorld, record: CycleRecord, arrays: Mapping[str, Any],
                prefix: Path) -> list[Path]:
    """MuJoCo renderings (overview and top cameras) of the cell at :func:`secure_piece_moment`;
    none where no offscreen OpenGL backend works (the matplotlib maps stand in for them)."""
    from rapidds.plots._mpl import plt, save
    from rapidds.worlds.painting.render import RenderError, render_cell

    t = secure_piece_moment(world, record, arrays)
    q, body = cell_state(world, record, arrays, t)
    out = []
    for camera in ("overview", "top"):
        try:
            img = render_cell(q, body, camera=camera, layout=world.layout)
        except RenderError:
            return out
        fig, ax = plt.subplots(figsize=(4.8, 3.6))
        ax.imshow(img)
        ax.set_axis_off()
        ax.set_title(f"cycle {record.cycle}, t = {t:.1f} s (Secure Piece)", fontsize=9)
        fig.tight_layout()
        out.append(save(fig, prefix.with_name(f"{prefix.name}-frame-{camera}.png")))
    return out


def save_cycle_gif(world: PaintingWorld, record: CycleRecord, arrays: Mapping[str, Any],
                   path: Path, view: str = "top", step: float = 0.3) -> Path:
    """A matplotlib animation of one stored cycle seen from ``view``: the arm's points and the
    person's hands and elbows every ``step`` seconds, with the task running at each moment."""
    import numpy as np
    from matplotlib.animation import FuncAnimation, PillowWriter

    from rapidds.fileio import atomic_write_bytes
    from rapidds.plots._mpl import plt

    h, v = world.views[view]
    times = record.realised.timeline
    end = max(f for _, f in times.values())
    fig, ax = plt.subplots(figsize=(4.2, 3.8))
    world.draw(ax, view)
    lo, hi = world.workspace_bounds
    ax.set_xlim(lo[h], hi[h])
    ax.set_ylim(lo[v], hi[v])
    (arm,) = ax.plot([], [], "-o", color="tab:blue", ms=2, lw=2, zorder=5)
    (hands,) = ax.plot([], [], "o", color="gold", ms=6, mec="k", zorder=6)
    (forearms,) = ax.plot([], [], "-", color="gold", lw=3, zorder=5)
    label = ax.set_title("", fontsize=8)

    def frame(t: float) -> tuple[Any, ...]:
        q, body = cell_state(world, record, arrays, t)
        pts = world.robot_points(q[None])[0]
        arm.set_data(pts[:, h], pts[:, v])
        hands.set_data(body[:2, h], body[:2, v])
        seg = np.array([body[2], body[0], [np.nan] * 3, body[3], body[1]])
        forearms.set_data(seg[:, h], seg[:, v])
        running = [task for task, (s, f) in times.items() if s <= t < f]
        label.set_text(f"cycle {record.cycle}  t = {t:4.1f} s  {' '.join(running)}")
        return arm, hands, forearms, label

    anim = FuncAnimation(fig, frame, frames=list(np.arange(0.0, end + step, step)), blit=False)
    tmp = path.with_name(f".{path.name}.tmp.gif")
    anim.save(tmp, writer=PillowWriter(fps=round(1 / step)))
    plt.close(fig)
    atomic_write_bytes(path, tmp.read_bytes())
    tmp.unlink()
    return path
