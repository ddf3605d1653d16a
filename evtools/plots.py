"""Plots with matplotlib (figures a paper can use): ROC curves, threshold maps, rates and hot pixels, as figures
(:func:`evtools.formats.figures.save_figure` writes them: PNG, SVG or PDF). Every map has pixel axes (x, y in
sensor pixels), a colour bar with round ticks, and a key for pixels without a value. Event frames and video stay
with OpenCV (:mod:`evtools.render`), the fast path.

Colour scales of maps are clipped at robust percentiles (2 and 98) so that one wild pixel cannot flatten the rest;
the clipping is written on the colour bar. Estimate and truth share one scale; errors use a diverging scale centred
on 0.
"""

from __future__ import annotations

import numpy as np

from evtools.errors import EvtoolsError

CLIP_PERCENTILES = (2.0, 98.0)
"""Where colour scales of maps are clipped (the bars say so)."""
INVALID_GREY = "0.75"
"""The colour of map pixels without a valid value (the key says so)."""
FAR_OUT_IQR = 3.0
"""A map's default colour range: min..max narrowed to Tukey's far-out fences (quartile -+ 3 IQR)."""


class PlotError(EvtoolsError, ValueError):
    """A figure that cannot be made (no values to draw, maps of the wrong shape)."""


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def _pixel_axes(axis, width: int, height: int) -> None:
    """Sensor pixels on both axes, whole numbers only, y downwards as images are."""
    from matplotlib.ticker import MaxNLocator

    axis.xaxis.set_major_locator(MaxNLocator(nbins=6, integer=True))
    axis.yaxis.set_major_locator(MaxNLocator(nbins=6, integer=True))
    axis.set_xlabel("x, px", fontsize=8)
    axis.set_ylabel("y, px", fontsize=8)
    axis.tick_params(labelsize=7)
    axis.set_xlim(-0.5, width - 0.5)
    axis.set_ylim(height - 0.5, -0.5)


def _invalid_key(figure, count: int, total: int) -> None:
    """A grey square and how many pixels it stands for, under the figure."""
    from matplotlib.patches import Patch

    if count:
        figure.legend(handles=[Patch(facecolor=INVALID_GREY, edgecolor="0.4",
                                     label=f"no valid value: {count:,} of {total:,} pixels")],
                      loc="lower left", fontsize=8, frameon=False)


def display_range(values: np.ndarray) -> tuple[float, float]:
    """min..max of ``values``, narrowed to Tukey's far-out fences (quartile -+ 3 IQR) so that a few wild pixels
    (dead pixels, failed fits) do not squash everyone else's colours into one end of the colour map."""
    low, high = float(values.min()), float(values.max())
    q1, q3 = np.percentile(values, [25.0, 75.0])
    iqr = float(q3 - q1)
    if iqr > 0:
        low, high = max(low, float(q1) - FAR_OUT_IQR * iqr), min(high, float(q3) + FAR_OUT_IQR * iqr)
    return low, high


def _valid_masks(on: np.ndarray, off: np.ndarray, valid) -> tuple[np.ndarray, np.ndarray]:
    on_valid, off_valid = np.isfinite(on), np.isfinite(off)
    if valid is not None:
        valid = np.asarray(valid).astype(bool)
        if valid.shape == on.shape:
            on_valid &= valid
            off_valid &= valid
        elif valid.shape == (2, *on.shape):
            on_valid &= valid[0]
            off_valid &= valid[1]
        else:
            raise PlotError(f"valid mask of shape {valid.shape} does not match the {on.shape[0]} x {on.shape[1]} "
                            "maps")
    return on_valid, off_valid


def _stats(name: str, values: np.ndarray, count: int) -> str:
    if not len(values):
        return f"{name}: no valid pixels"
    text = (f"{name}: mean {values.mean():.4g}, std {values.std():.4g}, min {values.min():.4g}, "
            f"max {values.max():.4g}")
    return text + (f", {count - len(values):,} invalid" if len(values) < count else "")


