"""``evtools metrics train-denoiser``: train the MLPF filter on streams whose events are labelled."""

from __future__ import annotations

import json
import os

import click
import numpy as np

from evtools.cli.options import Duration, FiniteRange, json_option, wants_json
from evtools.formats import open_events
from evtools.formats.io import atomic_path, same_file
from evtools.formats.thresholds import read_labels
from evtools.mlpf import FeatureMaker, MlpfError, train


def _features(noisy: str, truth: str, patch: int, tau_us: int, fraction: float, held_out: float, rng):
    """The sampled events' features (float16: they lie in [0, 1]), whether each is signal, and whether it is in
    the held-out end of the stream."""
    labels = read_labels(truth)
    take = rng.random(len(labels)) < fraction  # drawn up front: the rows are known before the stream is read
    rows = np.empty((int(take.sum()), 2 * patch * patch + 1), np.float16)
    seen = filled = 0
    with open_events(noisy) as stream:
        maker = FeatureMaker(stream.info.width, stream.info.height, patch, tau_us)
        for chunk in stream:
            if seen + len(chunk) > len(labels):
                raise MlpfError(f"{truth}: {len(labels):,} labels but {noisy} has more events (give the truth file "
                                "written with that stream)")
            part = maker.features(chunk, take[seen:seen + len(chunk)])
            rows[filled:filled + len(part)] = part
            filled += len(part)
            seen += len(chunk)
    if seen != len(labels):
        raise MlpfError(f"{truth}: {len(labels):,} labels but {noisy} has {seen:,} events (give the truth file "
                        "written with that stream)")
    index = np.flatnonzero(take)
    return rows, labels[index] == 0, index >= (1.0 - held_out) * len(labels)


@click.command("train-denoiser")
@click.argument("noisy", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--truth", "truths", multiple=True, required=True, type=click.Path(exists=True, dir_okay=False),
              help="Truth file of each NOISY, in the same order (`evtools simulate ... --truth`: labels per event).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Weights file to write (.npz).")
@click.option("--patch", type=click.IntRange(1, 15), default=7, show_default=True,
              help="Side of the time-surface patch, pixels (odd).")
@click.option("--hidden", type=click.IntRange(1, 256), default=20, show_default=True, help="Hidden units.")
@click.option("--tau", "tau_us", type=Duration(), default="100ms", show_default=True,
              help="Time constant of the time surface: a neighbour's event counts 1 - age / tau, 0 from tau on.")
@click.option("--seed", type=int, default=0, show_default=True, help="Sampling, initial weights, batch order.")
@click.option("--max-events", type=click.IntRange(min=100), default=400_000, show_default=True,
              help="Labelled events sampled from all inputs together (each event alike likely).")
@click.option("--held-out", type=FiniteRange(0.05, 0.5), default=0.2, show_default=True,
              help="The last part of each stream kept for early stopping and the reported AUC.")
@click.option("--epochs", type=click.IntRange(1, 1000), default=60, show_default=True, help="At most this many.")
@json_option
def train_denoiser(noisy, truths, output, patch, hidden, tau_us, seed, max_events, held_out, epochs, as_json):
    """Train the MLPF filter (`bafilter --method mlpf --weights FILE`) on NOISY streams labelled by their --truth.

    Labels come from `evtools simulate RECORDING --truth T.h5` (noise injected into a recording, every event
    labelled signal or noise). Numpy only: mini-batch Adam on the cross-entropy, early stopping on the held-out
    end of each stream; the same inputs and --seed give the same weights, byte for byte.

    \b
    evtools simulate walk.aedat --shot-noise-rate-hz 5 --leak-rate-hz 0.2 --seed 1 --truth t.h5 -o noisy.aedat4
    evtools metrics train-denoiser noisy.aedat4 --truth t.h5 -o weights.npz
    evtools bafilter other.aedat4 --method mlpf --weights weights.npz --threshold 0.5 -o clean.aedat4
    """
    if len(truths) != len(noisy):
        raise click.UsageError(f"give one --truth per NOISY stream ({len(noisy)} streams, {len(truths)} --truth)")
    if patch % 2 == 0:
        raise click.BadParameter(f"{patch} is even; the patch is centred on the event", param_hint="--patch")
    for name in (*noisy, *truths):
        if os.path.exists(output) and same_file(output, name):
            raise click.UsageError(f"{output}: is an input; choose another -o")
    total = sum(len(read_labels(truth)) for truth in truths)  # events over all inputs: the sampling fraction
    fraction = min(1.0, max_events / max(total, 1))
    rng = np.random.default_rng(seed)
    parts = [_features(n, t, patch, tau_us, fraction, held_out, rng) for n, t in zip(noisy, truths)]
    features, signal, check = (np.concatenate([part[i] for part in parts]) for i in range(3))
    weights, report = train(features, signal.astype(np.float64), check, patch=patch, tau_us=tau_us, hidden=hidden,
                            seed=seed, epochs=epochs)
    weights.info = {"inputs": " ".join(os.path.basename(n) for n in noisy), "seed": str(seed),
                    "validation_auc": f"{report.validation_auc:.4f}", "epochs": str(report.epochs)}
    with atomic_path(output) as temporary:
        weights.save(temporary)
    result = {"output": output, "patch": patch, "hidden": hidden, "tau_us": tau_us, "seed": seed,
              "events_total": total, "train_events": report.train_events,
              "held_out_events": report.validation_events, "signal_fraction": report.signal_fraction,
              "epochs": report.epochs, "train_loss": report.train_loss, "held_out_loss": report.validation_loss,
              "held_out_auc": report.validation_auc}
    if wants_json(as_json):
        click.echo(json.dumps(result, indent=2))
    else:
        click.echo(f"{output}: trained on {report.train_events:,} events ({report.signal_fraction:.1%} signal), "
                   f"{report.epochs} epochs; held out {report.validation_events:,}: cross-entropy "
                   f"{report.validation_loss:.4f}, AUC {report.validation_auc:.4f}")
