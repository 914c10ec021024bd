"""The study app's HTML: one page per step of a participant's session, plus the experimenter's
overview. Plain server-rendered HTML (every value escaped), one stylesheet and one script
(``static/``), no build step. The participant sees systems by the order they used them
("system 2 of 4"), never by name: the names are on the experimenter's overview only.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

from rapidds.schedule import Timeline, Wait, parse_item, task_items

__all__ = [
    "comfort_fieldset",
    "demographics_page",
    "done_page",
    "gantt_svg",
    "message_page",
    "overview_page",
    "page",
    "ranking_page",
    "round_page",
    "survey_page",
]

LIKERT = ("Strongly disagree", "Disagree", "Somewhat disagree", "Neutral", "Somewhat agree",
          "Agree", "Strongly agree")
"""Labels of the 7 points (1..7)."""
COMFORT_ITEM = "The robot came too close to me"
"""The comfort item of a round (agreement 1-7), asked when the design's ``comfort`` is on."""

DEMOGRAPHICS: tuple[tuple[str, str, str], ...] = (
    ("age", "Age (years)", "number"),
    ("gender", "Gender", "text"),
    ("handedness", "Dominant hand (left / right / both)", "text"),
    ("robot_experience", "Experience with robots (none, some, a lot)", "text"),
    ("comments", "Anything else you want to tell us", "text"),
)
"""The demographics form's fields: name, label, input type; all optional free fields."""


def e(x: object) -> str:
    return escape(str(x), quote=True)


def page(title: str, where: str, body: str) -> str:
    return (
        "<!doctype html><html lang=en><head><meta charset=utf-8>"
        "<meta name=viewport content='width=device-width, initial-scale=1'>"
        f"<title>{e(title)} · rapidds study</title>"
        "<link rel=stylesheet href='/static/study.css'>"
        "<script src='/static/study.js' defer></script></head><body>"
        # no link to the overview: it names each participant's systems (the blind)
        f"<header><span class=brand>rapidds study</span><span class=where>{where}</span>"
        "</header>"
        f"<main>{body}</main></body></html>")


def _form(api: str, step: str, inner: str, button: str, busy: str = "saving…") -> str:
    return (f"<form novalidate data-api='{e(api)}' data-step='{e(step)}' data-busy='{e(busy)}'>"
            f"{inner}"
            f"<div><button type=submit>{e(button)}</button><span class=busy></span></div>"
            "<p class=error role=alert></p></form>")


def gantt_svg(timeline: Timeline, title: str = "") -> str:
    """The plan's expected timeline as a Gantt chart (:func:`rapidds.plots.gantt.plot_gantt`),
    an SVG in a data URI for an ``<img>``."""
    from rapidds.plots._mpl import plt
    from rapidds.plots.gantt import plot_gantt

    ax = plot_gantt(timeline, title=title)
    buf = io.BytesIO()
    ax.figure.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(ax.figure)
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def where(pid: str, block: int | None = None, blocks: int | None = None,
          round_: int | None = None, rounds: int | None = None) -> str:
    parts = [f"participant <b>{e(pid)}</b>"]
    if block is not None:
        parts.append(f"system {block} of {blocks}")
    if round_ is not None:
        parts.append(f"round {round_} of {rounds}")
    return " · ".join(parts)


def _likert_head() -> str:
    """The header cells of a 1-7 agreement row (the survey's and the comfort item's)."""
    return "".join(f"<th>{i + 1}<br>{e(lab)}</th>" for i, lab in enumerate(LIKERT))


def comfort_fieldset() -> str:
    """The round's comfort item: the round clock, the "too close" button (its presses go in
    the hidden ``too_close`` field, see static/study.js) and the 1-7 answer ``comfort``."""
    points = "".join(
        f"<td><input type=radio name=comfort value={v} aria-label='comfort {v}'></td>"
        for v in range(1, 8))
    head = _likert_head()
    return (
        "<fieldset id=comfort><legend>How close the robot came</legend>"
        "<p><button type=button class=clock>The round starts now</button> "
        "<button type=button class=too-close disabled>Too close!</button> "
        "<span class='presses muted'>no presses</span></p>"
        "<input type=hidden name=too_close value=''>"
        "<p class='muted small'>Press <b>The round starts now</b> when the round starts (the "
        "first task begins), then <b>Too close!</b> whenever the robot comes too close. Each "
        "press is sent with the round as the seconds since that start, on this page's own "
        "clock (the browser's monotonic clock, unaffected by changes of the computer's "
        "time); the robot's plan puts its own start at the same moment.</p>"
        f"<table class=likert><tr><th></th>{head}</tr><tr><td class=item>{e(COMFORT_ITEM)}"
        f"</td>{points}</tr></table></fieldset>")