def map_figure(on, off, valid=None, *, value_range: tuple[float, float] | None = None, colormap: str | None = None,
               units: str = "", titles: tuple[str, str] = ("ON threshold", "OFF threshold")):
    """An ON and an OFF map side by side on one colour scale (``evtools render --map``): pixel axes, one colour
    bar with round ticks (arrows where values lie beyond it), invalid and non-finite pixels grey with a key, and
    each map's mean, std, min and max under it.

    ``valid``: one mask for both maps or ``(2, H, W)``, ON's then OFF's. ``value_range``: the values at the bar's
    ends (default: :func:`display_range` of the valid values). ``colormap``: a matplotlib name (viridis)."""
    plt = _pyplot()
    on, off = np.asarray(on), np.asarray(off)
    if on.ndim != 2 or on.shape != off.shape or 0 in on.shape:
        raise PlotError(f"ON and OFF maps must be two non-empty 2-D maps of one shape, got {on.shape} and "
                        f"{off.shape}")
    try:
        on, off = on.astype(np.float64), off.astype(np.float64)
    except (TypeError, ValueError):
        raise PlotError("the maps do not hold numbers") from None
    masks = _valid_masks(on, off, valid)
    values = np.concatenate([on[masks[0]], off[masks[1]]])
    if not len(values):
        raise PlotError("no pixel of the maps has a valid (finite, unmasked) value")
    low, high = display_range(values) if value_range is None else (float(v) for v in value_range)
    if not (np.isfinite(low) and np.isfinite(high)) or high < low:
        raise PlotError(f"value range {low} .. {high} is not an increasing pair of finite numbers")
    if high == low:  # one value everywhere: a bar around it
        low, high = low - 0.5 * max(abs(low), 1e-3), high + 0.5 * max(abs(high), 1e-3)
    try:
        cmap = plt.get_cmap(colormap or "viridis").with_extremes(bad=INVALID_GREY)
    except ValueError:
        raise PlotError(f"unknown colormap {colormap!r}") from None
    height, width = on.shape
    panel_w = 4.2
    figure, axes = plt.subplots(1, 2, figsize=(2 * panel_w + 1.4, panel_w * height / width + 1.5),
                                constrained_layout=True)
    for axis, title, values_map, mask in zip(axes, titles, (on, off), masks):
        image = axis.imshow(np.where(mask, values_map, np.nan), cmap=cmap, vmin=low, vmax=high,
                            interpolation="nearest")
        axis.set_title(title, fontsize=10)
        _pixel_axes(axis, width, height)
        axis.text(0.0, -0.16, _stats(title.split()[0], values_map[mask], mask.size), transform=axis.transAxes,
                  fontsize=7, va="top")
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}[
        (bool(values.min() < low), bool(values.max() > high))]
    bar = figure.colorbar(image, ax=list(axes), shrink=0.9, extend=extend)
    bar.set_label(f"threshold{', ' + units if units else ''}" + ("" if extend == "neither" else
                  "\n(arrows: values beyond the bar)"), fontsize=8)
    bar.ax.tick_params(labelsize=7)
    _invalid_key(figure, int((~masks[0] | ~masks[1]).sum()), on.size)
    return figure


def roc_figure(curves: list[dict], title: str = ""):
    """ROC curves: each ``{"label", "parameter", "points": [{"value", "fpr", "tpr"}...], "auc"}``; every point is
    marked with its swept value, the AUC is in the legend."""
    plt = _pyplot()
    figure, axes = plt.subplots(figsize=(6, 5.4))
    axes.plot([0, 1], [0, 1], color="0.8", linewidth=1, linestyle="--", label="chance")
    for curve in curves:
        points = sorted((p for p in curve["points"] if p["fpr"] is not None and p["tpr"] is not None),
                        key=lambda p: (p["fpr"], p["tpr"]))
        fpr = [0.0] + [p["fpr"] for p in points] + [1.0]
        tpr = [0.0] + [p["tpr"] for p in points] + [1.0]
        line, = axes.plot(fpr, tpr, marker="o", markersize=3.5, linewidth=1.5,
                          label=f"{curve['label']}, swept {curve.get('parameter', '?')}  (AUC {curve['auc']:.3f})")
        for point in points:
            axes.annotate(f"{point['value']:g}", (point["fpr"], point["tpr"]), textcoords="offset points",
                          xytext=(4, -9), fontsize=6.5, color=line.get_color())
    axes.set_xlim(0, 1)
    axes.set_ylim(0, 1.02)
    axes.set_xlabel("FPR: fraction of noise kept")
    axes.set_ylabel("TPR: fraction of signal kept")
    swept = {curve.get("parameter", "") for curve in curves}
    axes.set_title(title or f"ROC (the swept {', '.join(sorted(swept))} at each point)")
    axes.grid(True, color="0.92")
    if len(curves) > 3:  # many curves: the legend beside the axes, not over them
        figure.set_size_inches(9.5, 5.4)
        axes.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    else:
        axes.legend(loc="lower right", fontsize=8)
    return figure


