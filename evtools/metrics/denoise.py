"""Measuring a denoiser (``docs/algorithms.md`` section 3): labelled (DND21) and unlabelled (E-MLB ESR).

References
----------
S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI 45(1), 2023.
S. Ding et al., "E-MLB: Multilevel Benchmark for Event-Based Camera Denoising", IEEE Trans. Multimedia, 2023.
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from evtools._kernels.bafilter import match_subsequence
from evtools.errors import EvtoolsError
from evtools.events import LABEL_NAMES, StreamChecker, StreamInfo, as_chunk, label_problem

__all__ = ["LABEL_NAMES", "DenoiseMatcher", "DenoiseScore", "roc_auc", "esr", "EsrMeter"]


class DenoiseMetricsError(EvtoolsError, ValueError):
    """Filtered events that are not a subsequence of the input, or labels that do not fit."""


class DenoiseMatcher:
    """Matches a filter's output back to its labelled input, in streaming order, and counts what was kept.

    Feed input chunks with their labels (:meth:`add_input`) and output chunks (:meth:`add_output`) in any
    interleaving; each output event is matched to the first later input event with the same (t, x, y, p).
    Memory holds only the input not yet passed by the matching and the output not yet matched.
    """

    def __init__(self) -> None:
        self.total = np.zeros(256, dtype=np.int64)
        self.kept = np.zeros(256, dtype=np.int64)
        self._inputs: list[tuple[np.ndarray, np.ndarray]] = []
        self._outputs: list[np.ndarray] = []
        self._i = self._j = 0  # position in the first held input and output
        self.inputs_seen = self.outputs_seen = 0

    def add_input(self, events: np.ndarray, labels: np.ndarray) -> None:
        """The next events of the noisy stream (any layout :func:`evtools.events.as_chunk` takes) and their labels,
        one of 0 (signal), 1 (leak), 2 (shot), 3 (hot) per event (another was scored as nothing: a QA sweep)."""
        events, labels = as_chunk(events, "input"), np.asarray(labels)
        if labels.ndim != 1 or len(events) != len(labels):
            raise DenoiseMetricsError(f"{len(events)} events but labels of shape {labels.shape}")
        problem = label_problem(labels) if len(labels) else None
        if problem:
            raise DenoiseMetricsError(problem)
        labels = labels.astype(np.uint8, copy=False)
        self.total += np.bincount(labels, minlength=256)
        self.inputs_seen += len(events)
        if len(events):
            self._inputs.append((events, labels))
        self._match()

    def add_output(self, events: np.ndarray) -> None:
        events = as_chunk(events, "output")
        self.outputs_seen += len(events)
        if len(events):
            self._outputs.append(events)
        self._match()

    def _match(self) -> None:
        while self._inputs and self._outputs:
            events, labels = self._inputs[0]
            out = self._outputs[0]
            i, j, ok = match_subsequence(events["t"], events["x"], events["y"], events["p"], labels, self._i,
                                         out["t"], out["x"], out["y"], out["p"], self._j, self.kept)
            if not ok:
                self._fail(out[j])
            self._i, self._j = i, j
            if i == len(events):
                self._inputs.pop(0)
                self._i = 0
            if j == len(out):
                self._outputs.pop(0)
                self._j = 0

    def _fail(self, event) -> None:
        raise DenoiseMetricsError(
            f"filtered event (t={event['t']}, x={event['x']}, y={event['y']}, p={int(event['p'])}) is not in the "
            "input at its place: the filtered stream is not a subsequence of the input (give the stream the "
            "filter read as --input)")

    def finish(self) -> "DenoiseScore":
        """The score; raises when output events are left unmatched."""
        if self._outputs:
            self._fail(self._outputs[0][self._j])
        return DenoiseScore(self.total[:4].copy(), self.kept[:4].copy())


class DenoiseScore:
    """Kept / total per label (0 signal, 1 leak, 2 shot, 3 hot) and the rates derived from them."""

    def __init__(self, total: np.ndarray, kept: np.ndarray) -> None:
        self.total, self.kept = np.asarray(total, dtype=np.int64), np.asarray(kept, dtype=np.int64)

    @property
    def tpr(self) -> float:
        """Signal kept / signal (recall)."""
        return float(self.kept[0] / self.total[0]) if self.total[0] else math.nan

    @property
    def fpr(self) -> float:
        """Noise kept / noise."""
        noise = self.total[1:].sum()
        return float(self.kept[1:].sum() / noise) if noise else math.nan

    @property
    def precision(self) -> float:
        kept = self.kept.sum()
        return float(self.kept[0] / kept) if kept else math.nan

    @property
    def f1(self) -> float:
        p, r = self.precision, self.tpr
        return 2 * p * r / (p + r) if p + r > 0 else math.nan

    def as_dict(self) -> dict:
        return {
            "tpr": self.tpr, "fpr": self.fpr, "precision": self.precision, "f1": self.f1,
            "events_in": int(self.total.sum()), "events_kept": int(self.kept.sum()),
            "labels": {name: {"kept": int(self.kept[i]), "total": int(self.total[i])}
                       for i, name in enumerate(LABEL_NAMES)},
        }


def roc_auc(points: Iterable[tuple[float, float]]) -> tuple[list[tuple[float, float]], float]:
    """DND21's ROC: the (FPR, TPR) points plus (0, 0) and (1, 1), sorted by FPR (then TPR); trapezoid AUC."""
    curve = sorted([(0.0, 0.0), *((float(f), float(t)) for f, t in points), (1.0, 1.0)])
    area = sum((f1 - f0) * (t0 + t1) / 2 for (f0, t0), (f1, t1) in zip(curve, curve[1:]))
    return curve, area


