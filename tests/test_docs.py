"""docs/: prose at its top (``*.md``), what tools write under ``docs/figures`` (screenshots,
benchmark plots) and ``docs/results`` (study outputs, tables), and every link of the prose and
the README resolves, so a moved output cannot leave a dead link behind."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED = ("figures", "results")
# Not prose and not generated: a file a reader loads into a tool (README, "ROS 2 bags").
HAND_WRITTEN = {"foxglove-layout.json"}
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _markdown() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def test_docs_top_level_holds_prose_and_the_generated_folders_only() -> None:
    stray = sorted(p.name for p in DOCS.iterdir()
                   if not (p.is_dir() and p.name in GENERATED)
                   and not (p.is_file() and p.suffix == ".md")
                   and p.name not in HAND_WRITTEN)
    assert not stray, f"put generated outputs under docs/figures or docs/results: {stray}"
    assert not [p for p in DOCS.joinpath("figures").rglob("*") if p.suffix == ".md"], \
        "prose belongs at docs/, not among the figures"


def test_every_relative_link_in_the_docs_resolves() -> None:
    dead = []
    for md in _markdown():
        for target in _LINK.findall(md.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue  # a web address or an anchor on the same page
            path = (md.parent / target.split("#")[0]).resolve()
            if not path.exists():
                dead.append(f"{md.relative_to(ROOT)}: {target}")
    assert not dead, "dead links:\n" + "\n".join(dead)
    assert len(_markdown()) > 5  # the glob found the docs


def test_docs_and_scripts_name_only_output_paths_that_exist() -> None:
    """Paths written in backticks (not links) that name a file under docs/ exist too."""
    dead = []
    for md in [*_markdown(), *sorted((ROOT / "benchmarks").glob("*.py")),
               *sorted((ROOT / "tests").glob("*browser*.py"))]:
        for name in re.findall(r"docs/[\w./-]+\.(?:png|pdf|md|jsonl|json|log|csv|gif)\b",
                               md.read_text()):
            if not (ROOT / name).exists():
                dead.append(f"{md.relative_to(ROOT)}: {name}")
    assert not dead, "paths to files that are not there:\n" + "\n".join(dead)


def test_tools_write_into_docs_only_under_the_generated_folders() -> None:
    """A benchmark or a test that builds a path into docs/ (``ROOT / "docs" / ...``) writes an
    output, so the path goes under docs/figures or docs/results, never beside the prose (the
    benchmarks that append their section to a page of prose, docs/benchmarks.md, excepted)."""
    wrong = []
    sources = [*sorted((ROOT / "benchmarks").glob("*.py")), *sorted((ROOT / "tests").glob("*.py")),
               *sorted((ROOT / "scripts").rglob("*.py")), *sorted((ROOT / "src").rglob("*.py"))]
    for py in sources:
        for first in re.findall(r'"docs"\s*/\s*"([^"]+)"', py.read_text()):
            if first not in GENERATED and first not in HAND_WRITTEN and not first.endswith(".md"):
                wrong.append(f"{py.relative_to(ROOT)}: docs/{first}")
    assert not wrong, "outputs belong under docs/figures or docs/results:\n" + "\n".join(wrong)
