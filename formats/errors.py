"""Errors of the readers and writers."""

from evtools.errors import EvtoolsError, UsageMistake


class FormatError(EvtoolsError, ValueError):
    """A file is not what its format says (wrong magic, truncated, missing datasets, ...) or cannot be written."""


class UnknownOutputFormat(FormatError, UsageMistake):
    """An output path whose extension names no format, and no ``--format``: a usage mistake (exit 2)."""


class OutputCannotTakeFormat(FormatError, UsageMistake):
    """An output the format cannot go to, chosen on the command line (HDF5 on stdout, binary on a terminal): a usage
    mistake (exit 2)."""


class StreamReadAgain(EvtoolsError, RuntimeError):
    """An :class:`~evtools.formats.EventStream` iterated a second time: a stream is read once, as it comes (a pipe
    or socket cannot go back), so the second pass would see nothing, or the middle of the file."""
