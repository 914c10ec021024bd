"""Errors a user can act on. The CLI turns each into one line on stderr and exit code 2."""

from __future__ import annotations

import os


class RapiddsError(Exception):
    """Base class for errors caused by the user's input, not by a bug."""


class ProblemError(RapiddsError):
    """A problem file is missing, malformed or describes an impossible job."""


class CheckpointError(RapiddsError):
    """A model checkpoint is missing, corrupt or does not fit the request."""


class StateError(RapiddsError):
    """Stored state (a run database, a saved model) is corrupt or inconsistent."""


class ConfigError(RapiddsError, ValueError):
    """A setting is out of range or inconsistent.

    Both a :class:`RapiddsError` (the CLI prints one line, exit 2) and a ``ValueError`` (what
    Python code expects from a rejected argument).
    """


def os_error_line(exc: OSError) -> str:
    """One line for an error of the file system: the path(s), then what the system said, e.g.
    ``/media/out/.lock: Read-only file system``."""
    what = exc.strerror or str(exc) or type(exc).__name__
    if exc.filename is None:
        return what
    where = os.fsdecode(exc.filename)
    if exc.filename2 is not None:
        where += f" -> {os.fsdecode(exc.filename2)}"
    return f"{where}: {what}"


class StudyDesignError(RapiddsError):
    """A user-study design is impossible (e.g. cannot be balanced) or its file is malformed."""


class StudyDataError(RapiddsError):
    """A study data table lacks columns, holds NaN, or is unbalanced for the analysis asked."""


class RuntimeFault(RapiddsError):
    """The run could not go on for a reason that is not in its input (a cycle that cannot
    progress, a cell that stopped): the CLI prints one line and exits with code 3, not 2.
    A :class:`RapiddsError` still, so every caller that reports a user's error reports it."""
