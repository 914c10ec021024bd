"""Counterbalancing of the user study: Williams squares, orders, priming groups, the CSV file."""

from __future__ import annotations

import itertools
from collections import Counter

import pytest

from rapidds.errors import RapiddsError, StudyDesignError
from rapidds.experiments.study import SYSTEMS, StudyDesign, cell_sequence, williams_square
from rapidds.experiments.study.design import priming_factors, world_task_bound
from rapidds.worlds.registry import make_world


def neighbour_pairs(orders):
    """Count ordered pairs (a, b) where b is used right after a."""
    return Counter(pair for order in orders for pair in itertools.pairwise(order))


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 7])
def test_williams_square_is_latin_and_carry_over_balanced(n):
    rows = williams_square(n)
    assert len(rows) == (n if n % 2 == 0 else 2 * n)
    for row in rows:
        assert sorted(row) == list(range(n))
    # every condition equally often at every position
    for pos in range(n):
        assert Counter(row[pos] for row in rows) == {c: len(rows) // n for c in range(n)}
    # every ordered pair of distinct conditions as neighbours equally often: 1 (even) or 2 (odd)
    pairs = neighbour_pairs(rows)
    assert set(pairs) == {(a, b) for a in range(n) for b in range(n) if a != b}
    assert set(pairs.values()) == {1 if n % 2 == 0 else 2}


def test_williams_square_refuses_one_condition():
    with pytest.raises(StudyDesignError, match="at least 2"):
        williams_square(1)


@pytest.mark.parametrize(("rows", "groups"), [(4, 4), (6, 4), (10, 4), (4, 6), (3, 1), (5, 3)])
def test_cell_sequence_covers_every_cell_and_every_prefix_is_near_balanced(rows, groups):
    seq = cell_sequence(rows, groups)
    assert sorted(seq) == [(r, g) for r in range(rows) for g in range(groups)]
    for k in range(1, len(seq) + 1):
        r_counts = Counter(r for r, _ in seq[:k])
        g_counts = Counter(g for _, g in seq[:k])
        assert max(r_counts.values()) - min(r_counts.get(r, 0) for r in range(rows)) <= 1
        assert max(g_counts.values()) - min(g_counts.get(g, 0) for g in range(groups)) <= 1


def test_default_design_is_the_papers_study():
    d = StudyDesign()
    assert (d.participants, d.systems, d.rounds) == (32, SYSTEMS, 7)
    assert d.groups() == [("left", "fast"), ("left", "slow"), ("right", "fast"), ("right", "slow")]
    assert d.block_size == 16 and d.balanced


def test_every_participant_sees_every_system_once_and_cells_are_balanced():
    table = StudyDesign().assign()
    assert len(table) == 32 and table["participant"].is_unique
    assert list(table.columns) == ["participant", "row", "order", "group", "hand", "speed"]
    for order in table["order"]:
        assert sorted(order) == sorted(SYSTEMS)
    # each (order row, priming group) pair exactly twice; rows and groups 8 times each
    assert set(Counter(zip(table["row"], table["group"], strict=True)).values()) == {2}
    assert len(Counter(zip(table["row"], table["group"], strict=True))) == 16
    assert set(table["row"].value_counts()) == {8}
    assert set(table["group"].value_counts()) == {8}
    assert set(table["hand"].value_counts()) == {16} and set(table["speed"].value_counts()) == {16}
    # across participants: each system 8 times at each position, each ordered neighbour pair 8x
    for pos in range(4):
        assert set(Counter(o[pos] for o in table["order"]).values()) == {8}
    pairs = neighbour_pairs(table["order"])
    assert len(pairs) == 12 and set(pairs.values()) == {8}
    # the group column names the factor levels
    for r in table.itertuples():
        assert r.group == f"{r.hand}-{r.speed}"


def test_each_block_of_16_is_balanced_on_its_own():
    table = StudyDesign().assign()
    for block in (table.iloc[:16], table.iloc[16:]):
        assert len(set(zip(block["row"], block["group"], strict=True))) == 16


@pytest.mark.parametrize(("systems", "participants"), [(3, 24), (5, 40)])
def test_odd_systems_use_square_and_mirror(systems, participants):
    names = tuple(f"s{i}" for i in range(systems))
    d = StudyDesign(participants=participants, systems=names)
    assert len(d.square()) == 2 * systems and d.block_size == 2 * systems * 4
    table = d.assign()
    pairs = neighbour_pairs(table["order"])
    assert len(pairs) == systems * (systems - 1)
    assert len(set(pairs.values())) == 1  # every ordered pair equally often
    assert set(Counter(zip(table["row"], table["group"], strict=True)).values()) == {1}


def test_seed_permutes_participants_not_balance():
    a, b = StudyDesign(seed=1).assign(), StudyDesign(seed=2).assign()
    assert a.equals(StudyDesign(seed=1).assign())  # deterministic
    assert not a[["row", "group"]].equals(b[["row", "group"]])
    assert Counter(zip(a["row"], a["group"], strict=True)) == Counter(
        zip(b["row"], b["group"], strict=True)
    )


def test_sessions_run_sheet_follows_each_order():
    d = StudyDesign(participants=16, rounds=3)
    s = d.sessions()
    assert len(s) == 16 * 4 * 3
    table = d.assign().set_index("participant")
    for who, g in s.groupby("participant"):
        blocks = g.drop_duplicates("block").sort_values("block")
        assert tuple(blocks["system"]) == table.loc[who, "order"]
        assert sorted(g["round"].unique()) == [1, 2, 3]


def test_unbalanced_count_is_refused_with_what_is_needed():
    with pytest.raises(StudyDesignError, match=r"multiple of 16 \(e.g. 16 or 32\)") as exc:
        StudyDesign(participants=30)
    assert "\n" not in str(exc.value)
    with pytest.raises(StudyDesignError, match="multiple of 24"):
        StudyDesign(participants=32, systems=("a", "b", "c"))


def test_the_balance_error_names_the_flag_a_user_can_type():
    with pytest.raises(StudyDesignError, match="--allow-unbalanced") as exc:
        StudyDesign(participants=30)
    assert "require_balance: false" not in str(exc.value)


@pytest.mark.parametrize("world", ["painting", "fetch"])
def test_priming_groups_are_the_worlds_simulated_teammates(world):
    """Each group of a world's design names one of its simulated people (fetch: fast-middle
    ..., not painting's left-fast ...), so the simulated cell and typed-in rounds can work."""
    w = make_world(world)
    groups = set(StudyDesign(participants=16, factors=priming_factors(w)).assign()["group"])
    assert groups == set(w.teammate_names)


def test_a_world_without_listed_factors_primes_by_its_teammates():
    class Other:
        name, teammate_names = "other", ("calm", "hasty")

    assert priming_factors(Other()) == {"teammate": ("calm", "hasty")}  # type: ignore[arg-type]


def test_task_bounds_are_per_world_and_the_design_can_set_its_own():
    fetch, painting = make_world("fetch"), make_world("painting")
    assert world_task_bound(fetch) == 180.0 and world_task_bound(painting) == 120.0
    for w in (fetch, painting):  # far beyond any task the world's prior knows
        longest = max(t.human_mean + 5 * t.human_std for t in w.problem().tasks
                      if t.human_mean is not None)
        assert world_task_bound(w) > 5 * longest
    d = StudyDesign(participants=16)
    assert d.task_bound(fetch) == 180.0 and "max_task_s" not in d.model_dump_json()
    own = StudyDesign(participants=16, max_task_s=30)
    assert own.task_bound(fetch) == own.task_bound(painting) == 30.0
    assert StudyDesign(**own.model_dump()) == own  # stored and read back
    for bad in (0, -1, float("nan"), 1e6):
        with pytest.raises(StudyDesignError, match="max_task_s"):
            StudyDesign(participants=16, max_task_s=bad)


def test_the_comfort_item_is_off_by_default_and_stored_only_when_asked():
    d = StudyDesign(participants=16)
    assert not d.comfort and "comfort" not in d.model_dump_json()  # old designs read the same
    asked = StudyDesign(participants=16, comfort=True)
    assert asked.model_dump()["comfort"] is True and asked != d
    assert StudyDesign(**asked.model_dump()) == asked
    with pytest.raises(StudyDesignError, match="comfort"):
        StudyDesign(participants=16, comfort="yes")


def test_near_balance_when_allowed():
    d = StudyDesign(participants=30, require_balance=False)
    assert not d.balanced
    table = d.assign()
    assert len(table) == 30
    rows, groups = table["row"].value_counts(), table["group"].value_counts()
    assert rows.max() - rows.min() <= 1 and groups.max() - groups.min() <= 1
    cells = Counter(zip(table["row"], table["group"], strict=True))
    assert set(cells.values()) <= {1, 2}


def test_no_factors_is_one_group():
    d = StudyDesign(participants=8, factors={})
    assert d.groups() == [()] and d.block_size == 4
    assert set(d.assign()["group"]) == {"all"}


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"participants": 0}, "participants"),
        ({"participants": 32.5}, "participants"),
        ({"systems": ("full",)}, "systems"),
        ({"systems": ("full", "full", "none", "spatial")}, "named twice: full"),
        ({"systems": ("a;b", "c")}, "no separators"),
        ({"factors": {"group": ("a", "b")}}, "clash"),
        ({"factors": {"hand": ()}}, "no levels"),
        ({"factors": {"hand": ("left", "left")}}, "named twice"),
        ({"rounds": 0}, "rounds"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_bad_designs_are_refused_in_one_line(kwargs, message):
    with pytest.raises(StudyDesignError, match=message) as exc:
        StudyDesign(**kwargs)
    assert isinstance(exc.value, RapiddsError) and "\n" not in str(exc.value)


def test_csv_round_trip(tmp_path):
    d = StudyDesign(
        participants=10, seed=7, factors={"hand": ("left", "right")}, require_balance=False
    )
    path = tmp_path / "study" / "design.csv"
    d.to_csv(path)
    assert [p.name for p in path.parent.iterdir()] == ["design.csv"]  # no temporary left over
    back = StudyDesign.from_csv(path)
    assert back == d
    assert back.assign().equals(d.assign())
    text = path.read_text().splitlines()
    assert text[0].startswith("# rapidds study design: {")
    assert text[1] == "participant,row,order,group,hand"
    assert text[2].count(";") == 3


def test_from_csv_refuses_edited_or_malformed_files(tmp_path):
    path = tmp_path / "design.csv"
    StudyDesign().to_csv(path)
    lines = path.read_text().splitlines(keepends=True)
    edited = [*lines[:5], "P99" + lines[5][3:], *lines[6:]]
    path.write_text("".join(edited))
    with pytest.raises(StudyDesignError, match="line 6 differs"):
        StudyDesign.from_csv(path)
    path.write_text("participant,row\n")
    with pytest.raises(StudyDesignError, match="first line"):
        StudyDesign.from_csv(path)
    path.write_text("# rapidds study design: {not json\n")
    with pytest.raises(StudyDesignError, match="not valid JSON"):
        StudyDesign.from_csv(path)
    path.write_text('# rapidds study design: {"participants": 30}\n')
    with pytest.raises(StudyDesignError, match="multiple of 16"):
        StudyDesign.from_csv(path)
    with pytest.raises(StudyDesignError, match="cannot read"):
        StudyDesign.from_csv(tmp_path / "missing.csv")
