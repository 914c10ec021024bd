"""Errors a user can act on. The CLI turns each into one line on stderr and exit code 2."""


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
