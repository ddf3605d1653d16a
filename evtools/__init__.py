"""evtools: event-camera (DVS) noise toolkit - simulate, filter, estimate and correct contrast thresholds.

The Python API (:mod:`evtools.api`): :func:`read`, :func:`open`, :func:`write`, :func:`writer` for files;
:func:`simulate`, :func:`inject_noise`, :func:`bafilter`, :func:`estimate`, :func:`correct` - the command line's
processors on arrays; :func:`to_columns`, :func:`from_columns`, :func:`to_tonic`, :func:`from_tonic`,
:func:`to_dv`, :func:`from_dv` - conversions; :mod:`evtools.metrics` - the measures.
"""

from evtools.api import (
    bafilter,
    correct,
    estimate,
    from_columns,
    from_dv,
    from_tonic,
    inject_noise,
    open,
    read,
    simulate,
    to_columns,
    to_dv,
    to_tonic,
    write,
    writer,
)
from evtools.errors import EvtoolsError, InvalidEventsError
from evtools.events import CHUNK_EVENTS, EVENT_DTYPE, StreamChecker, StreamInfo, make_events

__version__ = "0.1.0"
__all__ = [
    "CHUNK_EVENTS", "EVENT_DTYPE", "EvtoolsError", "InvalidEventsError", "StreamChecker", "StreamInfo",
    "bafilter", "correct", "estimate", "from_columns", "from_dv", "from_tonic", "inject_noise", "make_events",
    "open", "read", "simulate", "to_columns", "to_dv", "to_tonic", "write", "writer",
]
