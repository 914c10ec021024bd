"""``rapidds`` command line. Each submodule registers its commands on :data:`app`.

Errors a user can fix (:class:`~rapidds.errors.RapiddsError`) become one line on stderr and exit
code 2; typer's own usage errors also exit 2.
"""

from __future__ import annotations

import sys

import typer

from rapidds.errors import RapiddsError

app = typer.Typer(
    name="rapidds",
    help="Adaptive human-robot team planning: schedules, steered robot motion, learned teammates.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def fail(message: str) -> None:
    """Stop with one clear line and exit code 2 (bad input)."""
    typer.echo(f"rapidds: error: {message}", err=True)
    raise typer.Exit(2)


def _register() -> None:
    # Imported for their side effect of adding commands to ``app``.
    import importlib
    import pkgutil

    for mod in pkgutil.iter_modules(__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"{__name__}.{mod.name}")


def main() -> None:
    _register()
    try:
        app()
    except RapiddsError as exc:
        typer.echo(f"rapidds: error: {exc}", err=True)
        sys.exit(2)
