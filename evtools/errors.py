"""Errors raised by evtools' library code; ``cli/`` turns them into one-line messages and exit code 1."""


class EvtoolsError(Exception):
    """Base class of every error that evtools reports to a user (never a bug)."""


class InvalidEventsError(EvtoolsError, ValueError):
    """An event stream breaks the event model: coordinates outside the sensor, time going backwards, ..."""
