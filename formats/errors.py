"""Errors of the readers and writers."""

from evtools.errors import EvtoolsError


class FormatError(EvtoolsError, ValueError):
    """A file is not what its format says (wrong magic, truncated, missing datasets, ...) or cannot be written."""
