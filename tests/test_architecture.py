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
     "rapidds.problem", "rapidds.schedule", "rapidds.record", "rapidds.bundled", "rapidds.store",
     "rapidds.codec", "rapidds.cache"),
    ("rapidds.human",),
    ("rapidds.scheduler", "rapidds.motion"),  # scheduler <-> motion: one layer
    ("rapidds.plots", "rapidds.render"),
    ("rapidds.worlds",),
    ("rapidds.execution",),
    ("rapidds.loop",),
    ("rapidds.bridge",),  # the real cell's border: ROS 2 formats in and out, runs the loop
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


# -- sizes ----------------------------------------------------------------------------------------
# A module does one job and a function one step: past these sizes they were doing several.
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80

# Each exception says why it stands; the list only shrinks. "Changed elsewhere this cycle": the
# file was being edited on another branch, so splitting it then would have made that work
# unmergeable. None remains.
FILE_EXCEPTIONS: dict[str, str] = {}
FUNCTION_EXCEPTIONS: dict[str, str] = {
}


def _sources() -> dict[str, Path]:
    root = SRC / "rapidds"
    return {p.relative_to(root).as_posix(): p for p in sorted(root.rglob("*.py"))}


def _body_start(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """The first line of a function's code, after its signature and docstring: a CLI command's
    signature is its declared options (data, one per option), not steps it takes."""
    body = node.body
    if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]
    return body[0].lineno


def _functions(tree: ast.AST, prefix: str = "") -> list[tuple[str, int]]:
    """(qualified name, lines of code) of every function, methods as ``Class.name``; a nested
    function counts in its parent's lines and on its own."""
    out = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            name = prefix + node.name
            if not isinstance(node, ast.ClassDef):
                out.append((name, node.end_lineno - _body_start(node) + 1))  # type: ignore[operator]
            out += _functions(node, name + ".")
    return out


def test_no_source_file_is_over_600_lines() -> None:
    long = {f"{rel} ({n} lines)" for rel, p in _sources().items()
            if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES
            and rel not in FILE_EXCEPTIONS}
    assert not long, f"split these at their seams: {sorted(long)}"


def test_no_function_is_over_80_lines() -> None:
    long = sorted(f"{rel}:{name} ({n} lines)" for rel, p in _sources().items()
                  for name, n in _functions(ast.parse(p.read_text()))
                  if n > MAX_FUNCTION_LINES and f"{rel}:{name}" not in FUNCTION_EXCEPTIONS)
    assert not long, "break these into named steps:\n" + "\n".join(long)


def test_every_size_exception_is_still_needed() -> None:
    """An exception outlives its reason only by mistake: each one still names a file or function
    over the limit (so the list shrinks as things are split)."""
    sources = _sources()
    for rel in FILE_EXCEPTIONS:
        assert len(sources[rel].read_text().splitlines()) > MAX_FILE_LINES, rel
    sizes = {f"{rel}:{name}": n for rel, p in sources.items()
             for name, n in _functions(ast.parse(p.read_text()))}
    for key in FUNCTION_EXCEPTIONS:
        assert sizes.get(key, 0) > MAX_FUNCTION_LINES, key


# -- parameters -----------------------------------------------------------------------------------
# A library function that takes more than 8 things is handed a context in pieces: pass the
# object that holds them (a RunContext, a Cycle, a CycleSetup). The CLI's commands are exempt:
# their parameters are their declared options. Each exception says why it stands; the list only
# shrinks (issue 32 wants it empty).
MAX_PARAMETERS = 8
PARAMETER_EXCEPTIONS: dict[str, str] = {}


def _parameters(tree: ast.AST, prefix: str = "") -> list[tuple[str, int]]:
    """(qualified name, parameters but self and cls) of every function in ``tree``."""
    out = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            name = prefix + node.name
            if not isinstance(node, ast.ClassDef):
                a = node.args
                names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs,
                                         *(v for v in (a.vararg, a.kwarg) if v is not None))]
                out.append((name, len([x for x in names if x not in ("self", "cls")])))
            out += _parameters(node, name + ".")
    return out


def _library_parameters() -> dict[str, int]:
    return {f"{rel}:{name}": n for rel, p in _sources().items() if not rel.startswith("cli/")
            for name, n in _parameters(ast.parse(p.read_text()))}


def test_no_library_function_takes_more_than_8_parameters() -> None:
    many = sorted(f"{key} ({n})" for key, n in _library_parameters().items()
                  if n > MAX_PARAMETERS and key not in PARAMETER_EXCEPTIONS)
    assert not many, "pass the object that holds these:\n" + "\n".join(many)


def test_every_parameter_exception_is_still_needed() -> None:
    counts = _library_parameters()
    for key in PARAMETER_EXCEPTIONS:
        assert counts.get(key, 0) > MAX_PARAMETERS, key


def test_the_parameter_count_sees_every_kind_of_parameter() -> None:
    tree = ast.parse("class A:\n    def f(self, a, /, b, *c, d, **e): ...\n"
                     "def g(cls, a=1, *, b): ...")
    assert _parameters(tree) == [("A.f", 5), ("g", 2)]


# -- one resampler --------------------------------------------------------------------------------
def test_samples_become_an_execution_in_one_place() -> None:
    """loop/observation.py owns turning tracked samples into a HumanExecution; the study
    tracker, the bag reader, the live link and the browser game had one each."""
    old = {"web/study/tracker.py": ("def resample", "def _rows_of", "np.interp("),
           "bridge/recorded.py": ("def resample", "np.interp("),
           "bridge/live.py": ("np.interp(", "def _path"),
           "web/game.py": ("np.interp(",)}
    sources = _sources()
    left = [f"{rel}: {text}" for rel, texts in old.items() for text in texts
            if text in sources[rel].read_text()]
    assert not left, left
    assert "def resample" in sources["loop/observation.py"].read_text()


