"""Errors a user can act on. The CLI turns each into one line on stderr and exit code 2."""


class RapiddsError(Exception):
    """Base class for errors caused by the user's input, not by a bug."""


class ProblemError(RapiddsError):
    """A problem file is missing, malformed or describes an impossible job."""


class CheckpointError(RapiddsError):
    """A model checkpoint is missing, corrupt or does not fit the request."""


class StateError(RapiddsError):
    """Stored state (a run database, a saved model) is corrupt or inconsistent."""


class StudyDesignError(RapiddsError):
    """A user-study design is impossible (e.g. cannot be balanced) or its file is malformed."""


class StudyDataError(RapiddsError):
    """A study data table lacks columns, holds NaN, or is unbalanced for the analysis asked."""
