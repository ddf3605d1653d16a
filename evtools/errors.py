"""Errors raised by evtools' library code; ``cli/`` turns them into one-line messages and exit code 1."""


class EvtoolsError(Exception):
    """Base class of every error that evtools reports to a user (never a bug)."""


class UsageMistake(EvtoolsError):
    """Mixed into an error that is a mistake in how a command was called (an output whose extension names no
    format, an unknown scene), found only once its value is used: the command line exits 2 for it, as for every
    usage error, and 1 for errors in the data."""


class InvalidEventsError(EvtoolsError, ValueError):
    """An event stream breaks the event model: coordinates outside the sensor, time going backwards, ..."""
