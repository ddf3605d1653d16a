"""Threshold-correction kernels: re-sample every pixel's events at one target threshold, and release them in order.

Each pixel's events are read as samples of its log intensity: event j moves the reconstruction by the pixel's own
``+on`` or ``-off`` threshold. The pixel keeps ``level``, the reconstruction minus the corrected (re-sampled)
reference. Between two points of the reconstruction the signal is a straight line (first-order hold); every time
``level`` reaches ``+target_on`` (``-target_off``) an ON (OFF) event is emitted at the exact crossing time on that
line and the reference moves by the target threshold; what is left over is carried on (the report's eq. 15).

Where the line of event j starts (``mode``):

- ``MODE_FOH`` (0): at the pixel's previous event, never before ``t_j - max_gap_us`` (the bound that keeps the
  reordering window finite); a pixel's first event has no predecessor: its crossings are at its own time;
- ``MODE_STEP`` (1): as FOH when the gap is at most ``hold_us``; over a longer gap (a rest) the signal is held
  constant until ``t_j``, so every crossing of event j is at ``t_j`` (the report's step-aware variant);
- ``MODE_HIGHPASS`` (2): as STEP, and over a rest the carried ``level`` decays by ``exp(-(gap - hold_us) /
  tau_us)`` (after a reversed run's excess, which came before the rest), so the level error that inexact
  thresholds add with every event is forgotten at every rest.

With ``turns`` (on in the ``turns`` and ``highpass`` modes of the corrector) the reconstruction is also

- anchored: every pixel's reconstruction starts at level 0 (its reference) at the stream's start (the caller sets
  ``last_us`` of every pixel to that time), so the crossings of its first event are interpolated too (unless the
  first event comes after a rest);
- turned, consistently: after its latest event a pixel's log intensity stayed within one threshold of its
  reference (it would have fired otherwise), so at a reversal the extremum lies beyond the run's last level by at
  least 0 and less than the run's threshold. The segment that ends at a reversal waits for the pixel's next event
  (the slope after the turn). Where the run before the turn is straight (its last two intervals within 1 %, as
  on a ramp linear in log intensity, where consecutive events are one threshold apart) the extremum is where the
  run's line and the new ramp's line meet (:func:`_resolve`): exact on piecewise log-linear signals with exact
  thresholds, as long as that point is consistent. Otherwise (a curved run, as on natural scenes, where those
  lines meet beyond the true extremum and re-sampling the overshoot invents events; a run of one event; a
  meeting point the pixel would have fired at) the extremum is the expected value over the consistent interval,
  half the run's threshold beyond its last level, reached at the time the two runs' slopes (scaled to fill the
  gap) put it. A reversal over a rest, and every pixel when the stream ends (:func:`finish_runs`), get the run's
  expected excess (:func:`_run_excess`: half a threshold; after a slowing run with ``curves``, its approach's rest;
  none after a re-sampled tail) at the run's slope after its last event, no earlier than three windows before the
  event (the latency with turns). The first ramp is extended back to the start level along its line.

Every re-sampled event lies after the start of the segment it belongs to: the pixel's previous event, or
``max(origin, t_j - max_gap_us)``; a waiting segment starts at most ``window_us`` before its event and waits at
most ``window_us`` (the ordering argument of :class:`evtools.correction.ThresholdCorrector`).
Pixels whose ``use`` flag is False pass through unchanged. ``tests/naive/correct.py`` holds the pure-Python
reference.

References
----------
The founding report, section 4.2 (FOH re-sampling) and 5.2 (step-aware variant).
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018
(the high-pass filter whose exponential decay ``MODE_HIGHPASS`` applies to the carried level).
"""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels.jit import kernel
from evtools._kernels.prefetch import prefetch

MODE_FOH = 0
MODE_STEP = 1
MODE_HIGHPASS = 2

NO_EVENT_US = (1 << 63) - 1
"""``last_us`` of a pixel that has not fired yet (the largest int64, so a minimum over pixels ignores it)."""


ON_BIT = 1 << 32
"""The polarity bit of an event's second 8-byte word (x int16 at byte 8, y int16 at byte 10, p bool at byte 12)."""


@kernel(inline=True)
def _crossings(level, delta, off0, span, shrink, tau, t_b, xy, target_on, target_off, out_t, out_w, n):
    """Re-sample the segment from ``(t_b + off0, level)`` to ``(t_b + off0 + span, level + delta)``: an event
    wherever it reaches the next target level; returns (level, n).

    ``tau`` 0: a straight line. Otherwise the exponential approach with time constant ``tau`` us, ``level + delta
    (1 - exp(-s / tau)) / shrink`` at ``s`` us, ``shrink = 1 - exp(-span / tau)``: ``log`` rather than
    ``log1p`` (rounding ``1 - z`` moves a crossing by about ``tau * 1e-16`` us, and ``log`` is the faster); a
    crossing at the segment's end (``z = shrink``) is at ``span``, also where ``exp(-span / tau)`` underflows
    (``shrink`` 1, ``z`` 1: ``log(0)``) or rounding puts ``z`` past ``shrink``.

    ``xy`` is the pixel's x and y as the low 32 bits of an event's second word; created events are written as
    (time, word) pairs."""
    if delta == 0.0:
        return level, n
    scale = shrink / delta if tau > 0.0 else 0.0
    # ON (delta > 0) and OFF alike with the sign: -(k * target) and (-k) * target are the same float, so this is
    # bit for bit the two branches it replaces
    sign = 1.0 if delta > 0.0 else -1.0
    target = target_on if delta > 0.0 else target_off
    word = xy | ON_BIT if delta > 0.0 else xy
    k = 1.0
    while sign * (level + delta) >= k * target:
        step = sign * k * target - level  # the change to the next crossing, of delta's sign
        if tau > 0.0:
            rest = 1.0 - step * scale
            s = min(-tau * math.log(rest), span) if rest > 0.0 else span
        else:
            s = step / delta * span
        out_t[n] = t_b + np.int64(math.floor(off0 + s + 0.5))
        out_w[n] = word
        n += 1
        k += 1.0
    return level + delta - sign * (k - 1.0) * target, n