def round_page(pid: str, view: Mapping[str, Any], *, tracker_help: str,
               game: str | None = None,
               sources: Sequence[str] = ("tracker", "simulated", "typed"),
               comfort: bool = False) -> str:
    """The plan of the round and the form for what the person did; game: the address where
    the round can be played in the browser game instead (a world with browser_play); sources:
    the form's choices that can work for this participant (a tracker file always); comfort: ask
    the design's comfort item (:func:`comfort_fieldset`)."""
    human = task_items(view["human"])
    seq = lambda items, cls: " → ".join(  # noqa: E731
        f"<span class={cls}>{e(t)}</span>" if not isinstance(t, Wait)
        else f"<span class=muted>wait for {e(t.task)}</span>" for t in map(parse_item, items)
    ) or "—"
    motions = "".join(f"<tr><td class=robot>{e(j)}</td><td>{e(m)}</td></tr>"
                      for j, m in view["routes"].items()) or "<tr><td>—</td></tr>"
    typed = "".join(
        f"<tr><td class=human>{e(t)}</td><td><input type=number name='d:{e(t)}' step=any "
        f"min=0 placeholder='seconds' aria-label='duration of {e(t)} in seconds'></td>"
        f"<td class='muted small'>planned {view['expected'][t]:.1f} s</td></tr>" for t in human)
    offered = {
        "tracker": (
            "a tracker file (CSV or JSON)",
            "<input type=file name=tracker_file accept='.csv,.json,text/csv,application/json'>"
            f"<p class='muted small'>{tracker_help}</p>"),
        "bag": (
            "a ROS 2 bag recorded in the cell",
            "<input type=text name=bag placeholder='round.mcap' "
            "aria-label='file name of the bag in the study folder'>"
            "<p class='muted small'>A rosbag2 bag (.mcap, .db3 or a bag folder) in the study "
            "folder's bags/: task events and tracked body points (README, \"In a real cell\")."
            "</p>"),
        "simulated": (
            "the simulated cell (the priming group's simulated person does the tasks)",
            "<p class='muted small'>No input: the world's simulated teammate of this "
            "participant's priming group performs the tasks.</p>"),
        "typed": (
            "durations typed in",
            f"<table class=grid>{typed}</table><p class='muted small'>The path is the priming "
            "group's nominal path of each task, stretched to the duration: timing adapts to the "
            "person, paths to the group.</p>"),
    }
    shown = [k for k in offered if k in sources]
    src = ("<fieldset><legend>What the person did</legend>" + "".join(
        f"<label class=choice><input type=radio name=source value={k}"
        f"{' checked' if k == shown[0] else ''}> {offered[k][0]}</label>"
        f"<div class=source data-source={k}>{offered[k][1]}</div>" for k in shown)
        + "</fieldset>")
    body = (
        f"<section class=card id=plan><h2>Round {view['round']}: the robot's plan</h2>"
        f"<img class=gantt alt='Gantt chart of the plan' src='{view['gantt']}'>"
        f"<p><b>You</b>: {seq(view['human'], 'human')}</p>"
        f"<p><b>Robot</b>: {seq(view['robot'], 'robot')}</p>"
        "<h3>Robot motions</h3><table class=grid><tr><th>task</th><th>motion</th></tr>"
        f"{motions}</table><p class='muted small'>Expected makespan "
        f"{view['makespan']:.1f} s.</p></section>"
        + (f"<section class=card id=game><h2>Play the round</h2><p><a class=play "
           f"href='{e(game)}'>Play round {view['round']} in the browser game</a></p>"
           "<p class='muted small'>The game shows this plan; when your tasks are done the "
           "round is recorded with your times and paths, and the study goes on.</p></section>"
           if game else "")
        + "<section class=card id=input><h2>After the round</h2>"
        + _form(f"/api/p/{pid}/round", view["step"],
                src + (comfort_fieldset() if comfort else ""), "Record the round",
                "recording and planning the next round…") + "</section>")
    return page(f"{pid} round {view['round']}",
                where(pid, view["block"], view["blocks"], view["round"], view["rounds"]), body)


