"""Example problems shipped inside the package, so ``rapidds plan fetch`` works from any folder
and from an installed wheel, not only from a checkout that has ``examples/``.

The package is installed as plain files (editable or wheel, never zipped), so the bundled YAML
files have real paths and can be handed to :func:`rapidds.problem.load_problem`.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from rapidds.errors import ProblemError


def examples_dir() -> Path:
    """Folder holding the bundled ``*.yaml`` problems."""
    return Path(str(files("rapidds") / "examples"))


def example_names() -> list[str]:
    """Names of the bundled problems (file stems), sorted."""
    return sorted(p.stem for p in examples_dir().glob("*.yaml"))


def example_path(name: str) -> Path:
    """Path of bundled problem ``name`` (``"fetch"`` or ``"fetch.yaml"``); ProblemError if none."""
    stem = name.removesuffix(".yaml")
    path = examples_dir() / f"{stem}.yaml"
    if "/" in stem or not path.is_file():
        raise ProblemError(
            f"no bundled example '{name}' (bundled: {', '.join(example_names()) or 'none'})"
        )
    return path


def resolve_problem(arg: str | Path) -> Path:
    """A problem argument as the user typed it: an existing file wins, then a bundled name.

    Anything else is reported as a missing file, listing the bundled names as a hint.
    """
    path = Path(arg)
    if path.exists():
        return path
    stem = str(arg).removesuffix(".yaml")
    if "/" not in stem and stem in example_names():
        return example_path(stem)
    raise ProblemError(
        f"{arg}: no such file or bundled example (bundled: {', '.join(example_names())})"
    )