@kernel(inline=True)
def _segment(level, delta, off0, off1, t_b, xy, target_on, target_off, out_t, out_w, n):
    """Re-sample the line from ``(t_b + off0, level)`` to ``(t_b + off1, level + delta)``; returns (level, n)."""
    return _crossings(level, delta, off0, off1 - off0, 1.0, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)


AHEAD = 16
"""How many events ahead the kernel prefetches a pixel's state (events hit random pixels: 20 % faster on the
bench stream than a plain load ahead, which was itself 20 % faster than none)."""

PIXEL_DTYPE = np.dtype([("level", np.float64), ("last_us", np.int64), ("interval_us", np.float32),
                        ("pending_us", np.int32), ("on", np.float32), ("off", np.float32)])
"""Per-pixel state, 32 bytes (one cache line holds two pixels, so an event touches one): the carried level (at the
start of the pending segment while one waits), the latest event's time (NO_EVENT_US before the first; the stream's
start with turns), the time between the current run's last two events (its slope is one threshold per that
interval; 0 when unknown: one event so far, or after a rest), the length of the pending segment (its start is ``last_us - pending_us``), and
the pixel's thresholds (float32, the maps' precision). While nothing is pending, ``pending_us`` holds the
run's interval before ``interval_us`` (0 unknown), so that a turn knows whether the run was straight."""

SETTLED = 1
"""``status`` of a pixel (int8, signed by its latest event's polarity, 0 before the first): nothing pending."""
TURN = 2
"""``status``: the latest event reversed the run; its segment waits for the next event (the slope after the turn)."""
LINES = 5
"""``status``: as :data:`TURN`, after a straight run (its last two intervals within :data:`MIN_CURVE_RATIO`): the
extremum is where the lines of the runs on both sides meet, if that is consistent."""
FIRST = 3
"""``status``: the pixel's first event (reconstruction anchored at the stream's start); its segment waits for the
next event (the slope of the first ramp, to extrapolate it back)."""

TAIL = 4
"""``status`` (``curves``): the latest event continued a run that slows down as an exponential approach whose rest
(up to its asymptote) crosses a target level that the pixel's own next threshold lies beyond; the tail waits a
window for the pixel's next event: if one comes the run went on (the tail is dropped), else it is re-sampled.
While a pixel waits so, ``pending_us`` holds the approach's time constant (us) instead of a segment length."""

MIN_CURVE_RATIO = 1.01
"""``curves``: a run's segment is an exponential approach when its interval exceeds the run's previous one by more
than this factor; intervals within 1 % (or shrinking) give a straight line."""

TAIL_TAUS = 3.0
"""``curves``: a tail is re-sampled over at most this many time constants after the run's last event (95 % of the
approach); later crossings lie where the distance left to the asymptote is within the fit's own error (a target
level at the asymptote itself would fire at a time set by rounding)."""

TAILED = -1.0
"""``interval_us`` of a pixel whose run ended in a re-sampled tail (its excess beyond the last event is modelled:
a reversal over a rest adds none)."""

MAX_TAU_US = 2**31 - 1
"""The longest time constant kept (it waits in ``pending_us``, 32 bits)."""

@kernel(inline=True)
def _within(interval_a, interval_b):
    """Whether two positive intervals agree within :data:`MIN_CURVE_RATIO` (a straight run)."""
    return max(interval_a, interval_b) <= MIN_CURVE_RATIO * min(interval_a, interval_b)


def _shape_table(cells: int) -> np.ndarray:
    """``y / (1 - x)`` at ``x = 1 / ratio = k / cells``, ``y`` the positive root of ``exp(y) + exp(-ratio y) = 2``:
    Newton's method from ``ln 2`` (right of the root, where the convex function rises, so it converges
    monotonically), all cells at once; the ends are the limits ln 2 (``ratio`` infinite) and 1 (``ratio`` -> 1)."""
    x = np.arange(1, cells) / cells
    ratio = 1.0 / x
    y = np.full(cells - 1, math.log(2.0))
    for _ in range(100):
        y = y - (np.expm1(y) + np.expm1(-ratio * y)) / (np.exp(y) - ratio * np.exp(-ratio * y))
    return np.concatenate([[math.log(2.0)], y / (1.0 - x), [1.0]])


_SHAPE_CELLS = 4096
_SHAPE = _shape_table(_SHAPE_CELLS)
"""The root ``y`` of :func:`_approach_rate`'s equation as ``y / (1 - x)`` (smooth, from ln 2 to 1) over ``x = 1 /
ratio``: cubic interpolation in it is within 2e-11 of the root (relative), so the time constant rounded to whole
us is the root's but where the root lies within 2e-11 of a half us."""


