"""MLPF, a learned background-activity filter (Guo & Delbruck, TPAMI 2023), and its training on labelled streams.

Each event is described by a time-surface patch around it (the ON and the OFF map, ``patch x patch`` pixels,
each value ``max(0, 1 - age / tau)``) and its polarity (see ``evtools/_kernels/mlpf.py``); a perceptron with one
hidden layer of ReLU units gives the probability that the event is signal, and the filter keeps the events above
a threshold. :func:`train` fits the perceptron with numpy alone (mini-batch Adam on the cross-entropy, early
stopping on a held-out part) to streams whose events are labelled, as ``evtools simulate`` labels injected noise.

References
----------
S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI 45(1), 2023.
D. P. Kingma, J. Ba, "Adam: A Method for Stochastic Optimization", ICLR 2015.
"""

from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evtools._kernels import mlpf as kernels
from evtools.errors import EvtoolsError
from evtools.events import record_words
from evtools.inputs import note_input

DEFAULT_WEIGHTS = Path(__file__).parent / "data" / "mlpf.npz"
"""The weights shipped with evtools (trained as the README says)."""


class MlpfError(EvtoolsError, ValueError):
    """A weights file that does not describe an MLPF, or training data that cannot train one."""


@dataclass
class Weights:
    """A trained MLPF: ``w1`` (inputs, hidden), ``b1`` (hidden), ``w2`` (hidden), ``b2``; the patch side (odd) and
    the time constant its features were made with: ``tau_scale`` times the stream's activity time (the time the
    sensor takes to fire once per pixel, followed as the stream goes: ``evtools/_kernels/mlpf.py``) when
    ``tau_scale`` > 0, else the fixed ``tau_us``; ``info``: how it was trained (free-form strings)."""

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float
    patch: int
    tau_us: int
    tau_scale: float = 0.0
    info: dict = field(default_factory=dict)

    @property
    def radius(self) -> int:
        return self.patch // 2

    def check(self, name: str) -> "Weights":
        inputs = 2 * self.patch * self.patch + 1
        if self.patch < 1 or self.patch % 2 == 0:
            raise MlpfError(f"{name}: patch {self.patch} is not an odd number of pixels")
        if not (math.isfinite(self.tau_scale) and self.tau_scale >= 0):
            raise MlpfError(f"{name}: tau_scale {self.tau_scale} is not a finite number >= 0")
        if self.tau_scale == 0 and self.tau_us < 1:
            raise MlpfError(f"{name}: tau_us {self.tau_us} is not positive (and no tau_scale)")
        hidden = len(self.b1)
        if self.w1.shape != (inputs, hidden) or self.w2.shape != (hidden,):
            raise MlpfError(f"{name}: weights of shapes w1 {self.w1.shape}, b1 {self.b1.shape}, w2 {self.w2.shape} "
                            f"do not fit a {self.patch}x{self.patch} patch ({inputs} inputs, w1 ({inputs}, hidden))")
        if not all(np.isfinite(a).all() for a in (self.w1, self.b1, self.w2)) or not math.isfinite(self.b2):
            raise MlpfError(f"{name}: the weights hold NaN or infinite values")
        return self

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "wb") as sink:
            np.savez(sink, w1=self.w1, b1=self.b1, w2=self.w2, b2=np.float64(self.b2), patch=np.int64(self.patch),
                     tau_us=np.int64(self.tau_us), tau_scale=np.float64(self.tau_scale),
                     info=np.array(repr(sorted(self.info.items()))))


