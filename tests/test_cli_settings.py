"""Settings that write the CLI (issue 32): each run setting described once, in its field; the
options of every command written from the fields; old spellings still accepted with one
deprecation line; help texts whole sentences; a run's stored settings flat as ever."""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Any

import pytest
import typer.main
from cli_helpers import run_main

from rapidds.cli import _register, app
from rapidds.loop.config import RunConfig
from rapidds.loop.run import AdaptiveRun
from rapidds.store import RunStore
from rapidds.worlds.registry import make_world

SRC = Path(__file__).resolve().parents[1] / "src" / "rapidds"

# what main stored for a small fetch run before the settings were grouped (its model_dump)
FLAT = {
    "world": "fetch", "variant": "default", "human": "fast-middle", "adapt": "full", "cycles": 2,
    "gamma": 1.75, "lam": 15.0, "seed": 0, "population": 4, "generations": 2, "samples": 4,
    "patience": 8, "particles": 1, "candidates": 2, "steps": None, "beta": 1.0, "rho": 0.05,
    "grid_points": 32, "surrogate": False, "reuse_motions": True, "change": None, "drift": 0.0,
    "drift_from": 0, "forgetting": 1.0, "detect": True, "hazard": 0.05, "detect_threshold": 0.5,
    "ask": False, "whole_person": False, "reexplore": 0, "gamma_learn": False,
    "gamma_prior": None, "gamma_plan": "mean", "comfort": 2.5, "gamma_reactions": True,
    "execution": "planned", "reacts": False, "deviate": 0.0, "slowdowns": None,
    "slowdown_mean": 1.0, "slowdown_sd": 1.0}


def _strings() -> list[str]:
    """Every string constant in the package's source (adjacent literals joined, as written)."""
    found = []
    for path in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found.append(node.value)
    return found


def _params() -> list[tuple[str, Any]]:
    """(command path, click parameter) of every command, after the CLI's own registration."""
    _register()
    out = []

    def walk(cmd: Any, path: str) -> None:
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {name}")
        out.extend((path, p) for p in cmd.params)

    walk(typer.main.get_command(app), "rapidds")
    return out


def _commands() -> list[tuple[str, Any]]:
    _register()
    out = []

    def walk(cmd: Any, path: str) -> None:
        out.append((path, cmd))
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {name}")

    walk(typer.main.get_command(app), "rapidds")
    return out


def test_the_settings_are_grouped_and_stored_flat_as_before():
    cfg = RunConfig(**FLAT)
    assert cfg.search.population == cfg.population == 4
    assert cfg.changes.detect and cfg.teammate.comfort == 2.5
    assert list(cfg.model_dump()) == list(FLAT)  # the keys, in the order main stored them
    assert cfg.model_dump() == FLAT and RunConfig.model_validate_json(cfg.model_dump_json()) == cfg
    assert cfg.replace(population=6).search.population == 6
    # device is never stored, sampler only when set (runs stored before it stay identical)
    assert [k for k in RunConfig.flat_fields() if k not in ("device", "sampler")] == list(FLAT)
    assert cfg.replace(sampler="dpm").model_dump()["sampler"] == "dpm"


def test_a_store_written_flat_resumes(tmp_path):
    """A run stored by the flat settings of before continues: its settings compare equal."""
    world = make_world("fetch")
    path = tmp_path / "run.sqlite"
    rid = RunConfig(**FLAT).run_id
    with RunStore(path) as store:
        store.create_run(rid, dict(FLAT))  # as main wrote it
    with RunStore(path) as store:
        run = AdaptiveRun(RunConfig(**FLAT), None, store, world=world)
        assert run.next_cycle == 0 and store.run_config(rid) == FLAT
    with RunStore(path) as store, pytest.raises(Exception, match=r"population=4 \(asked 5\)"):
        AdaptiveRun(RunConfig(**{**FLAT, "population": 5}), None, store, world=world)


def test_each_run_setting_is_described_once_in_the_source():
    strings = _strings()
    for name, field in RunConfig.flat_fields().items():
        assert field.description, name
        homes = [s for s in strings if field.description in s]
        assert len(homes) == 1, (name, len(homes))


def test_no_help_sentence_is_written_twice():
    """A help text shown by two commands is one constant shared, not two copies."""
    strings = _strings()
    helps = {p.help for _, p in _params() if getattr(p, "help", None)}
    for text in helps:
        for sentence in re.split(r"(?<=[.;])\s+", text):
            if len(sentence.split()) < 4:
                continue
            homes = [s for s in strings if sentence in s]
            assert len(homes) <= 1, (sentence, homes)


def test_every_help_is_whole_sentences():
    for path, cmd in _commands():
        text = (cmd.help or "").strip()
        assert text.endswith("."), path
        for paragraph in text.split("\n\n"):
            assert "\n" not in paragraph, (path, paragraph)  # a break where the source broke
    for path, p in _params():
        if getattr(p, "hidden", False) or p.name == "help":
            continue
        text = (getattr(p, "help", None) or "").strip()
        assert text.endswith(".") and "\n" not in text, (path, p.name, text)
        assert text[0].isupper() or text[0] in "'(", (path, p.name, text)


def test_the_search_options_are_the_same_in_every_command_that_searches():
    by_option: dict[str, set[str]] = {}
    for _, p in _params():
        if p.name in ("population", "generations", "samples", "particles", "candidates"):
            by_option.setdefault(p.name, set()).add(p.help)
    assert by_option.keys() == {"population", "generations", "samples", "particles",
                                "candidates"}
    for name, helps in by_option.items():
        assert helps == {RunConfig.flat_fields()[name].description}, name


def test_commands_are_grouped_in_the_help(capsys):
    code, out, _ = run_main(capsys, "--help")
    assert code == 0
    panels = re.findall(r"─ ([A-Z][A-Za-z ]+) ─", out)
    assert panels[:5] == ["Options", "Run the loop", "Plan and move", "A real cell",
                          "Experiments"], panels
    assert "Other" not in panels


@pytest.mark.parametrize(("old", "new", "needle"), [
    ("run --comfort 0", "--teammate-gamma", "--teammate-gamma: Input should be greater than 0"),
    ("play --player ../etc", "--human", "--human '../etc'"),
    ("demo --world moon", "the WORLD argument", "unknown world 'moon'"),
    ("gamma --world moon", "the WORLD argument", "unknown world 'moon'"),
    ("study design --out {tmp}/s --world nowhere", "the WORLD argument",
     "unknown world 'nowhere'"),
    ("case-study painting --out {tmp}/cs --settings , --reactive",
     "--execution planned,reactive", "--settings names no setting"),
])
def test_an_old_spelling_still_works_with_one_deprecation_line(old, new, needle, tmp_path,
                                                               capsys):
    code, _, err = run_main(capsys, *old.format(tmp=tmp_path).split())
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2, err
    assert lines[0].startswith("rapidds: note: ") and "deprecated" in lines[0], err
    assert (new in lines[0] and old.split()[-2] in lines[0]) or "--reactive" in lines[0], err
    assert lines[1].startswith("rapidds: error: ") and needle in lines[1], err


def test_a_bad_gamma_text_is_one_line(capsys):
    code, _, err = run_main(capsys, "run", "--gamma", "lots")
    assert code == 2 and err.count("\n") == 1
    assert "--gamma is a number >= 0 or 'learn', got 'lots'" in err
