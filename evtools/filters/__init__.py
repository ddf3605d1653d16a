"""Background-activity filters as stream processors (``docs/algorithms.md`` section 2).

:class:`BAFilter` runs one or several stages in order (``"hotpixel,refractory,stcf"``); each stage sees only the
events that the stages before it kept, so its time map never holds an event an earlier stage rejected. Within a
stage, a rejected event still writes its time (as every reference implementation does). :func:`ba_filter` is the
one-shot convenience.

One module a method (``baf`` the report's filter, Delbruck 2008; ``stcf`` jAER's SpatioTemporalCorrelationFilter;
``dwf`` Guo & Delbruck 2022; ``orderN`` Khodamoradi & Kastner 2018; ``refractory``; ``hotpixel``; ``mlpf``), each
a :class:`~evtools.filters.spec.Filter` whose parameters are declared once (:class:`~evtools.filters.spec.Param`);
:data:`~evtools.filters.registry.REGISTRY` lists them, and the command line, the checks, ``metrics roc``'s sweeps,
the README's table and the API's signature come from there.

Presets (start-up behaviour and defaults):

- ``evtools`` (default): maps start "long ago", so nothing is supported by a phantom past; windows start empty.
- ``dv``: dv-processing's BackgroundActivityNoiseFilter (``baf`` only): the time map starts at 0 (every event
  with ``t < dt`` passes), ``dt`` 2 ms, ``t - T < dt``, self excluded, clipped at the border. Verified
  event for event against dv-processing 2.0.
- ``jaer``: jAER (2024 sources): correlation time 25 ms; the first event of every pixel is rejected
  (letFirstEventThrough off); STCF k = 2, polarities must match, and jAER's window clipping (the last ``r``
  columns/rows never count as neighbours); DWF windows of 256 (wlen 512), distance 5, k = 1, its first 512
  events rejected (the first 256 fill the kept window) and the rejected window pre-filled with (-1, -1);
  orderN counts the pixel itself and rejects (without storing) events on the sensor's border; refractory
  drops ``t - T <= dt``. jAER's 32-bit time wrap is not reproduced (times are int64 here).

References
----------
T. Delbruck, "Frame-free dynamic digital vision", Proc. Intl. Symp. on Secure-Life Electronics, 2008.
S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI 45(1), 2023.
A. Khodamoradi, R. Kastner, "O(N)-Space Spatiotemporal Filter for Reducing Noise in Neuromorphic Vision
Sensors", IEEE Trans. Emerging Topics in Computing 9(1), 2021.
"""

from evtools.filters.chain import BAFilter, ba_filter, check_preset, not_applying, parse_methods
from evtools.filters.hotpixel import MAX_LEARN_EVENTS, learn_hot_pixels
from evtools.filters.registry import BY_NAME, METHODS, REGISTRY
from evtools.filters.spec import PRESETS, BAFilterError, Filter, Param

__all__ = ["METHODS", "PRESETS", "REGISTRY", "BY_NAME", "BAFilter", "BAFilterError", "Filter", "Param", "ba_filter",
           "check_preset", "learn_hot_pixels", "not_applying", "parse_methods", "MAX_LEARN_EVENTS"]
