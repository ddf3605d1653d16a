"""A DAVIS camera watching a natural moving texture: ideal DVS pixels and APS frames, generated independently of
``evtools.simulation`` and ``evtools.aps`` (it shares no code with them), for tests of ``estimate --method frames``.

The scene is :func:`tests.naive.texture.texture_signal`'s log-intensity field (a polyline in time per pixel) around
a base level; events are its exact threshold crossings (:func:`tests.naive.texture.crossings`). A frame integrates
the intensity ``exp(L)`` over its exposure exactly (``L`` is linear between two samples of the polyline, so each
piece integrates to ``(e^b - e^a) / (b - a)`` times its length), then ``DN = black + offset_px + gain_px * t_exp *
mean I + read noise``, rounded, clipped to 0..255.
"""

from __future__ import annotations

import numpy as np

from tests.naive.texture import crossings, texture_signal


def _integral(times_us, levels, begin_us, end_us):
    """Per pixel, the integral of exp(levels) over [begin, end] (us), the levels linear between the times."""
    inside = (times_us > begin_us) & (times_us < end_us)
    knots = np.concatenate([[begin_us], times_us[inside], [end_us]])
    flat = levels.reshape(len(times_us), -1)

    def at(t):  # the polyline at time t, every pixel
        j = min(max(int(np.searchsorted(times_us, t, "right")) - 1, 0), len(times_us) - 2)
        share = (t - times_us[j]) / (times_us[j + 1] - times_us[j])
        return flat[j] * (1 - share) + flat[j + 1] * share

    values = np.concatenate([at(begin_us)[None], flat[inside], at(end_us)[None]])
    total = np.zeros(flat.shape[1])
    for k in range(len(knots) - 1):
        a, b, span = values[k], values[k + 1], knots[k + 1] - knots[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            piece = np.where(np.abs(b - a) > 1e-12, (np.exp(b) - np.exp(a)) / (b - a), np.exp(a))
        total += piece * span
    return total.reshape(levels.shape[1:])


def davis_recording(width, height, duration_us, *, seed, theta_on, theta_off, rate_hz=25.0, exposure_us=5000,
                    base_log=4.2, contrast=0.6, black_level=16.0, gain=0.08, read_noise=1.5, gain_fpn=0.01,
                    offset_fpn=1.0, pan_px_s=(20.0, 5.0), wobble_px=4.0, step_us=1000, drift_per_s=0.0,
                    threshold_step=(None, 1.0)):
    """(events (EVENT_FIELDS), frames [(exposure_begin_us, exposure_end_us, image uint8)]) of a DAVIS: intensity
    ``exp(base_log + texture)`` (0-255-like levels), ``gain`` DN per level per ms; the thresholds drift by
    ``drift_per_s`` of their value a second, and step by ``threshold_step`` (time us, factor)
    (:func:`tests.naive.texture.crossings`)."""
    times, levels = texture_signal(width, height, duration_us, seed=seed, contrast=contrast, pan_px_s=pan_px_s,
                                   wobble_px=wobble_px, step_us=step_us)
    levels = levels + base_log
    events = crossings(times, levels, theta_on, theta_off, drift_per_s, threshold_step)
    rng = np.random.default_rng([seed, 7])
    gain_px = gain * (1 + gain_fpn * rng.standard_normal((height, width)))
    offset_px = black_level + offset_fpn * rng.standard_normal((height, width))
    frames = []
    period_us = 1e6 / rate_hz
    begin = period_us / 2
    while begin + exposure_us < duration_us:
        b, e = int(round(begin)), int(round(begin)) + exposure_us
        mean = _integral(times, levels, b, e) / exposure_us
        dn = offset_px + gain_px * (exposure_us / 1000) * mean + read_noise * rng.standard_normal(mean.shape)
        frames.append((b, e, np.clip(np.round(dn), 0, 255).astype(np.uint8)))
        begin += period_us
    return events, frames


def write_with_dv(path, events, frames, width, height) -> None:
    """The recording written by dv-processing's own writer, as DV records a DAVIS (LZ4)."""
    import dv_processing as dv

    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.DAVISConfig("DAVIS346", (width, height)))
    store_at = 0
    for begin, end, image in frames:
        upto = int(np.searchsorted(events["t"], end, "right"))
        if upto > store_at:
            writer.writeEvents(_store(dv, events[store_at:upto]))
            store_at = upto
        writer.writeFrame(dv.Frame(int(begin), int(end - begin), 0, 0, image, dv.FrameSource.SENSOR))
    if store_at < len(events):
        writer.writeEvents(_store(dv, events[store_at:]))
    del writer


def _store(dv, events):
    store = dv.EventStore()
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        store.push_back(t, x, y, bool(p))
    return store