def _robust_range(values: np.ndarray) -> tuple[float, float]:
    low, high = np.percentile(values, CLIP_PERCENTILES)
    if high <= low:
        low, high = float(values.min()), float(values.max())
    if high <= low:
        high = low + 1e-9
    return float(low), float(high)


def thresholds_figure(estimated_on, estimated_off, valid, true_on, true_off, units: str = "log units"):
    """Estimated and true ON / OFF maps on one shared scale (clipped at the 2nd and 98th percentiles, said on the
    bar) and the relative error (estimate / truth - 1) on a diverging scale centred on 0; invalid pixels grey."""
    plt = _pyplot()
    maps = {"ON": (np.asarray(estimated_on, float), np.asarray(true_on, float)),
            "OFF": (np.asarray(estimated_off, float), np.asarray(true_off, float))}
    valid = np.asarray(valid, bool)
    valid = valid if valid.ndim == 3 else np.stack([valid, valid])
    shown = [np.where(mask & np.isfinite(estimate), estimate, np.nan) for mask, (estimate, _) in
             zip(valid, maps.values())]
    values = np.concatenate([s[np.isfinite(s)] for s in shown] + [t[np.isfinite(t)].ravel() for _, t in maps.values()])
    if not len(values):
        raise PlotError("no pixel has a valid estimate to draw")
    low, high = _robust_range(values)
    errors = [(s / t - 1.0) * 100.0 for s, (_, t) in zip(shown, maps.values())]
    finite = np.concatenate([e[np.isfinite(e)] for e in errors])
    limit = float(np.percentile(np.abs(finite), CLIP_PERCENTILES[1])) if len(finite) else 1.0
    limit = max(limit, 1e-6)
    figure, axes = plt.subplots(2, 3, figsize=(12, 6.4), constrained_layout=True)
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.75")
    diverging = plt.get_cmap("RdBu_r").with_extremes(bad="0.75")
    for row, ((name, (_, truth)), estimate, error) in enumerate(zip(maps.items(), shown, errors)):
        image = axes[row, 0].imshow(estimate, cmap=cmap, vmin=low, vmax=high, interpolation="nearest")
        axes[row, 1].imshow(truth, cmap=cmap, vmin=low, vmax=high, interpolation="nearest")
        wrong = axes[row, 2].imshow(error, cmap=diverging, vmin=-limit, vmax=limit, interpolation="nearest")
        axes[row, 0].set_title(f"{name}: estimated")
        axes[row, 1].set_title(f"{name}: true")
        axes[row, 2].set_title(f"{name}: error, % of the true value")
        bar = figure.colorbar(image, ax=axes[row, :2], shrink=0.9, extend="both")
        bar.set_label(f"threshold, {units}\nclipped at the 2nd and 98th percentiles", fontsize=8)
        error_bar = figure.colorbar(wrong, ax=axes[row, 2], shrink=0.9, extend="both")
        error_bar.set_label(f"error, %\nclipped at ±{limit:.3g} (98th percentile of |error|)", fontsize=8)
        for axis in axes[row]:
            _pixel_axes(axis, truth.shape[1], truth.shape[0])
    _invalid_key(figure, int((~np.isfinite(np.stack(shown))).any(axis=0).sum()), valid[0].size)
    return figure


def edge_levels_figure(panels: list[tuple[str, list]], edge_start_us: int, edge_end_us: int):
    """Per-pixel reconstructions over one edge (the founding report's Figures 31 and 32): for each panel
    ``(title, levels)``, ``levels`` being (t_us, level) per pixel as :func:`evtools.metrics.uniformity.pixel_levels`
    gives them, each pixel's ON-minus-OFF count as a staircase against the time since the edge began, panels side
    by side on one scale."""
    plt = _pyplot()
    figure, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4), sharey=True, squeeze=False)
    for axis, (title, levels) in zip(axes[0], panels):
        for t_us, level in levels:
            times_ms = np.concatenate([[0.0], (np.asarray(t_us) - edge_start_us) / 1e3])
            axis.step(times_ms, np.concatenate([[0.0], level]), where="post", linewidth=0.7, alpha=0.6)
        axis.set_title(title, fontsize=10)
        axis.set_xlim(0, max(edge_end_us - edge_start_us, 1) / 1e3)
        axis.set_xlabel("time since the edge began, ms")
        axis.grid(True, color="0.92")
    axes[0, 0].set_ylabel("events so far, ON minus OFF\n(times the threshold: log intensity)")
    return figure