@kernel(inline=True)
def _approach_tau(interval_a, interval_b):
    """The time constant ``tau`` (us) of the exponential approach ``L_inf - B exp(-t / tau)`` through three events
    one threshold apart, ``interval_a`` then ``interval_b`` apart (``interval_b > interval_a > 0``).

    Equal level steps give ``exp(-t1/tau) - exp(-t2/tau) = exp(-t2/tau) - exp(-t3/tau)``, i.e. with ``y =
    interval_a / tau`` and ``r = interval_b / interval_a``: ``exp(y) + exp(-r y) = 2``, its root interpolated
    (cubic Lagrange, four cells) in the table :data:`_SHAPE`: no transcendental function."""
    x = interval_a / interval_b
    where = x * _SHAPE_CELLS
    cell = min(max(int(where), 1), _SHAPE_CELLS - 2)
    f = where - cell
    p0 = _SHAPE[cell - 1]
    p1 = _SHAPE[cell]
    p2 = _SHAPE[cell + 1]
    p3 = _SHAPE[cell + 2]
    shape = p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0)))
    return interval_a / ((1.0 - x) * shape)


TAIL_SHARE = -math.expm1(-TAIL_TAUS)
"""``1 - exp(-TAIL_TAUS)``: the share of an approach's rest that a tail of ``TAIL_TAUS`` time constants covers."""


@kernel(inline=True)
def _covered(span, tau_us):
    """``1 - exp(-span / tau)``: how much of an exponential approach's rest the ``span`` us after an event cover
    (the rest at an event that ended a rise by ``theta`` over an interval is ``theta / (exp(interval / tau) -
    1)``)."""
    return TAIL_SHARE if span >= TAIL_TAUS * tau_us else -math.expm1(-span / tau_us)


@kernel(inline=True)
def _resolve(level, t_b, pending_us, kind, up, interval_a, interval_b, theta_on, theta_off, xy, target_on,
             target_off, out_t, out_w, n):
    """Re-sample the pending segment that ends at the event ``(t_b, up)``; returns (level, n).

    A ramp's slope is one threshold per interval between its events: ``interval_b`` is that of the ramp the event
    starts (the time to the next event; 0: unknown, the ramp has a single event), ``interval_a`` that of the run
    before a turn (0: unknown).

    - ``FIRST``: the first ramp, extended back to the pixel's start level, starts ``interval_b`` before ``t_b``
      (the signal held its start level until then), never before the anchor ``pending_us`` back; with the interval
      unknown, the line from the anchor (the hold of the report).
    - ``TURN`` / ``LINES``: the extremum lies ``excess`` beyond the run's last level ``R`` (at ``t_a``), with ``0
      <= excess < theta_a`` (the consistency rule), and ``u`` after ``t_a``. ``LINES`` (a straight run): the
      intersection of the run's line through ``(t_a, R)`` and the new ramp's line through ``(t_b, R -/+
      theta_b)``: with ``G = t_b - t_a`` and ``D = theta_a interval_b + theta_b interval_a`` it lies ``u = theta_b
      (G - interval_b) interval_a / D`` after ``t_a`` and ``theta_a theta_b (G - interval_b) / D`` beyond ``R`` (0
      when ``G <= interval_b``). ``TURN``, or a meeting point at or past ``theta_a`` (the pixel would have fired
      again): ``excess = theta_a / 2``, the expected value over the consistent interval, at the ``u`` where the
      time to rise by it at the run's slope and to fall to the event's level at the new ramp's slope, scaled to
      fill ``G``, meet. A slope not known takes the other's; with neither, both are the slope that turns half a
      threshold beyond ``R``.
    """
    theta_b = theta_on if up else theta_off
    d = theta_b if up else -theta_b
    gap = float(pending_us)
    if kind == FIRST:
        back = min(gap, interval_b) if interval_b > 0.0 else gap
        return _segment(level, d, -back, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)
    theta_a = theta_off if up else theta_on  # the run before the turn went the other way
    if interval_a <= 0.0 and interval_b <= 0.0:
        interval_a = theta_a * gap / (theta_a + theta_b)
        interval_b = theta_b * gap / (theta_a + theta_b)
    elif interval_a <= 0.0:
        interval_a = theta_a * interval_b / theta_b
    elif interval_b <= 0.0:
        interval_b = theta_b * interval_a / theta_a
    u = 0.0
    excess = 0.0
    lines = kind == LINES
    if lines and gap > interval_b:
        scale = theta_b * (gap - interval_b) / (theta_a * interval_b + theta_b * interval_a)
        u = scale * interval_a
        excess = scale * theta_a
        if scale >= 1.0:  # at the next level: a turn there within the precision of whole-us times, else curved
            lines = scale <= MIN_CURVE_RATIO
            u = interval_a
            excess = theta_a
    if not lines:
        excess = 0.5 * theta_a
        rise = excess * interval_a / theta_a
        both = rise + (excess + theta_b) * interval_b / theta_b  # 0 only when the gap is (both slopes unknown)
        u = gap * rise / both if both > 0.0 else 0.0
    run = -1.0 if up else 1.0
    level, n = _segment(level, run * excess, -gap, u - gap, t_b, xy, target_on, target_off, out_t, out_w, n)
    return _segment(level, d - run * excess, u - gap, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)


