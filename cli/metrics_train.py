"""``evtools metrics train-denoiser``: train the MLPF filter on labelled streams, or on a camera's own recordings
with no labels at all (the DND21 recipe, automated: :class:`evtools.mlpf.SelfLabeller`)."""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager

import click
import numpy as np

from evtools import interrupt
from evtools.cli.options import Duration, FileRead, FiniteRange, echo_json, json_option, wants_json
from evtools.cli.progress import with_progress
from evtools.formats import open_events
from evtools.formats.io import atomic_path, same_file
from evtools.formats.thresholds import read_labels
from evtools.formats.truth import Fingerprint, check_labelled
from evtools.mlpf import FeatureMaker, MlpfError, NoiseMeter, NoiseRates, SelfLabeller, train


class Sample:
    """Rows of features drawn from one labelled stream (each event with probability ``fraction``): the features
    (float16: they lie in [0, 1]), whether each is signal, and its time (the held-out part is the end of the
    stream by time)."""

    def __init__(self, maker: FeatureMaker, fraction: float, rng: np.random.Generator) -> None:
        self.maker, self.fraction, self.rng = maker, fraction, rng
        self.rows, self.signal, self.times = [], [], []

    def add(self, events: np.ndarray, labels: np.ndarray) -> None:
        take = self.rng.random(len(events)) < self.fraction
        self.rows.append(self.maker.features(events, take).astype(np.float16))
        self.signal.append(labels[take] == 0)
        self.times.append(events["t"][take])

    def result(self, held_out: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        times = np.concatenate(self.times)
        first, last = (int(times[0]), int(times[-1])) if len(times) else (0, 0)
        return (np.concatenate(self.rows), np.concatenate(self.signal),
                times >= first + (1.0 - held_out) * (last - first))


def _from_truth(noisy: str, truth: str, features_of, budget: int, rng, held_out: float):
    """Rows of a stream labelled by its truth file; ``features_of(width, height)``: its :class:`FeatureMaker`."""
    labels, fingerprint = read_labels(truth)
    seen = 0
    read = Fingerprint()
    with open_events(noisy) as stream:
        sample = Sample(features_of(stream.info.width, stream.info.height), min(1.0, budget / max(len(labels), 1)),
                        rng)
        for chunk in with_progress(stream, stream, f"features of {os.path.basename(noisy)}"):
            if seen + len(chunk) > len(labels):
                raise MlpfError(f"{truth}: {len(labels):,} labels but {noisy} has more events (give the truth file "
                                "written with that stream)")
            sample.add(chunk, labels[seen:seen + len(chunk)])
            read.add(chunk)
            seen += len(chunk)
    if interrupt.received() is not None:  # (stopped: fewer events than labels, and no model is made)
        raise interrupt.StopReading
    if seen != len(labels):
        raise MlpfError(f"{truth}: {len(labels):,} labels but {noisy} has {seen:,} events (give the truth file "
                        "written with that stream)")
    check_labelled(truth, fingerprint, read, noisy)
    return sample.result(held_out)


def _balanced(part: tuple, rng: np.random.Generator) -> tuple:
    """One stream's rows (features, signal, held out) with as many noise rows as signal rows: the commoner kind
    thinned at random, the order kept. Each stream then teaches what tells signal from noise, not how much noise
    its camera makes; left unbalanced, the cameras' noise shares set the decision rule, and a model trained without
    a camera lost up to 0.05 AUC on it (issue 41: README, "leave-one-sensor-out"). A stream of one kind is kept
    whole."""
    features, signal, check = part
    signal_rows, noise_rows = np.flatnonzero(signal), np.flatnonzero(~signal)
    size = min(len(signal_rows), len(noise_rows))
    if size == 0:
        return part
    keep = np.sort(np.concatenate([rng.choice(signal_rows, size, replace=False),
                                   rng.choice(noise_rows, size, replace=False)]))
    return features[keep], signal[keep], check[keep]


def _measure(recording: str) -> NoiseRates:
    with open_events(recording) as stream:
        meter = NoiseMeter(stream.info.width, stream.info.height)
        for chunk in with_progress(stream, stream, f"noise of {os.path.basename(recording)}"):
            meter.process(chunk)
    try:
        return meter.rates()
    except MlpfError as error:
        raise MlpfError(f"{recording}: {error}") from None


def _self_labelled(recording: str, noise: NoiseRates, features_of, budget: int, rng, held_out: float, seed: int):
    """Rows of a recording labelled by :class:`SelfLabeller`, at most about ``budget`` (drawn as if every event
    of the recording were kept, with the noise to inject)."""
    with open_events(recording) as stream:
        width, height = stream.info.width, stream.info.height
        expected = noise.events + (noise.shot_hz + noise.leak_hz) * width * height * noise.duration_us * 1e-6
        sample = Sample(features_of(width, height), min(1.0, budget / max(expected, 1.0)), rng)
        labeller = SelfLabeller(width, height, noise, seed)
        for chunk in with_progress(stream, stream, f"features of {os.path.basename(recording)}"):
            sample.add(*labeller.process(chunk))
        sample.add(*labeller.flush())
    return sample.result(held_out)


@contextmanager
def _epochs_shown(epochs: int):
    """A callback showing the training's epochs on stderr when it is a terminal."""
    if not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn

    with Progress(TextColumn("training"), BarColumn(), TextColumn("epoch {task.completed}/{task.total}"),
                  TextColumn("held-out loss {task.fields[loss]:.4f}"), transient=True,
                  console=Console(stderr=True)) as progress:
        task = progress.add_task("training", total=epochs, loss=float("nan"))
        yield lambda epoch, loss: progress.update(task, completed=epoch, loss=loss)


@click.command("train-denoiser")
@click.argument("recordings", nargs=-1, required=True, type=FileRead())
@click.option("--truth", "truths", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Truth file of each RECORDING, in the same order (`evtools simulate ... --truth`: labels per "
                   "event). Without: each recording labels itself (see above).")
@click.option("--noise-rate-hz", type=FiniteRange(0, 1e4, min_open=True), default=None,
              help="Without --truth: the shot-noise rate per pixel to inject (ON and OFF together) instead of the "
                   "one measured on each recording's quiet pixels.")
@click.option("--leak-rate-hz", type=FiniteRange(0, 1e4), default=None,
              help="Without --truth: the leak rate per pixel to inject (ON) instead of the measured one; 0 with "
                   "--noise-rate-hz unless given.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Weights file to write (.npz).")
@click.option("--patch", type=click.IntRange(1, 15), default=5, show_default=True,
              help="Side of the time-surface patch, pixels (odd).")
@click.option("--hidden", type=click.IntRange(1, 256), default=10, show_default=True, help="Hidden units.")
@click.option("--tau-scale", type=FiniteRange(0, 100, min_open=True), default=0.25, show_default=True,
              help="Time constant of the time surface as a multiple of the stream's activity time (the time the "
                   "sensor takes to fire once per pixel), followed as the stream goes.")
@click.option("--tau", "tau_us", type=Duration(), default=None,
              help="A fixed time constant instead of --tau-scale (a neighbour's event counts 1 - age / tau, 0 from "
                   "tau on).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Sampling, noise, initial weights, batch order.")
@click.option("--max-events", type=click.IntRange(min=100), default=400_000, show_default=True,
              help="Labelled events sampled, shared equally by the recordings (each event of a recording alike "
                   "likely); of each recording's, the commoner kind (signal or noise) is then thinned to as many "
                   "as the other.")
@click.option("--held-out", type=FiniteRange(0.05, 0.5), default=0.2, show_default=True,
              help="The last part (by time) of each stream kept for early stopping and the reported AUC.")
@click.option("--epochs", type=click.IntRange(1, 1000), default=60, show_default=True, help="At most this many.")
@json_option
def train_denoiser(recordings, truths, noise_rate_hz, leak_rate_hz, output, patch, hidden, tau_scale, tau_us, seed,
                   max_events, held_out, epochs, as_json):
    """Train the MLPF filter (`bafilter --method mlpf --weights FILE`) on RECORDINGS.

    With --truth (one per recording): on their labelled events (`evtools simulate RECORDING --truth T.h5` injects
    labelled noise into a recording). Without: on the recordings alone, so a new camera needs no labels. Each
    recording's noise is measured on its quiet pixels (or given with --noise-rate-hz), its events that an STCF
    keeps (4 of the 24 pixels around active within 30 ms) are taken as signal, and noise at that rate is injected
    with labels (the DND21 recipe). Numpy only: mini-batch Adam on the cross-entropy, early stopping on the
    held-out end of each stream; the same inputs and --seed give the same weights, byte for byte.

    \b
    evtools metrics train-denoiser my_camera_1.aedat4 my_camera_2.aedat4 -o weights.npz
    evtools bafilter other.aedat4 --method mlpf --weights weights.npz --threshold 0.5 -o clean.aedat4
    evtools metrics train-denoiser noisy.aedat4 --truth t.h5 -o weights.npz
    """
    if truths and len(truths) != len(recordings):
        raise click.UsageError(f"give one --truth per RECORDING ({len(recordings)} recordings, {len(truths)} "
                               "--truth)")
    if truths and (noise_rate_hz is not None or leak_rate_hz is not None):
        raise click.UsageError("--noise-rate-hz and --leak-rate-hz are for recordings without --truth (their noise "
                               "is injected); with --truth the labels say what is noise")
    if patch % 2 == 0:
        raise click.BadParameter(f"{patch} is even; the patch is centred on the event", param_hint="--patch")
    for name in (*recordings, *truths):
        if os.path.exists(output) and same_file(output, name):
            raise click.UsageError(f"{output}: is an input; choose another -o")
    if tau_us is not None:
        tau_scale = 0.0
    budget = max_events // len(recordings)
    rng = np.random.default_rng(seed)
    parts, measured = [], []
    def features_of(width: int, height: int) -> FeatureMaker:
        return FeatureMaker(width, height, patch, tau_us or 0, tau_scale)

    for index, recording in enumerate(recordings):
        if truths:
            parts.append(_balanced(_from_truth(recording, truths[index], features_of, budget, rng, held_out), rng))
            continue
        noise = _measure(recording)
        if noise_rate_hz is not None or leak_rate_hz is not None:
            noise = NoiseRates(noise_rate_hz or 0.0, leak_rate_hz or 0.0, noise.pixels, "given", noise.events,
                               noise.duration_us)
        if noise.shot_hz + noise.leak_hz <= 0:
            raise MlpfError(f"{recording}: no noise measured on its {noise.pixels:,} {noise.source} (give "
                            "--noise-rate-hz)")
        measured.append({"recording": recording, "shot_rate_hz": noise.shot_hz, "leak_rate_hz": noise.leak_hz,
                         "measured_on": noise.source, "pixels": noise.pixels})
        parts.append(_balanced(_self_labelled(recording, noise, features_of, budget, rng, held_out, seed + index),
                               rng))
    if interrupt.received() is not None:  # (a model of part of the recordings, unmarked, once went out as whole; an
        raise interrupt.StopReading  # early stop said "too few labelled events", exit 1: a QA sweep): no weights
    features, signal, check = (np.concatenate([part[i] for part in parts]) for i in range(3))
    try:
        with _epochs_shown(epochs) as shown:
            weights, report = train(features, signal.astype(np.float64), check, patch=patch, tau_us=tau_us or 0,
                                    tau_scale=tau_scale, hidden=hidden, seed=seed, epochs=epochs, on_epoch=shown)
    except MlpfError as error:  # (what the recordings gave: "too few labelled events" named none, a QA sweep)
        raise MlpfError(f"{', '.join(recordings)}: {error}") from None
    weights.info = {"inputs": " ".join(os.path.basename(n) for n in recordings), "seed": str(seed),
                    "labels": "truth" if truths else "self", "validation_auc": f"{report.validation_auc:.4f}",
                    "epochs": str(report.epochs)}
    with atomic_path(output) as temporary:
        weights.save(temporary)
    result = {"output": output, "labels": "truth" if truths else "self", "patch": patch, "hidden": hidden,
              "tau_scale": tau_scale or None, "tau_us": tau_us, "seed": seed, "noise": measured,
              "train_events": report.train_events, "held_out_events": report.validation_events,
              "signal_fraction": report.signal_fraction, "epochs": report.epochs, "train_loss": report.train_loss,
              "held_out_loss": report.validation_loss, "held_out_auc": report.validation_auc}
    if wants_json(as_json):
        echo_json(result, indent=2)
        return
    for row in measured:
        click.echo(f"{row['recording']}: noise injected: shot {row['shot_rate_hz']:.3g} Hz, leak "
                   f"{row['leak_rate_hz']:.3g} Hz per pixel ({row['measured_on']}"
                   + (f", {row['pixels']:,} pixels)" if row["measured_on"] != "given" else ")"))
    click.echo(f"{output}: trained on {report.train_events:,} events ({report.signal_fraction:.1%} signal), "
               f"{report.epochs} epochs; held out {report.validation_events:,}: cross-entropy "
               f"{report.validation_loss:.4f}, AUC {report.validation_auc:.4f}"
               + ("" if truths else " (against the self-made labels)"))
