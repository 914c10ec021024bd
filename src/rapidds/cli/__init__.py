"""``rapidds`` command line. Each submodule registers its commands on :data:`app`.

Errors a user can fix (:class:`~rapidds.errors.RapiddsError`, typer's usage errors, a file the
system refuses) become one line on stderr and exit code 2; a runtime fault
(:class:`~rapidds.errors.RuntimeFault`: a cycle that cannot progress) one line and exit code 3;
a closed pipe ends the output quietly; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys

import typer

from rapidds.errors import RapiddsError, RuntimeFault, os_error_line

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


PANELS: dict[str, tuple[str, ...]] = {
    "Run the loop": ("run", "demo", "play", "worlds"),
    "Plan and move": ("plan", "sample", "train-policy"),
    "A real cell": ("deploy", "sim-robot", "sim-human", "export", "plan-next", "observe"),
    "Experiments": ("ablation", "report", "case-study", "study"),
    "People": ("gamma",),
}
"""How ``rapidds --help`` groups the commands, in this order."""


def one_paragraph_lines(text: str | None) -> str | None:
    """A docstring as help: the lines of each paragraph joined, so that the help wraps whole
    sentences to the terminal instead of breaking where the source broke its lines."""
    if text is None:
        return None
    import inspect

    return "\n\n".join(" ".join(p.split()) for p in inspect.cleandoc(text).split("\n\n"))


def _register() -> None:
    """Import the command modules (each adds its commands to ``app``), then group the commands
    in ``rapidds --help`` (:data:`PANELS`) with their help as whole sentences."""
    import importlib
    import pkgutil

    for mod in pkgutil.iter_modules(__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"{__name__}.{mod.name}")
    order = [name for names in PANELS.values() for name in names]
    panel = {name: title for title, names in PANELS.items() for name in names}
    commands = list(app.registered_commands)
    for info in [*app.registered_commands, *app.registered_groups]:
        info.rich_help_panel = panel.get(str(info.name), "Other")
        commands += getattr(getattr(info, "typer_instance", None), "registered_commands", [])
    for command in commands:
        if command.help is None and command.callback is not None:
            command.help = one_paragraph_lines(command.callback.__doc__)
    app.registered_commands.sort(key=lambda c: order.index(c.name) if c.name in order else 99)


def _typer_errors(name: str) -> tuple[type[BaseException], ...]:
    """Every exception class called ``name`` the installed typer can raise. typer >= 0.24 vendors
    click as ``typer._click`` (Abort and Exit then live in ``typer.exceptions``); older typer
    raises click's own. Looked up by name in whichever layout is installed."""
    layouts = (("typer._click.exceptions", "typer.exceptions")
               if importlib.util.find_spec("typer._click") else ("click.exceptions",))
    found: list[type[BaseException]] = []
    for module in layouts:
        cls = getattr(importlib.import_module(module), name, None)
        if isinstance(cls, type) and issubclass(cls, BaseException) and cls not in found:
            found.append(cls)
    return tuple(found)


def _quiet_broken_pipe() -> None:
    """The reader of stdout went away (``rapidds ... | head``): stop without a word. stdout is
    pointed at /dev/null first so the interpreter's final flush cannot fail a second time (the
    recipe of the Python docs, "Note on SIGPIPE"); exit 1, as Python itself does on EPIPE."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout has no file descriptor (already replaced)
        pass
    sys.exit(1)


def main() -> None:
    no_args = _typer_errors("NoArgsIsHelpError")
    usage = _typer_errors("UsageError")
    click_error = _typer_errors("ClickException")
    abort = _typer_errors("Abort")
    try:
        _register()
        rc = app(standalone_mode=False)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at interpreter exit
    except RuntimeFault as exc:  # before its base class: a runtime fault exits 3
        typer.echo(f"rapidds: error: {exc}", err=True)
        sys.exit(3)
    except RapiddsError as exc:
        typer.echo(f"rapidds: error: {exc}", err=True)
        sys.exit(2)
    except no_args:
        sys.exit(0)  # typer has printed the help already
    except usage as exc:
        # One line, not click's boxed usage panel; the hint names the right --help.
        ctx = getattr(exc, "ctx", None)
        where = ctx.command_path if ctx else "rapidds"
        typer.echo(f"rapidds: error: {exc.format_message()} (see '{where} --help')", err=True)
        sys.exit(2)
    except click_error as exc:
        typer.echo(f"rapidds: error: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except (*abort, KeyboardInterrupt):
        typer.echo("rapidds: interrupted", err=True)
        sys.exit(130)
    except BrokenPipeError:
        _quiet_broken_pipe()
    except OSError as exc:  # read-only file system, a file where a folder must be, no space...
        typer.echo(f"rapidds: error: {os_error_line(exc)}", err=True)
        sys.exit(2)
    sys.exit(rc if isinstance(rc, int) else 0)