@kernel(inline=True)
def _room(level, theta_on, theta_off, per_target):
    """The most events one input event can create at a pixel: a pending segment (the carried level, an extremum
    below one threshold, the event's threshold) and the event's own segment (``per_target``: 1 / the smaller
    target; a product, not a division, in the per-event loop, and the + 6 covers its rounding)."""
    return (abs(level) + 3.0 * (theta_on + theta_off)) * per_target + 6.0


@kernel(inline=True)
def _settle(state, status, pixel, xy, interval_b, span_us, target_on, target_off, out_t, out_w, n):
    """Re-sample the pending segment of ``pixel`` (at ``xy``, the low word of its events; ``interval_b`` the time
    from its event to the next of the same polarity, 0 unknown), or its tail over the ``span_us`` after its event;
    returns n.

    Afterwards the pixel's level is at its latest event (a tail's crossings move the corrected reference, the
    level returns to the pixel's own reference level, from which its next event counts) and its run's interval is
    known only for a first ramp resolved by its anchored line (the line from the anchor is then that ramp)."""
    row = state[pixel]
    up = status[pixel] > 0
    kind = abs(status[pixel])
    theta_on = float(row.on)
    theta_off = float(row.off)
    if kind == TAIL:
        tau = float(row.pending_us)
        span_us = min(span_us, TAIL_TAUS * tau)
        share = _covered(span_us, tau)
        tail = (theta_on if up else theta_off) / math.expm1(float(row.interval_us) / tau) * share
        tail = tail if up else -tail
        level, n = _crossings(row.level, tail, 0.0, span_us, share, tau, row.last_us, xy, target_on, target_off,
                              out_t, out_w, n)
        row.level = level - tail
        row.interval_us = TAILED
        row.pending_us = 0
        status[pixel] = SETTLED if up else -SETTLED
        return n
    row.level, n = _resolve(row.level, row.last_us, row.pending_us, kind, up, float(row.interval_us), interval_b,
                            theta_on, theta_off, xy, target_on, target_off, out_t, out_w, n)
    # a first ramp whose line back meets the anchor (or of one event: the line from the anchor is the ramp) is a
    # straight run so far, its interval the anchored segment's
    anchored = kind == FIRST and (interval_b == 0.0 or _within(interval_b, float(row.pending_us)))
    row.interval_us = row.pending_us if anchored else 0.0
    row.pending_us = row.pending_us if anchored else 0
    status[pixel] = SETTLED if up else -SETTLED
    return n


