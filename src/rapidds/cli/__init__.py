"""``rapidds`` command line. Each submodule registers its commands on :data:`app`.

Errors a user can fix (:class:`~rapidds.errors.RapiddsError`) become one line on stderr and exit
code 2; typer's own usage errors also exit 2.
"""

from __future__ import annotations

import sys

import typer

try:  # typer >= 0.24 vendors click; its exceptions are not click's
    from typer._click import exceptions as _cx
except ImportError:  # pragma: no cover - older typer on top of click
    import click.exceptions as _cx  # type: ignore[no-redef]

from rapidds.errors import RapiddsError

app = typer.Typer(
    name="rapidds",
    help="Adaptive human-robot team planning: schedules, steered robot motion, learned teammates.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """Adaptive human-robot team planning: schedules, steered robot motion, learned teammates."""


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
        rc = app(standalone_mode=False)
    except RapiddsError as exc:
        typer.echo(f"rapidds: error: {exc}", err=True)
        sys.exit(2)
    except _cx.NoArgsIsHelpError:
        sys.exit(0)  # typer has printed the help already
    except _cx.UsageError as exc:
        # One line, not click's boxed usage panel; the hint names the right --help.
        where = exc.ctx.command_path if exc.ctx else "rapidds"
        typer.echo(f"rapidds: error: {exc.format_message()} (see '{where} --help')", err=True)
        sys.exit(2)
    except _cx.ClickException as exc:
        typer.echo(f"rapidds: error: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except _cx.Abort:
        typer.echo("rapidds: interrupted", err=True)
        sys.exit(130)
    sys.exit(rc if isinstance(rc, int) else 0)