# -- who knows a world by name -------------------------------------------------------------------
# Everything else reaches a world through the registry (rapidds.worlds.registry) and the World
# interface. These name one on purpose (README, "Worlds and teammates", says the same):
NAMES_A_WORLD: dict[str, str] = {
    "loop/config.py": "RunConfig's default world, fetch",
    "cli/run.py": "`rapidds run` and `demo` default to fetch (and its default teammate)",
    "cli/play.py": "`rapidds play` defaults to fetch (it plays any world with browser_play)",
    "cli/case_study.py": "the paper's painting case study",
    "cli/study.py": "`rapidds study` defaults to the painting world",
    "experiments/ablation.py": "the paper's fetch ablation",
    "experiments/painting.py": "the paper's painting case study",
}
_WORLDS = ("fetch", "painting")


def _names_a_world(tree: ast.AST) -> bool:
    """A world's name as a string of code (docstrings never equal it), an import of a world's
    package, or its World class."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and node.value in _WORLDS:
            return True
        modules = ([node.module or ""] if isinstance(node, ast.ImportFrom) else
                   [a.name for a in node.names] if isinstance(node, ast.Import) else [])
        if any(m.startswith(tuple(f"rapidds.worlds.{w}" for w in _WORLDS)) for m in modules):
            return True
        if isinstance(node, ast.Name | ast.alias) and \
                getattr(node, "id", getattr(node, "name", "")) in ("FetchWorld", "PaintingWorld"):
            return True
    return False


def test_only_the_listed_modules_know_a_world_by_name() -> None:
    named = [rel for rel, path in _sources().items()
             if not rel.startswith("worlds/") and not any(rel.startswith(k) for k in NAMES_A_WORLD)
             and _names_a_world(ast.parse(path.read_text()))]
    assert not named, f"these know a world by name; go through the registry: {named}"


def test_the_world_name_check_sees_each_way_of_naming_one() -> None:
    for code in ('make_world("fetch")', "from rapidds.worlds.painting import x",
                 "import rapidds.worlds.fetch.map", "isinstance(w, FetchWorld)"):
        assert _names_a_world(ast.parse(code)), code
    assert not _names_a_world(ast.parse('"""Runs in the fetch world."""\nmake_world(name)'))


# -- what a world can do is asked by name, never probed ----------------------------------------
def _world_packages() -> dict[str, set[str]]:
    """World package (``worlds/fetch/``) -> the classes it defines."""
    out: dict[str, set[str]] = {}
    for rel, path in _sources().items():
        parts = rel.split("/")
        if parts[0] == "worlds" and len(parts) > 2:
            out.setdefault(f"worlds/{parts[1]}/", set()).update(
                n.name for n in ast.walk(ast.parse(path.read_text()))
                if isinstance(n, ast.ClassDef))
    return out


def _optional_members() -> set[str]:
    """Names a world may or may not have: every capability's members, and the spec's fields
    that are not the contract's (joint and body point names, once optional members)."""
    import dataclasses

    from rapidds.worlds.base import World, WorldSpec
    from rapidds.worlds.capabilities import CAPABILITIES

    members = {m for proto, _ in CAPABILITIES.values() for m in vars(proto)}
    members |= {f.name for f in dataclasses.fields(WorldSpec)}
    return {m for m in members if not m.startswith("_") and m not in dir(World)}


def _probes(tree: ast.AST, concrete: set[str], optional: set[str]) -> list[str]:
    """``isinstance(x, C)`` of a concrete world class C, and ``getattr``/``hasattr`` of an
    optional world member by its name."""
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and len(node.args) >= 2):
            continue
        what = node.args[1]
        names = {n.id for n in ast.walk(what) if isinstance(n, ast.Name)}
        if node.func.id == "isinstance" and names & concrete:
            found.append(ast.unparse(node))
        if node.func.id in ("getattr", "hasattr") and isinstance(what, ast.Constant) \
                and what.value in optional:
            found.append(ast.unparse(node))
    return found


def test_no_world_is_probed_outside_its_package_and_the_capability_helper() -> None:
    packages = _world_packages()
    optional = _optional_members()
    found = {}
    for rel, path in _sources().items():
        if rel == "worlds/capabilities.py":
            continue  # the one helper that asks
        concrete = set().union(*(c for pkg, c in packages.items() if not rel.startswith(pkg)))
        if hits := _probes(ast.parse(path.read_text()), concrete, optional):
            found[rel] = hits
    assert not found, f"ask rapidds.worlds.capabilities.capability(world, NAME) instead: {found}"


def test_the_probe_check_sees_each_way_of_probing() -> None:
    concrete, optional = {"FetchWorld", "PaintingWorld"}, _optional_members()
    assert {"physics_model", "robot_duration", "joint_names", "tracking_mapping",
            "priming_factors", "home"} <= optional
    for code in ("isinstance(w, FetchWorld)", "isinstance(w, (int, PaintingWorld))",
                 'getattr(world, "robot_duration", None)', 'hasattr(self.world, "physics_model")',
                 'getattr(w, "joint_names")'):
        assert _probes(ast.parse(code), concrete, optional), code
    for code in ("isinstance(w, World)", 'getattr(module, "main")', "getattr(w, name)"):
        assert not _probes(ast.parse(code), concrete, optional), code
