"""evtools: event-camera (DVS) noise toolkit - simulate, filter, estimate and correct contrast thresholds.

The Python API (:mod:`evtools.api`): :func:`read`, :func:`open`, :func:`write`, :func:`writer` for files;
:func:`simulate`, :func:`inject_noise`, :func:`bafilter`, :func:`estimate`, :func:`correct` - the command line's
processors on arrays; :func:`to_columns`, :func:`from_columns`, :func:`to_tonic`, :func:`from_tonic`,
:func:`to_dv`, :func:`from_dv` - conversions; :mod:`evtools.metrics` - the measures.

The names are loaded on first use (PEP 562), so that ``import evtools.cli.main`` runs before numpy is imported:
the command line sets numpy's thread defaults first (see :func:`evtools.cli.main.main`).
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING

from evtools.errors import EvtoolsError, InvalidEventsError

__version__ = "0.1.0"

__all__ = [
    "CHUNK_EVENTS", "EVENT_DTYPE", "EvtoolsError", "Frame", "InvalidEventsError", "StreamChecker", "StreamInfo",
    "bafilter", "correct", "estimate", "from_columns", "from_dv", "from_tonic", "inject_noise", "make_events",
    "open", "read", "simulate", "to_columns", "to_dv", "to_tonic", "write", "writer", "ReadOptions",
]
_EVENTS = {"CHUNK_EVENTS", "EVENT_DTYPE", "StreamChecker", "StreamInfo", "make_events"}
_HOME = {name: "evtools.events" if name in _EVENTS else "evtools.api" for name in __all__
         if name not in ("EvtoolsError", "InvalidEventsError")}
_HOME["Frame"] = "evtools.frames"
_HOME["ReadOptions"] = "evtools.formats"
"""The module each lazily loaded name lives in."""

if TYPE_CHECKING:  # what type checkers and editors see
    from evtools.api import (bafilter, correct, estimate, from_columns, from_dv, from_tonic, inject_noise, open,
                             read, simulate, to_columns, to_dv, to_tonic, write, writer)
    from evtools.events import CHUNK_EVENTS, EVENT_DTYPE, StreamChecker, StreamInfo, make_events
    from evtools.formats import ReadOptions
    from evtools.frames import Frame


def __getattr__(name: str):
    """``evtools.read`` and the other names of ``__all__``, imported from their module on first use; a submodule
    (``evtools.metrics``, ``evtools.events``, ...) likewise."""
    if name in _HOME:
        module = importlib.import_module(_HOME[name])
        if name in getattr(module, "PROCESSORS", ()):
            module.document_processors()
        value = getattr(module, name)
        globals()[name] = value
        return value
    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module 'evtools' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
