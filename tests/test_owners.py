"""Each format that crosses a boundary has one owner that writes and reads it: a schedule item's
text (``wait:TASK``) belongs to :mod:`rapidds.schedule` (the browser gets structured items), a
stored path array's name (``human/TASK``, ``robot/TASK``) to :mod:`rapidds.store`, a stored
cycle record's keys to :mod:`rapidds.record` (readers take a ``CycleRecord``). These tests
read every source file (Python and the page's JavaScript) for a second reader or writer."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from rapidds.schedule import Wait, item_json, parse_item, task_items
from rapidds.store import cycle_paths, path_arrays

SRC = Path(__file__).resolve().parents[1] / "src" / "rapidds"

# the text of a wait (a literal "wait:" in code or a string, not a word in a comment) or its
# parse by position
WAIT_TEXT = re.compile(r"""["'`]wait:|startsWith\(\s*["']wait|\bslice\(5\)|\[5:\]""")
# an array name built or split by hand: "human/...", "robot/...", f"{kind}/{task}", split("/")
ARRAY_NAME = re.compile(r"""["'`](?:human|robot)/|\}/\{(?:task|t|j)\}"""
                        r"""|(?:split|partition)\(\s*["']/["']""")


# a cycle record read as the stored dict: a key only a record has, on any mapping (not assigned),
# or any stored key on a variable named as a record is
_ONLY_A_RECORDS = "realised|plan_cost|gamma_belief|executed|replans|pauses|yields"
_STORED_KEYS = ("cycle|human|robot|routes|gamma|lambda|expected|realised|observed|belief|"
                "plan_cost|search|changes|comfort|gamma_belief|executed|deviation|pauses|replans|"
                "protective|yields|live|seconds|run_id")
RECORD_KEY = re.compile(
    rf"""(?:\[\s*["'](?:{_ONLY_A_RECORDS})["']\s*\](?!\s*=[^=])"""
    rf"""|\.get\(\s*["'](?:{_ONLY_A_RECORDS})["'])"""
    rf"""|\b(?:rec|record|r|recs?\[-?\d+\]|records\[-?\d+\])"""
    rf"""(?:\[|\.get\()\s*["'](?:{_STORED_KEYS})["']""")


def _offenders(pattern: re.Pattern[str], owner: str | tuple[str, ...],
               suffixes: tuple[str, ...] = (".py", ".js", ".html")) -> list[str]:
    owners = (owner,) if isinstance(owner, str) else owner
    hits = []
    for path in sorted(SRC.rglob("*")):
        if path.suffix not in suffixes or path.relative_to(SRC).as_posix() in owners:
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{path.relative_to(SRC)}:{n}: {line.strip()}")
    return hits


def test_only_the_schedule_reads_or_writes_a_wait_items_text() -> None:
    assert not _offenders(WAIT_TEXT, "schedule.py"), "use rapidds.schedule (parse_item, "\
        "task_items, item_json) instead:\n" + "\n".join(_offenders(WAIT_TEXT, "schedule.py"))


def test_only_the_store_names_or_parses_path_arrays() -> None:
    assert not _offenders(ARRAY_NAME, "store.py"), "use rapidds.store (path_arrays, "\
        "cycle_paths) instead:\n" + "\n".join(_offenders(ARRAY_NAME, "store.py"))


def test_only_the_record_reads_a_stored_records_keys() -> None:
    """Readers go through rapidds.record (the store hands its dicts over as they are)."""
    hits = _offenders(RECORD_KEY, ("record.py", "store.py"), (".py",))
    assert not hits, "read a CycleRecord (RunStore.cycle_records, CycleRecord.from_json) " \
        "instead:\n" + "\n".join(hits)


def test_the_record_pattern_catches_dict_reads_and_spares_others() -> None:
    for line in ('real = rec["realised"]', "x = record['plan_cost']['cost']",
                 'said = r.get("comfort") or {}', 'b = x.get("gamma_belief")',
                 'c = records[-1]["cycle"]', "n = len(rec['pauses'])", 'm = last["realised"]',
                 'rid = r["run_id"]'):
        assert RECORD_KEY.search(line), line
    for line in ('out["plan_cost"] = summarise(data)', 'dur["human"]', 'doc["gamma"]',
                 'plan.order["robot"]', 'result["run_id"]', "rec.realised.makespan",
                 'row["cycle"]'):
        assert not RECORD_KEY.search(line), line


# YAML parsed anywhere but the one reader (rapidds.settings.read_yaml / parse_yaml)
YAML_READ = re.compile(r"\byaml\.(?:safe_|full_|unsafe_)?load(?:_all)?\(")


def test_only_the_settings_read_yaml() -> None:
    hits = _offenders(YAML_READ, "settings.py", (".py",))
    assert not hits, "use rapidds.settings.read_yaml (or parse_yaml) instead:\n" + "\n".join(hits)
    for line in ("yaml.safe_load(text)", "raw = yaml.load(text, Loader=L)"):
        assert YAML_READ.search(line), line


def test_the_patterns_catch_what_they_are_for() -> None:
    """The greps above would see the hand parsers this replaced (or they prove nothing)."""
    for line in ('if t.startswith("wait:")', "x.startsWith('wait:')", "w = item.slice(5)",
                 'f"wait:{t}"'):
        assert WAIT_TEXT.search(line), line
    for line in ('f"robot/{j}"', 'key.split("/", 1)', 'f"{kind}/{task}"',
                 'if key.startswith("human/")'):
        assert ARRAY_NAME.search(line), line
    assert not WAIT_TEXT.search("# the robot waits: for the person")


def test_wait_items_round_trip_through_their_owner() -> None:
    items = ["t0", str(Wait("t1")), "t2"]
    assert [parse_item(x) for x in items] == ["t0", Wait("t1"), "t2"]
    assert task_items(items) == ["t0", "t2"]
    assert [item_json(x) for x in items] == [{"task": "t0"}, {"wait": "t1"}, {"task": "t2"}]
    assert item_json(Wait("t1")) == {"wait": "t1"}


def test_path_arrays_round_trip_through_the_store_names() -> None:
    robot = {"j1": np.zeros((3, 2))}
    human = {"j1": np.ones((4, 2)), "h2": np.full((2, 2), 2.0)}
    arrays = path_arrays(robot, human)
    assert len(arrays) == 3  # a robot and a human task of the same name do not collide
    back = cycle_paths({**arrays, "other": np.zeros(1)})
    assert set(back) == {"robot", "human"}
    assert back["robot"].keys() == robot.keys() and back["human"].keys() == human.keys()
    assert all(np.array_equal(back["human"][t], human[t]) for t in human)
    assert np.array_equal(back["robot"]["j1"], robot["j1"])