def esr(counts: np.ndarray, n_pixels: int) -> float:
    """E-MLB's event structural ratio of one slice from its per-pixel event counts (polarity ignored).

    ``NTSS = sum n_i (n_i - 1) / (N (N - 1))``, ``L_N = K - sum (1 - M/N)^n_i`` with ``K`` pixels and
    ``M = floor(2N/3)``; ``ESR = sqrt(NTSS * L_N)``. Pixels without events add 1 each to the second sum.
    """
    n = np.asarray(counts, dtype=np.float64)
    n = n[n > 0]
    total = n.sum()
    if total < 2:
        return math.nan
    ntss = float((n * (n - 1)).sum() / (total * (total - 1)))
    m = math.floor(2 * total / 3)
    base = 1.0 - m / total
    l_n = n_pixels - (float((base ** n).sum()) + (n_pixels - len(n)))
    return math.sqrt(ntss * l_n)


class EsrMeter:
    """ESR per slice of ``slice_events`` events (the last, shorter slice is left out unless it is the only one)
    and their mean, MESR (E-MLB: 30,000-event slices)."""

    def __init__(self, width: int, height: int, slice_events: int = 30_000) -> None:
        if slice_events < 2:
            raise DenoiseMetricsError(f"slice_events must be >= 2, got {slice_events}")
        self.width, self.n_pixels, self.slice_events = width, width * height, slice_events
        self.counts = np.zeros(self.n_pixels, dtype=np.int64)
        self.filled = 0
        self.values: list[float] = []
        self._checker = StreamChecker(StreamInfo(width, height))  # (off the sensor: counted on the wrong pixel)

    def add(self, chunk: np.ndarray) -> None:
        chunk = self._checker.check(chunk)
        while len(chunk):
            take = min(self.slice_events - self.filled, len(chunk))
            part = chunk[:take]
            self.counts += np.bincount(part["y"].astype(np.int64) * self.width + part["x"], minlength=self.n_pixels)
            self.filled += take
            chunk = chunk[take:]
            if self.filled == self.slice_events:
                self.values.append(esr(self.counts, self.n_pixels))
                self.counts[:] = 0
                self.filled = 0

    def finish(self) -> dict:
        if not self.values and self.filled >= 2:
            self.values.append(esr(self.counts, self.n_pixels))
        values = [v for v in self.values if not math.isnan(v)]
        return {"slices": len(self.values), "slice_events": self.slice_events,
                "mesr": float(np.mean(values)) if values else math.nan, "esr": self.values}