@kernel
def settle_waiting(width, state, status, target_on, target_off, window_us, queue_pixel, queue_us, head, tail,
                   before_us, out_t, out_w, n):  # pragma: no cover - compiled
    """Settle, in queue order, the pixels that started to wait before ``before_us``, their next slope unknown
    (``before_us`` = NO_EVENT_US: all of them, the stream ended), tails over (at most) one window. Called out of
    line: rarely due, and kept out of the per-event loop it is faster (the loop's code stays small).

    Returns (count, queue head); the head stops early when the output arrays are full. A queue entry whose pixel
    has had an event since is stale and skipped."""
    capacity = out_t.shape[0]
    per_target = 1.0 / min(target_on, target_off)
    while head < tail and queue_us[head] < before_us:
        if head + AHEAD < tail:  # the queue is read in order: its pixels' states can be fetched early
            ahead = queue_pixel[head + AHEAD]
            if abs(status[ahead]) >= TURN:  # (most tails were dropped by their pixel's next event)
                prefetch(state, ahead)
        pixel = queue_pixel[head]
        if abs(status[pixel]) < TURN:
            head += 1
            continue
        row = state[pixel]
        if row.last_us == queue_us[head]:
            if n + _room(row.level, float(row.on), float(row.off), per_target) > capacity:
                return n, head
            xy = ((pixel // width) << 16) | (pixel % width)
            n = _settle(state, status, pixel, xy, 0.0, float(window_us), target_on, target_off, out_t, out_w, n)
        head += 1
    return n, head


@kernel(inline=True)
def _run_excess(row, up, curves):
    """How far a settled pixel's run went on after its latest event, by the consistency rule's expected value:
    none after a re-sampled tail (modelled); with ``curves``, a run that slowed down goes on by its exponential
    approach's rest to the asymptote when that is below a threshold (the pixel did not fire again); otherwise half
    its threshold. Signed by the run's direction."""
    theta = float(row.on) if up else float(row.off)
    excess = 0.5 * theta
    if row.interval_us < 0.0:
        excess = 0.0
    elif curves and 0 < row.pending_us and row.interval_us > MIN_CURVE_RATIO * row.pending_us:
        tau = min(math.floor(_approach_tau(float(row.pending_us), float(row.interval_us)) + 0.5), MAX_TAU_US)
        rest = theta / math.expm1(float(row.interval_us) / tau)
        if rest < theta:  # followed as a tail is: for at most TAIL_TAUS time constants
            excess = rest * TAIL_SHARE
    return excess if up else -excess


@kernel
def finish_runs(width, parity, state, status, use, curves, not_before_us, target_on, target_off, out_t, out_w,
                n):  # pragma: no cover - compiled
    """The stream ended: every re-sampled pixel of the sensor rows of ``parity`` (nothing pending: settled first),
    in index order, goes on after its latest event by the expected excess of its run (:func:`_run_excess`, at
    the run's slope), never before ``not_before_us`` (what is released already ends there).
    Returns n; the caller makes room for the created events."""
    for pixel in range(parity * width, status.shape[0], 2 * width):
        for column in range(width):
            here = pixel + column
            sign = status[here]
            row = state[here]
            if not use[here] or sign == 0:
                continue
            excess = _run_excess(row, sign > 0, curves)
            xy = ((here // width) << 16) | column
            begin = float(max(not_before_us - row.last_us, 0))
            row.level, n = _segment(row.level, excess, begin, max(0.5 * float(row.interval_us), begin), row.last_us,
                                    xy, target_on, target_off, out_t, out_w, n)
    return n


@kernel
def curve_run(state, status, pixel, xy, on, t_b, window_us, target_on, target_off, queue_pixel, queue_us, tail, out_t,
              out_w, n):  # pragma: no cover - compiled
    """The segment that the event ``(t_b, on)`` adds to its pixel's slowing run, as the exponential approach through
    the run's last three events (``curves``); queues the pixel when the approach's tail will cross a target level
    (:data:`TAIL`). Returns (n, queue tail). Out of line: it keeps the per-event loop's code small."""
    row = state[pixel]
    theta = float(row.on) if on else float(row.off)
    delta = theta if on else -theta
    level = row.level
    interval_a = float(row.interval_us)
    span = float(t_b - row.last_us)
    row.interval_us = span
    row.pending_us = np.int32(math.floor(interval_a + 0.5))
    sign = 1 if on else -1
    status[pixel] = sign
    if (level + 2.0 * theta < target_on) if on else (level - 2.0 * theta > -target_off):
        row.level = level + delta  # no crossing, and no tail (less than theta) can reach one: the shape is moot
        return n, tail
    tau = min(math.floor(_approach_tau(interval_a, span) + 0.5), MAX_TAU_US)
    shrink = -math.expm1(-span / tau)  # how much of the approach's rest the segment covers
    level, n = _crossings(level, delta, -span, span, shrink, tau, t_b, xy, target_on, target_off, out_t, out_w, n)
    row.level = level
    if (level + theta < target_on) if on else (level - theta > -target_off):
        return n, tail  # a tail (less than a threshold) cannot reach a target level
    rest = theta * (1.0 - shrink) / shrink * _covered(min(float(window_us), TAIL_TAUS * tau), tau)
    if rest < theta and (level + rest >= target_on if on else level - rest <= -target_off):
        row.pending_us = tau  # the approach crosses a target level the pixel will not fire at: wait
        status[pixel] = sign * TAIL
        queue_pixel[tail] = pixel
        queue_us[tail] = t_b
        tail += 1
    return n, tail


@kernel
def correct_events(words, start, width, state, status, use, target_on, target_off, mode, turns, curves, hold_us,
                   max_gap_us, tau_us, window_us, queue_pixel, queue_us, head, tail, checks_us, checked, out_t, out_w,
                   n):  # pragma: no cover - compiled
    """Process the events ``words[start:]`` ((n, 2) int64: time, then x, y, p as EVENT_DTYPE lays them out) while
    their worst case fits in the output arrays.

    Returns (next input, count, queue head, queue tail, checks done).

    ``state`` (:data:`PIXEL_DTYPE`) and ``status`` (int8, see :data:`SETTLED`) are per pixel (index ``y * width +
    x``) and updated in place; ``use`` says which pixels are re-sampled. Events are written from index ``n`` on, in
    creation order, as times ``out_t`` and second words ``out_w`` (padding zero).

    With ``turns``, a pixel's segment that ends at a reversal (or at its first event) waits for the pixel's next
    event; that event gives the slope after the turn if it comes within ``window_us`` (else the slope is unknown,
    as after a rest). ``queue_pixel[head:tail]`` / ``queue_us`` list the waiting pixels in the order they started to
    wait (so by time). At the checks ``checks_us[checked:]`` (times of the whole stream's events, at least a window
    apart: :func:`split_rows`), before the first event at or after a check's time (or at the end of ``words``),
    every pixel that has waited more than ``window_us`` by then is settled with its next slope unknown: what it
    would get from its own next event, so only the order of creation changes, and that only with the events'
    times, never with where the stream was cut or how its pixels were split into lanes. Checking a window at a
    time (not at every event) keeps the loop fast; a segment then waits at most two windows. The caller makes room
    for one queue entry per input event.
    """
    capacity = out_t.shape[0]
    per_target = 1.0 / min(target_on, target_off)
    end = words.shape[0]
    i = start
    checks = checks_us.shape[0]
    while i < end or checked < checks:
        t_b = words[i, 0] if i < end else NO_EVENT_US
        if checked < checks and checks_us[checked] <= t_b:  # settle the pixels that waited too long
            while checked + 1 < checks and checks_us[checked + 1] <= t_b:
                checked += 1
            before_us = checks_us[checked] - window_us
            n, head = settle_waiting(width, state, status, target_on, target_off, window_us, queue_pixel,
                                     queue_us, head, tail, before_us, out_t, out_w, n)
            if head < tail and queue_us[head] < before_us:
                return i, n, head, tail, checked
            checked += 1
            continue
        if i + AHEAD < end:  # the state of a pixel a few events ahead: its cache miss overlaps this work
            ahead = words[i + AHEAD, 1]
            prefetch(state, ((ahead >> 16) & 0xFFFF) * width + (ahead & 0xFFFF))
        word = words[i, 1]
        xy = word & 0xFFFFFFFF
        on = ((word >> 32) & 0xFF) != 0
        pixel = ((word >> 16) & 0xFFFF) * width + (word & 0xFFFF)
        if not use[pixel]:
            if n >= capacity:
                return i, n, head, tail, checked
            out_t[n] = t_b
            out_w[n] = xy | ON_BIT if on else xy
            n += 1
            i += 1
            continue
        row = state[pixel]
        theta_on = float(row.on)
        theta_off = float(row.off)
        if n + _room(row.level, theta_on, theta_off, per_target) > capacity:
            return i, n, head, tail, checked
        d = theta_on if on else -theta_off
        sign = 1 if on else -1
        t_a = row.last_us
        gap = t_b - t_a
        kind = abs(status[pixel])
        if kind == TAIL and gap <= window_us:  # the pixel fired again: the run went on (or turned), no tail
            status[pixel] = SETTLED if status[pixel] > 0 else -SETTLED
            row.pending_us = 0  # (held the tail's tau; a slowing run is not straight)
        elif kind >= TURN:  # the pending segment (or tail) waited for this event
            same = (on == (status[pixel] > 0)) and 0 < gap <= window_us
            n = _settle(state, status, pixel, xy, float(gap) if same else 0.0, float(window_us), target_on,
                        target_off, out_t, out_w, n)
        last = status[pixel]
        a = row.level
        if t_a == NO_EVENT_US:  # a first event with nothing before it: its crossings at its own time
            a, n = _segment(a, d, 0.0, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)
            row.interval_us = 0.0
            row.pending_us = 0
            status[pixel] = sign
        elif mode != MODE_FOH and gap > hold_us:  # a rest: held, everything at t_b
            forget = math.exp(-(gap - hold_us) / tau_us) if mode == MODE_HIGHPASS else 1.0
            if turns and last == -sign:
                # a reversal over a rest: the run went on by its expected excess (:func:`_run_excess`) at its slope
                # (at once when unknown: a step), never earlier than three windows before t_b (the latency with
                # turns: what is released ends there at the latest), and came back just before t_b; highpass
                # forgets the level over the rest after the run's excess (forgotten first, the excess crossed no
                # level where the pixel's threshold was just below the target: one event lost an edge), the excess
                # with it, so that t_b's level is the forgotten level plus d, as without a turn
                excess = _run_excess(row, not on, curves)
                latency = 3.0 * window_us
                reached = -min(float(gap) - 0.5 * max(row.interval_us, 0.0), latency)
                a, n = _segment(a, excess, max(-float(gap), -latency), reached, t_b, xy, target_on, target_off, out_t,
                                out_w, n)
                a, n = _segment(a * forget, d - excess * forget, 0.0, 0.0, t_b, xy, target_on, target_off, out_t,
                                out_w, n)
            else:
                a, n = _segment(a * forget, d, 0.0, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)
            row.interval_us = 0.0
            row.pending_us = 0
            status[pixel] = sign
        elif turns and (last == 0 or last == -sign) and gap <= max_gap_us:  # wait for the pixel's next event
            straight = 0 < row.pending_us and 0.0 < row.interval_us and _within(row.interval_us, row.pending_us)
            row.pending_us = gap
            status[pixel] = sign * (FIRST if last == 0 else LINES if straight else TURN)
            queue_pixel[tail] = pixel
            queue_us[tail] = t_b
            tail += 1
        elif curves and last == sign and 0.0 < row.interval_us and gap <= window_us and (
                gap > MIN_CURVE_RATIO * row.interval_us):  # a run that slows down: an exponential approach
            n, tail = curve_run(state, status, pixel, xy, on, t_b, window_us, target_on, target_off, queue_pixel,
                                queue_us, tail, out_t, out_w, n)
            a = row.level
        else:
            a, n = _segment(a, d, -float(min(gap, max_gap_us)), 0.0, t_b, xy, target_on, target_off, out_t, out_w,
                            n)
            ramp = last == sign and 0 < gap <= window_us  # a ramp within the window
            row.pending_us = np.int32(math.floor(max(row.interval_us, 0.0) + 0.5)) if ramp else 0
            row.interval_us = gap if ramp else 0
            status[pixel] = sign
        row.level = a
        row.last_us = t_b
        i += 1
    return i, n, head, tail, checked


@kernel(inline=True)
def _merge(a_t, a_w, i, a_end, b_t, b_w, j, b_end, dst_t, dst_w, d):
    """Merge ``a[i:a_end]`` and ``b[j:b_end]`` (each sorted by time) into ``dst`` from ``d``, ``a`` first on ties;
    branch-free in the common part (which run is next is a coin toss)."""
    while i < a_end and j < b_end:
        ta = a_t[i]
        tb = b_t[j]
        take_a = ta <= tb
        dst_t[d] = ta if take_a else tb
        dst_w[d] = a_w[i] if take_a else b_w[j]
        i += take_a
        j += 1 - take_a
        d += 1
    while i < a_end:
        dst_t[d] = a_t[i]
        dst_w[d] = a_w[i]
        i += 1
        d += 1
    while j < b_end:
        dst_t[d] = b_t[j]
        dst_w[d] = b_w[j]
        j += 1
        d += 1
    return d


@kernel
def sort_created(new_t, new_w, n, counts, sorted_t, sorted_w):  # pragma: no cover - compiled
    """Sort the ``n`` created events ``new_*`` (creation order) by time into ``sorted_*``, ties in creation order.

    A counting sort that scatters them straight to their places, with a bucket per us when ``counts`` covers their
    time span, else buckets of ``2**shift`` us, each then put in order by a stable insertion sort (created events
    are nearly in order, so buckets are short and mostly sorted already)."""
    if n == 0:
        return
    low = new_t[0]
    high = new_t[0]
    for k in range(n):
        low = min(low, new_t[k])
        high = max(high, new_t[k])
    shift = 0  # buckets of 2**shift us, so that the span fits the counts
    while ((high - low) >> shift) + 1 > counts.shape[0]:
        shift += 1
    buckets = ((high - low) >> shift) + 1
    counts[:buckets] = 0
    for k in range(n):
        counts[(new_t[k] - low) >> shift] += 1
    total = 0
    for b in range(buckets):
        c = counts[b]
        counts[b] = total
        total += c
    if shift == 0:  # a bucket per us: reads in order, writes scattered (stores do not stall like loads)
        for k in range(n):
            bucket = new_t[k] - low
            place = counts[bucket]
            counts[bucket] = place + 1
            sorted_w[place] = new_w[k]
        place = 0  # counts[b] is now where bucket b ends: the times follow in order, no scatter needed
        for b in range(buckets):
            while place < counts[b]:
                sorted_t[place] = low + b
                place += 1
        return
    for k in range(n):
        bucket = (new_t[k] - low) >> shift
        place = counts[bucket]
        counts[bucket] = place + 1
        sorted_t[place] = new_t[k]
        sorted_w[place] = new_w[k]
    begin = 0
    for b in range(buckets):
        end = counts[b]
        for j in range(begin + 1, end):
            t = sorted_t[j]
            w = sorted_w[j]
            i = j - 1
            while i >= begin and sorted_t[i] > t:
                sorted_t[i + 1] = sorted_t[i]
                sorted_w[i + 1] = sorted_w[i]
                i -= 1
            sorted_t[i + 1] = t
            sorted_w[i + 1] = w
        begin = end


@kernel
def release_runs(held_t, held_w, begins, ends, runs, bound, spare_t, spare_w, out_t,
                 out_w):  # pragma: no cover - compiled
    """Take from each of the ``runs`` time-sorted runs ``held[begins[r]:ends[r]]`` (oldest first) its events before
    ``bound`` and merge them into ``out``, ties in the runs' order: a stable k-way merge, the parts merged pairwise
    (the earlier first on ties) pass after pass between ``spare`` and ``out``, the first pass reading the runs where
    they are and writing the buffer that makes the last pass write ``out``; each event moves ceil(log2(parts))
    times, once at least. The runs taken whole leave the table (``begins``, ``ends`` updated in place, in order).

    Returns (count, runs left), or (count, -1) and nothing changed when ``out`` or ``spare`` holds fewer than
    ``count`` events."""
    cut = np.empty(runs, np.int64)
    total = 0
    for r in range(runs):
        low = begins[r]
        high = ends[r]
        while low < high:  # the run's first event at or after the bound
            middle = (low + high) >> 1
            if held_t[middle] < bound:
                low = middle + 1
            else:
                high = middle
        cut[r] = low
        total += low - begins[r]
    if total > out_t.shape[0] or total > spare_t.shape[0]:
        return total, -1
    part_begin = np.empty(runs, np.int64)
    part_end = np.empty(runs, np.int64)
    parts = 0
    for r in range(runs):
        if cut[r] > begins[r]:
            part_begin[parts] = begins[r]
            part_end[parts] = cut[r]
            parts += 1
    passes = 0
    remaining = parts
    while remaining > 1:
        remaining = (remaining + 1) >> 1
        passes += 1
    a_t, a_w, b_t, b_w = out_t, out_w, spare_t, spare_w  # first written: out after an odd number of passes
    if passes % 2 == 0 and passes > 0:
        a_t, a_w, b_t, b_w = spare_t, spare_w, out_t, out_w
    merged_ends = np.empty(parts + 1, np.int64)
    merged_ends[0] = 0
    filled = 0
    merged = 0
    for k in range(0, parts, 2):  # the first pass: the runs' parts, read where they are
        if k + 1 < parts:
            filled = _merge(held_t, held_w, part_begin[k], part_end[k], held_t, held_w, part_begin[k + 1],
                            part_end[k + 1], a_t, a_w, filled)
        else:
            filled = _merge(held_t, held_w, part_begin[k], part_end[k], held_t, held_w, 0, 0, a_t, a_w, filled)
        merged += 1
        merged_ends[merged] = filled
    while merged > 1:  # adjacent ranges merged pairwise, between the two buffers
        count = 0
        for k in range(0, merged, 2):
            low = merged_ends[k]
            middle = merged_ends[k + 1]
            high = merged_ends[k + 2] if k + 2 <= merged else middle
            _merge(a_t, a_w, low, middle, a_t, a_w, middle, high, b_t, b_w, low)
            merged_ends[count + 1] = high
            count += 1
        merged = count
        a_t, b_t = b_t, a_t
        a_w, b_w = b_w, a_w
    left = 0
    for r in range(runs):
        if cut[r] < ends[r]:
            begins[left] = cut[r]
            ends[left] = ends[r]
            left += 1
    return total, left


@kernel
def compact_runs(held_t, held_w, begins, ends, runs):  # pragma: no cover - compiled
    """Move the runs ``held[begins[r]:ends[r]]`` (in buffer order) to the front of the buffer, end to end, in
    order, updating ``begins`` and ``ends``; returns where the last one ends."""
    filled = 0
    for r in range(runs):
        begin = begins[r]
        count = ends[r] - begin
        if begin != filled:
            for k in range(count):  # forward: the destination never passes the source
                held_t[filled + k] = held_t[begin + k]
                held_w[filled + k] = held_w[begin + k]
        begins[r] = filled
        filled += count
        ends[r] = filled
    return filled


@kernel
def merge_sorted(a_t, a_w, b_t, b_w, out_t, out_w):  # pragma: no cover - compiled
    """Merge the time-sorted runs ``a`` and ``b`` into ``out``, ``a`` first on ties; returns the count."""
    return _merge(a_t, a_w, 0, a_t.shape[0], b_t, b_w, 0, b_t.shape[0], out_t, out_w, 0)


@kernel
def split_rows(words, even, odd, due_us, window_us, checks_us):  # pragma: no cover - compiled
    """Copy the events ``words`` ((n, 2) int64) of even sensor rows to ``even``, of odd rows to ``odd``, in order
    (both hold n rows: each event is written to both, the count of its own advances), and list in ``checks_us`` the
    times at which waiting pixels are checked (:func:`correct_events`): the first event at or after ``due_us``,
    then the first one a window after it, and so on. Returns the two counts, the number of checks and the next
    ``due_us``."""
    n_even = 0
    n_odd = 0
    checks = 0
    for i in range(words.shape[0]):
        t = words[i, 0]
        word = words[i, 1]
        is_odd = (word >> 16) & 1  # the lowest bit of y
        even[n_even, 0] = t
        even[n_even, 1] = word
        odd[n_odd, 0] = t
        odd[n_odd, 1] = word
        n_even += 1 - is_odd
        n_odd += is_odd
        if t >= due_us:
            checks_us[checks] = t
            checks += 1
            due_us = t + window_us
    return n_even, n_odd, checks, due_us


@kernel
def compact_waiting(state, queue_pixel, queue_us, head, tail):  # pragma: no cover - compiled
    """Move the waiting pixels' queue entries ``[head, tail)`` to the front of the queue, in order, without those
    that can never be settled: an entry is settled only while its pixel's latest event is the one it was queued at
    (``last_us`` equal to the entry's time), and a pixel's latest time never decreases. A busy stream's queue
    otherwise fills with such entries (a million a lane at 9.5 Mev/s), while the live ones are at most about one
    a pixel. Returns the count kept."""
    kept = 0
    for k in range(head, tail):
        pixel = queue_pixel[k]
        if state[pixel].last_us == queue_us[k]:
            queue_pixel[kept] = pixel
            queue_us[kept] = queue_us[k]
            kept += 1
    return kept


@kernel(inline=True)
def _start_of(state, status, pixel, now_us, rest_us):
    """The earliest time ``pixel``'s next created event can lie at, once the stream has reached ``now_us``: its
    latest event, or the start of the segment that waits for its next event (a turn's or a first ramp's,
    ``pending_us`` before it; a tail starts at the event). A pixel that has not fired yet (its reconstruction
    anchored at the stream's start, ``turns``) creates its first events at the stream's start only if it fires
    within ``rest_us`` of it (``hold_us``: later, its first event comes after a rest and all it creates is at its
    own time, at or after ``now_us``): NO_EVENT_US once ``now_us`` is past that (NO_EVENT_US for ``rest_us``:
    ``foh``, which has no rests)."""
    start = state[pixel].last_us
    kind = abs(status[pixel])
    if kind == TURN or kind == FIRST or kind == LINES:
        start -= state[pixel].pending_us
    elif kind == 0 and start != NO_EVENT_US and now_us - start > rest_us:
        start = NO_EVENT_US
    return start


@kernel
def earliest_start(state, status, hint_us, hint_pixel, now_us, rest_us):  # pragma: no cover - compiled
    """The earliest time any pixel's next created event can lie at once the stream has reached ``now_us``
    (:func:`_start_of`), and a pixel where it is; NO_EVENT_US (and -1) when no pixel can create an event before
    ``now_us``.

    ``hint_us`` and ``hint_pixel`` are the previous call's answer (pixel -1: none). A pixel's start never decreases (its
    latest event only moves on, a waiting segment starts at the event before, which is at or after where the pixel's
    start was, a pixel that has not fired only loses its start at the stream's start), and a pixel firing starts
    at its event, after every start that exists; so while the hinted pixel's start is still ``hint_us`` that is
    still the earliest, and the scan of every pixel (2.4 MB of state on a 640 x 480 sensor, 48 ns an event with
    2,048-event chunks) is skipped."""
    if hint_pixel >= 0 and _start_of(state, status, hint_pixel, now_us, rest_us) == hint_us:
        return hint_us, hint_pixel
    earliest = NO_EVENT_US
    where = -1
    for pixel in range(status.shape[0]):
        start = _start_of(state, status, pixel, now_us, rest_us)
        if start < earliest:
            earliest = start
            where = pixel
    return earliest, where