def load_weights(path: str | os.PathLike | None = None) -> Weights:
    """The weights in ``path`` (an ``.npz`` written by :meth:`Weights.save`), or the shipped ones; checked."""
    path = DEFAULT_WEIGHTS if path is None else Path(path)
    note_input(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            if "patch" in data and not float(data["patch"]).is_integer():  # (5.5 was taken as 5)
                raise MlpfError(f"{path}: the patch size must be a whole number of pixels, not {float(data['patch'])}")
            weights = Weights(np.asarray(data["w1"], np.float64), np.asarray(data["b1"], np.float64).reshape(-1),
                              np.asarray(data["w2"], np.float64).reshape(-1), float(data["b2"]), int(data["patch"]),
                              int(data["tau_us"]), float(data["tau_scale"]) if "tau_scale" in data else 0.0,
                              {"file": str(path)})
            if "info" in data:
                weights.info["trained"] = str(data["info"])
    except FileNotFoundError:
        raise MlpfError(f"{path}: no such weights file") from None
    except KeyError as error:  # (numpy's message: "w1 is not a file in the archive")
        missing = str(error.args[0]).split(" ")[0] if error.args else "?"
        raise MlpfError(f"{path}: not MLPF weights (no {missing!r} array; train-denoiser writes them)") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # (a damaged copy: a traceback, a QA sweep)
        raise MlpfError(f"{path}: not an MLPF weights file (an .npz archive as train-denoiser writes), or a "
                        "damaged one") from None
    return weights.check(str(path))


class FeatureMaker:
    """The features of a stream's events, chunk by chunk (the ON and OFF maps carried over)."""

    def __init__(self, width: int, height: int, patch: int, tau_us: int, tau_scale: float = 0.0) -> None:
        self.radius, self.tau_us = patch // 2, int(tau_us)
        self.inputs = 2 * patch * patch + 1
        self.maps = kernels.padded_maps(width, height, self.radius)
        self.clock, self.scale = kernels.new_clock(width * height), float(tau_scale) * (width * height)

    def features(self, chunk: np.ndarray, take: np.ndarray) -> np.ndarray:
        """(number taken, inputs) float32: the features of the events of ``chunk`` where ``take``."""
        words = record_words(np.ascontiguousarray(chunk))
        rows = np.empty((int(take.sum()), self.inputs), np.float32)
        kernels.mlpf_features(words, self.maps, self.radius, self.clock, self.scale, self.tau_us,
                              np.ascontiguousarray(take, np.bool_), rows)
        return rows


SIGNAL_FILTER = {"methods": "stcf", "radius": 2, "k": 4, "dt_us": 30_000}
"""The filter whose kept events a recording trains on as signal when it has no labels: STCF, four of the 24
pixels around within 30 ms. Lenient on purpose: sparse signal it rejects is missing from training, which cost
more than the noise it lets through (self-trained vs trained on the true labels, AUC on another noise draw, a
128 x 96 moving texture with 5 Hz noise: 10 ms -0.010, 30 ms -0.005, 100 ms -0.025; 1 Hz: -0.011, -0.002,
-0.001; the true signal itself: -0.001)."""

QUIET_FILTER = {"methods": "stcf", "radius": 2, "k": 4, "dt_us": 10_000}
"""The stricter filter that finds a recording's quiet pixels (:class:`NoiseMeter`): where it keeps nothing nearby
there is no signal."""


@dataclass
class NoiseRates:
    """Noise measured on a recording (:class:`NoiseMeter`): ``shot_hz`` (ON and OFF together) and ``leak_hz`` (ON)
    per pixel, from ``pixels`` pixels (``source``: "quiet pixels", those where :data:`QUIET_FILTER` kept nothing
    nearby, or "rejected events" over the whole sensor when too few are quiet); ``events`` and ``duration_us`` of
    the recording."""

    shot_hz: float
    leak_hz: float
    pixels: int
    source: str
    events: int
    duration_us: int


QUIET_RADIUS = 2
"""A quiet pixel has no event kept by :data:`QUIET_FILTER` within this many pixels (measured: with radius 0 the
pixels beside a moving texture's edges counted its rejected events as noise, 1.9 Hz on a noiseless scene)."""


class NoiseMeter:
    """Measures a recording's background activity chunk by chunk, as :class:`NoiseRates`: the event rates of its
    quiet pixels (no event kept by :data:`QUIET_FILTER` nearby: no signal there), the top 1 % of them left out (hot
    pixels); ON events beyond the OFF ones are leak, the rest shot noise (equally ON and OFF). When fewer than
    1 % of the pixels (and 16) are quiet, a busy scene, the events the filter rejects stand for the noise."""

    def __init__(self, width: int, height: int) -> None:
        from evtools.filters import BAFilter

        self.width, self.height = width, height
        self.filter = BAFilter(width, height, **QUIET_FILTER)
        self.counts = np.zeros((2, height * width), np.int64)  # OFF, ON events per pixel
        self.kept = np.zeros(height * width, np.int64)
        self.first_us = self.last_us = None

    def process(self, chunk: np.ndarray) -> None:
        if not len(chunk):
            return
        if self.first_us is None:
            self.first_us = int(chunk["t"][0])
        self.last_us = int(chunk["t"][-1])
        np.add.at(self.counts, (chunk["p"].astype(np.int64), self._pixels(chunk)), 1)
        self._keep(self.filter.process(chunk))

    def _pixels(self, events: np.ndarray) -> np.ndarray:
        return events["y"].astype(np.int64) * self.width + events["x"]

    def _keep(self, kept: np.ndarray) -> None:
        self.kept += np.bincount(self._pixels(kept), minlength=self.kept.size)

    def _quiet(self) -> np.ndarray:
        """(height, width) bool: no kept event within QUIET_RADIUS pixels (a pixel beside signal gets some)."""
        r = QUIET_RADIUS
        padded = np.pad(self.kept.reshape(self.height, self.width) > 0, r)
        near = np.zeros((self.height, self.width), bool)
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                near |= padded[dy:dy + self.height, dx:dx + self.width]
        return ~near

    def rates(self) -> NoiseRates:
        self._keep(self.filter.flush())
        events = int(self.counts.sum())
        duration_us = 0 if self.first_us is None else self.last_us - self.first_us
        if duration_us <= 0:
            raise MlpfError(f"{events:,} events spanning {duration_us} us: too short to measure the noise")
        quiet = np.flatnonzero(self._quiet().ravel())
        if len(quiet) >= max(16, self.kept.size // 100):
            totals = self.counts[:, quiet].sum(axis=0)
            quiet = quiet[totals <= np.quantile(totals, 0.99)]  # hot pixels out
            off, on = self.counts[:, quiet].sum(axis=1)
            pixels, source = len(quiet), "quiet pixels"
        else:
            rejected = events - int(self.kept.sum())
            on_fraction = self.counts[1].sum() / events
            off, on = rejected * (1.0 - on_fraction), rejected * on_fraction
            pixels, source = self.kept.size, "rejected events"
        per_pixel_second = 1.0 / (pixels * duration_us * 1e-6)
        off_hz, on_hz = off * per_pixel_second, on * per_pixel_second
        return NoiseRates(float(2.0 * off_hz), float(max(0.0, on_hz - off_hz)), int(pixels), source, events,
                          duration_us)


class SelfLabeller:
    """A recording labelled without truth (the DND21 recipe, automated): its events that :data:`SIGNAL_FILTER`
    keeps are signal (label 0), the rest (its own noise, and signal too sparse to tell) left out, and shot and
    leak noise at ``noise``'s rates is injected and labelled (:class:`evtools.noise.NoiseInjector`: 1 leak,
    2 shot). ``process(chunk) -> (events, labels)``, then ``flush()``; the same for any chunking. (Measured: keeping
    the rejected events in the stream, unlabelled, trained worse models: they double the noise around every
    event.)"""

    def __init__(self, width: int, height: int, noise: NoiseRates, seed: int) -> None:
        from evtools.filters import BAFilter
        from evtools.noise import NoiseInjector

        self.filter = BAFilter(width, height, **SIGNAL_FILTER)
        self.injector = NoiseInjector(width, height, shot_noise_rate_hz=noise.shot_hz, leak_rate_hz=noise.leak_hz,
                                      seed=seed)

    def process(self, chunk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.injector.process(self.filter.process(chunk))

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        from evtools.events import join

        events, labels = self.injector.process(self.filter.flush())
        tail_events, tail_labels = self.injector.flush()
        return join([events, tail_events]), np.concatenate([labels, tail_labels])


def forward(weights: Weights, features: np.ndarray) -> np.ndarray:
    """The perceptron's logits for rows of features (numpy; the filter's kernel computes the same)."""
    hidden = np.maximum(features @ weights.w1 + weights.b1, 0.0)
    return hidden @ weights.w2 + weights.b2


@dataclass
class TrainingReport:
    epochs: int
    train_loss: float
    validation_loss: float
    validation_auc: float
    train_events: int
    validation_events: int
    signal_fraction: float


def train(features: np.ndarray, labels: np.ndarray, validation: np.ndarray, *, patch: int, tau_us: int,
          tau_scale: float = 0.0, hidden: int = 20, seed: int = 0, epochs: int = 60, batch: int = 512,
          learning_rate: float = 2e-3, patience: int = 5, on_epoch=None) -> tuple[Weights, TrainingReport]:
    """Fit the perceptron to ``features`` (n, inputs; any float type, kept as given: float16 halves the memory)
    and ``labels`` (1 signal, 0 noise): mini-batch Adam on the mean cross-entropy, stopping when the loss on the
    rows where ``validation`` is true has not improved for ``patience`` epochs (the best weights are kept). The
    same inputs and seed give the same weights, byte for byte. ``on_epoch(epoch, held-out loss)``, if given, is
    called after each epoch (progress)."""
    labels = np.asarray(labels, np.float64)
    train_rows, check_rows = np.flatnonzero(~validation), np.flatnonzero(validation)
    if len(train_rows) < 2 or len(check_rows) < 1:
        raise MlpfError(f"too few labelled events to train ({len(train_rows)}) and check ({len(check_rows)})")
    train_y = labels[train_rows]
    if train_y.min() == train_y.max():
        raise MlpfError("the labels are all signal or all noise: nothing to learn")
    prior = float(np.clip(train_y.mean(), 1e-3, 1 - 1e-3))
    rng = np.random.default_rng(seed)
    inputs = features.shape[1]
    params = [rng.normal(0.0, math.sqrt(2.0 / inputs), (inputs, hidden)), np.zeros(hidden),
              rng.normal(0.0, math.sqrt(1.0 / hidden), hidden), np.array(math.log(prior / (1 - prior)))]
    moments = [np.zeros_like(p) for p in params]
    squares = [np.zeros_like(p) for p in params]
    beta1, beta2, epsilon, step = 0.9, 0.999, 1e-8, 0

    def logits(p, rows) -> np.ndarray:  # in blocks: a (rows, hidden) float64 array at a time
        return np.concatenate([np.maximum(np.asarray(features[part], np.float64) @ p[0] + p[1], 0.0) @ p[2] + p[3]
                               for part in np.array_split(rows, max(1, len(rows) // 65536))])

    def loss_of(p, rows) -> float:
        z = logits(p, rows)
        return float(np.mean(np.logaddexp(0.0, z) - labels[rows] * z))  # the cross-entropy of sigmoid(z), stably

    best, best_loss, waited, epoch = [p.copy() for p in params], loss_of(params, check_rows), 0, 0
    for epoch in range(1, epochs + 1):
        order = train_rows[rng.permutation(len(train_rows))]
        for begin in range(0, len(order), batch):
            rows = order[begin:begin + batch]
            x, y = np.asarray(features[rows], np.float64), labels[rows]
            pre = x @ params[0] + params[1]
            h = np.maximum(pre, 0.0)
            z = h @ params[2] + params[3]
            dz = (1.0 / (1.0 + np.exp(-z)) - y) / len(y)
            dh = np.outer(dz, params[2]) * (pre > 0)
            grads = [x.T @ dh, dh.sum(axis=0), h.T @ dz, np.array(dz.sum())]
            step += 1
            for p, g, m, v in zip(params, grads, moments, squares):
                m *= beta1
                m += (1 - beta1) * g
                v *= beta2
                v += (1 - beta2) * g * g
                p -= learning_rate * (m / (1 - beta1 ** step)) / (np.sqrt(v / (1 - beta2 ** step)) + epsilon)
        loss = loss_of(params, check_rows)
        if on_epoch is not None:
            on_epoch(epoch, loss)
        if loss < best_loss - 1e-6:
            best, best_loss, waited = [p.copy() for p in params], loss, 0
        else:
            waited += 1
            if waited >= patience:
                break
    weights = Weights(best[0], best[1], best[2], float(best[3]), patch, tau_us, tau_scale)
    report = TrainingReport(epoch, loss_of(best, train_rows), best_loss, auc(logits(best, check_rows),
                                                                             labels[check_rows]),
                            len(train_rows), len(check_rows), float(labels.mean()))
    return weights, report


def auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for ``labels`` (1 positive): the probability that a positive
    scores above a negative, ties counting half (Mann-Whitney)."""
    labels = np.asarray(labels).astype(bool)
    positives, negatives = int(labels.sum()), int((~labels).sum())
    if not positives or not negatives:
        return float("nan")
    order = np.argsort(scores, kind="stable")
    ranks = np.empty(len(scores))
    sorted_scores = np.asarray(scores)[order]
    # average ranks of ties
    edges = np.flatnonzero(np.diff(sorted_scores)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [len(scores)]))
    for start, end in zip(starts, ends):
        ranks[order[start:end]] = (start + end + 1) / 2.0
    return float((ranks[labels].sum() - positives * (positives + 1) / 2.0) / (positives * negatives))
