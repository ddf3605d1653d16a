"""evtools: event-camera (DVS) noise toolkit - simulate, filter, estimate and correct contrast thresholds."""

from evtools.errors import EvtoolsError, InvalidEventsError
from evtools.events import CHUNK_EVENTS, EVENT_DTYPE, StreamChecker, StreamInfo, make_events

__version__ = "0.1.0"
__all__ = ["CHUNK_EVENTS", "EVENT_DTYPE", "EvtoolsError", "InvalidEventsError", "StreamChecker", "StreamInfo", "make_events"]