def survey_page(pid: str, step: str, block: int, blocks: int,
                items: Sequence[Mapping[str, Any]]) -> str:
    head = _likert_head()
    rows = "".join(
        f"<tr><td class=item>{e(it['text'])}</td>" + "".join(
            f"<td><input type=radio name='{e(it['id'])}' value={v} "
            f"aria-label='{e(it['id'])} {v}'></td>" for v in range(1, 8)) + "</tr>"
        for it in items)
    inner = f"<table class=likert><tr><th></th>{head}</tr>{rows}</table>"
    body = ("<section class=card id=survey>"
            f"<h2>About system {block}: how much do you agree?</h2>"
            f"<p class=muted>Think of the {e(_ordinal(block))} system you worked with, the one "
            "you have just finished.</p>"
            + _form(f"/api/p/{pid}/survey", step, inner, "Save the answers") + "</section>")
    return page(f"{pid} survey {block}", where(pid, block, blocks), body)


def _ordinal(n: int) -> str:
    return {1: "first", 2: "second", 3: "third", 4: "fourth", 5: "fifth", 6: "sixth"}.get(
        n, f"{n}th")


def ranking_page(pid: str, step: str, blocks: int) -> str:
    options = "".join(f"<option value={b}>system {b} (the {_ordinal(b)} you worked with)"
                      "</option>" for b in range(1, blocks + 1))
    rows = "".join(
        f"<div class=rank-row><label>{_ordinal(r).capitalize()} choice: <select "
        f"name='rank{r}'><option value=''>choose…</option>{options}</select></label></div>"
        for r in range(1, blocks + 1))
    body = ("<section class=card id=ranking><h2>Which system did you prefer?</h2>"
            "<p class=muted>Rank all the systems, from the one you liked best to the one you "
            "liked least; each system once.</p>"
            + _form(f"/api/p/{pid}/ranking", step, rows, "Save the ranking") + "</section>")
    return page(f"{pid} ranking", where(pid), body)


def demographics_page(pid: str, step: str) -> str:
    rows = "".join(
        f"<div class=rank-row><label>{e(label)}: <input type={kind} name='{name}'"
        + (" min=0 max=130 step=1" if kind == "number" else " maxlength=200") + "></label></div>"
        for name, label, kind in DEMOGRAPHICS)
    body = ("<section class=card id=demographics><h2>About you</h2>"
            "<p class=muted>Every field is optional.</p>"
            + _form(f"/api/p/{pid}/demographics", step, rows, "Finish") + "</section>")
    return page(f"{pid} demographics", where(pid), body)


def done_page(pid: str) -> str:
    body = ("<section class=card id=done><p class=done>Thank you! Participant "
            f"{e(pid)} has finished every part of the study.</p></section>")
    return page(f"{pid} done", where(pid), body)


def message_page(title: str, message: str) -> str:
    return page(title, "", f"<section class=card><h2>{e(title)}</h2><p>{e(message)}</p>"
                           "</section>")


def overview_page(title: str, rows: Sequence[Mapping[str, Any]], facts: str) -> str:
    """The experimenter's table: every participant, group, order of systems, next step."""
    body_rows = "".join(
        f"<tr><td><a href='/p/{e(r['participant'])}'>{e(r['participant'])}</a></td>"
        f"<td>{e(r['group'])}</td><td>{e(' → '.join(r['order']))}</td>"
        f"<td>{e(r['next'])}</td></tr>" for r in rows)
    body = (f"<section class=card id=overview><h2>{e(title)}</h2><p class=muted>{facts}</p>"
            "<table class=grid><tr><th>participant</th><th>priming group</th>"
            "<th>order of systems (experimenter only)</th><th>next step</th></tr>"
            f"{body_rows}</table></section>")
    return page(title, "experimenter overview", body)