class RateCounter:
    """Event counts of a stream, chunk by chunk: per time bin (ON and OFF) and per pixel, for :func:`rate_figure`.
    Bins start at the first event; ``bin_us`` of 1 ms, merged in pairs whenever there would be more than
    ``max_bins`` (so memory stays bounded on any stream length)."""

    def __init__(self, width: int, height: int, bin_us: int = 1000, max_bins: int = 4096) -> None:
        self.width, self.height = width, height
        self.bin_us, self.max_bins = int(bin_us), int(max_bins)
        self.first_us: int | None = None
        self.last_us: int | None = None
        self.bins = np.zeros((2, 0), np.int64)  # OFF, ON
        self.pixels = np.zeros(width * height, np.int64)

    def add(self, chunk: np.ndarray) -> None:
        if not len(chunk):
            return
        if self.first_us is None:
            self.first_us = int(chunk["t"][0])
        self.last_us = int(chunk["t"][-1])
        while (self.last_us - self.first_us) // self.bin_us >= self.max_bins:  # coarser bins: pairs merged
            pairs = self.bins[:, : self.bins.shape[1] // 2 * 2].reshape(2, -1, 2).sum(axis=2)
            odd = self.bins[:, self.bins.shape[1] // 2 * 2:]
            self.bins, self.bin_us = np.concatenate([pairs, odd], axis=1), self.bin_us * 2
        index = (chunk["t"] - self.first_us) // self.bin_us
        size = int(index[-1]) + 1
        if size > self.bins.shape[1]:
            self.bins = np.pad(self.bins, ((0, 0), (0, size - self.bins.shape[1])))
        polarity = chunk["p"].astype(np.int64)
        self.bins += np.bincount(polarity * size + index, minlength=2 * size).reshape(2, size)[:, : self.bins.shape[1]]
        self.pixels += np.bincount(chunk["y"].astype(np.int64) * self.width + chunk["x"], minlength=len(self.pixels))


def rate_figure(counter: RateCounter, title: str = ""):
    """The event rate over time (ON and OFF, events/s) above the per-pixel rate map (events/s, log scale clipped at
    the 98th percentile, said on the bar): where a hot pixel or a flickering light would show."""
    from matplotlib.colors import LogNorm

    plt = _pyplot()
    if counter.first_us is None:
        raise PlotError("no events to plot")
    span_s = max(counter.last_us - counter.first_us + 1, 1) / 1e6
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(8, 8.5), gridspec_kw={"height_ratios": [1, 1.6]})
    times_s = (np.arange(counter.bins.shape[1]) + 0.5) * counter.bin_us / 1e6
    top.plot(times_s, counter.bins[1] / (counter.bin_us / 1e6), color="tab:orange", linewidth=1, label="ON")
    top.plot(times_s, counter.bins[0] / (counter.bin_us / 1e6), color="tab:blue", linewidth=1, label="OFF")
    top.set_xlabel("time since the first event, s")
    top.set_ylabel(f"events/s (bins of {counter.bin_us / 1e3:g} ms)")
    top.set_xlim(0, span_s)
    top.grid(True, color="0.92")
    top.legend(loc="upper right", fontsize=8)
    top.set_title(title or "event rate")
    rates = counter.pixels.reshape(counter.height, counter.width) / span_s
    positive = rates[rates > 0]
    high = float(np.percentile(positive, 98)) if len(positive) else 1.0
    low = max(float(positive.min()) if len(positive) else 0.1, high / 1e4, 1e-3)
    # magma without its black end, so that black is only "no event" (the slowest pixels were drawn black too, and
    # those below the scale's floor: a QA sweep); a pixel that fired is never below the lowest colour
    from matplotlib.colors import ListedColormap

    cmap = ListedColormap(plt.get_cmap("magma")(np.linspace(0.2, 1.0, 256))).with_extremes(under="black")
    shown = np.where(rates > 0, np.maximum(rates, low), low * 0.5)
    image = bottom.imshow(shown, cmap=cmap, norm=LogNorm(vmin=low, vmax=max(high, low * 1.01)), interpolation="nearest")
    bottom.set_title(f"events/s per pixel over {span_s:.3g} s")
    _pixel_axes(bottom, counter.width, counter.height)
    bar = figure.colorbar(image, ax=bottom, shrink=0.85, extend="both")
    bar.set_label(f"events/s, log scale, clipped at the 98th percentile ({high:.3g}); black: no event", fontsize=8)
    figure.tight_layout()
    return figure


def hot_pixels_figure(hot: np.ndarray, counts: np.ndarray | None, duration_s: float):
    """The hot pixels (circled) on the per-pixel event rate of the learning stretch (log scale), or on their own
    map when no counts were learned (a given list)."""
    from matplotlib.colors import LogNorm

    plt = _pyplot()
    figure, axes = plt.subplots(figsize=(7, 5.5))
    ys, xs = np.nonzero(hot)
    if counts is not None and duration_s > 0 and counts.any():
        rates = counts / duration_s
        positive = rates[rates > 0]
        high = float(positive.max())
        low = max(float(positive.min()), high / 1e5)
        image = axes.imshow(np.maximum(rates, low * 0.999), norm=LogNorm(vmin=low, vmax=max(high, low * 1.01)),
                            cmap=plt.get_cmap("magma").with_extremes(under="black"), interpolation="nearest")
        figure.colorbar(image, ax=axes, shrink=0.85).set_label(
            f"events/s in the learning stretch ({duration_s:.3g} s), log scale", fontsize=8)
    else:
        axes.imshow(hot, cmap="gray_r", interpolation="nearest")
    axes.scatter(xs, ys, s=60, facecolors="none", edgecolors="cyan", linewidths=1.2, label=f"{len(xs)} hot pixels")
    axes.set_title(f"hot pixels: {len(xs)} of {hot.size:,}")
    axes.legend(loc="upper right", fontsize=8)
    _pixel_axes(axes, hot.shape[1], hot.shape[0])
    return figure


def steady_frames(truth: np.ndarray, count: int = 5) -> np.ndarray:
    """Indices of ``count`` frames spread over ``truth``, each the one of its stretch longest after the truth last
    changed (a change: mean |difference| above 0.1 % of the truth's range; the middle one among equals): a frame at
    or just after a step edge shows the reconstruction's lag, not its error, in every panel."""
    flat = truth.reshape(len(truth), -1)
    spread = float(flat.max() - flat.min()) or 1.0
    changed = np.concatenate([[True], np.abs(np.diff(flat, axis=0)).mean(axis=1) > 1e-3 * spread])
    last_change = np.maximum.accumulate(np.where(changed, np.arange(len(truth)), 0))
    since = np.arange(len(truth)) - last_change
    bounds = np.linspace(0, len(truth), min(count, len(truth)) + 1).round().astype(int)
    picks = []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        stretch = np.arange(start, stop)
        picks.append(int(stretch[np.lexsort((np.abs(stretch - (start + stop - 1) / 2), -since[start:stop]))[0]]))
    return np.unique(picks)


def reconstruction_figure(truth: np.ndarray, estimated: np.ndarray, times):
    """True (top row) and reconstructed (bottom row) log intensity at five settled times (:func:`steady_frames`),
    one grey scale (the true range), each panel's RMSE in its title (``metrics reconstruction --plot``)."""
    plt = _pyplot()
    picks = steady_frames(truth)
    low, high = float(truth.min()), float(truth.max())
    height, width = truth.shape[1:]
    figure, axes = plt.subplots(2, len(picks), figsize=(2.4 * len(picks), 5.0), squeeze=False,
                                constrained_layout=True)
    for column, k in enumerate(picks):
        for row, (frames, label) in enumerate(((truth, "true"), (estimated, "reconstructed"))):
            axis = axes[row][column]
            shown = axis.imshow(frames[k], cmap="gray", vmin=low, vmax=high, interpolation="nearest")
            _pixel_axes(axis, width, height)
            if row == 0:
                axis.set_title(f"{times[k] / 1e3:.0f} ms", fontsize=9)
            else:
                error = float(np.sqrt(np.mean((estimated[k] - truth[k]) ** 2)))
                axis.set_title(f"RMSE {error:.3f}", fontsize=8)
            if column == 0:
                axis.set_ylabel(f"{label}\ny, px", fontsize=9)
    figure.colorbar(shown, ax=axes, shrink=0.8, label="log intensity")
    return figure
