"""The import graph: arrows point one way, problem -> human models -> scheduler/motion -> worlds
-> execution -> loop -> experiments -> web -> cli, with no cycle and nothing in the library
importing the CLI. Imports inside functions count too: they are arrows all the same, only later."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
LAYERS: list[tuple[str, ...]] = [
    ("rapidds", "rapidds.errors", "rapidds.fileio", "rapidds.lazy", "rapidds.settings",
     "rapidds.problem", "rapidds.schedule", "rapidds.bundled", "rapidds.store"),
    ("rapidds.human",),
    ("rapidds.scheduler", "rapidds.motion"),  # scheduler <-> motion: one layer
    ("rapidds.plots", "rapidds.render"),
    ("rapidds.worlds",),
    ("rapidds.execution",),
    ("rapidds.loop",),
    ("rapidds.experiments",),
    ("rapidds.web",),
    ("rapidds.cli",),
]


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in SRC.rglob("*.py")}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """rapidds modules imported anywhere in the file (TYPE_CHECKING-only imports excluded)."""
    tree = ast.parse(path.read_text())
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for n in ast.walk(node))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]
                                + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t.startswith("rapidds"):
                out.add(t)
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    graph = {}
    for name, path in mods.items():
        deps = _imports(path, name, known)
        # a package and its own submodules are one unit: importing a submodule runs the
        # package's __init__, and a lazy package __init__ imports its submodules
        graph[name] = {d for d in deps if d != name and not d.startswith(name + ".")
                       and not name.startswith(d + ".")}
    return graph


def _layer(module: str) -> int:
    best = (-1, -1)
    for rank, prefixes in enumerate(LAYERS):
        for p in prefixes:
            if module == p or module.startswith(p + "."):
                best = max(best, (len(p), rank))
    assert best[1] >= 0, f"{module} is in no layer: add it to LAYERS"
    return best[1]


def test_arrows_point_down_the_layers() -> None:
    back = sorted(f"{m} -> {d}" for m, deps in _graph().items() for d in deps
                  if _layer(d) > _layer(m))
    assert not back, "imports against the layering:\n" + "\n".join(back)


def test_library_never_imports_the_cli() -> None:
    bad = sorted(f"{m} -> {d}" for m, deps in _graph().items() if not m.startswith("rapidds.cli")
                 for d in deps if d.startswith("rapidds.cli"))
    assert not bad, bad


def test_no_import_cycles() -> None:
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(u: str) -> list[str] | None:
        state[u] = 1
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                return [*stack[stack.index(v):], v]
            if v not in state and (cycle := visit(v)):
                return cycle
        stack.pop()
        state[u] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            pytest.fail("import cycle: " + " -> ".join(cycle))


def _loaded_by(argv: list[str], modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh process has imported after ``rapidds ARGV``."""
    code = ("import json, sys\nfrom rapidds.cli import main\ntry:\n    main()\n"
            "except SystemExit:\n    pass\nprint('LOADED', json.dumps(sorted(m for m in "
            f"{modules!r} if m in sys.modules)), file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                         timeout=120)
    line = [x for x in out.stderr.splitlines() if x.startswith("LOADED ")]
    assert line, out.stderr[-2000:]
    return json.loads(line[-1][len("LOADED "):])


@pytest.mark.parametrize("argv", [["--help"], ["plan", "fetch", "--seed", "0", "--json"],
                                  ["run", "--help"], ["worlds"], ["case-study", "--help"]])
def test_light_commands_import_no_heavy_library(argv: list[str]) -> None:
    assert _loaded_by(argv, ("torch", "diffusers", "distributed", "matplotlib", "mujoco")) == []


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["ablation", "--help"]])
def test_help_imports_no_numpy(argv: list[str]) -> None:
    """Help is read far more often than anything is run: it lists options without numpy."""
    assert _loaded_by(argv, ("numpy", "pandas")) == []
