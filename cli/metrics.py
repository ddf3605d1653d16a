"""``evtools metrics``: the group of measurements; each subcommand lives in its own ``cli/metrics_*.py`` module."""

from __future__ import annotations

import click

from cli.main import LazyGroup


@click.group(cls=LazyGroup, lazy_commands={
    "denoise": "cli.metrics_denoise:denoise",
    "roc": "cli.metrics_denoise:roc",
    "esr": "cli.metrics_denoise:esr",
    "thresholds": "cli.metrics_thresholds:thresholds",
    "uniformity": "cli.metrics_uniformity:uniformity",
})
def metrics() -> None:
    """Measure denoising (denoise, roc, esr), threshold estimation (thresholds) and uniformity (uniformity).

    Each prints a table on a terminal and JSON when stdout is not a terminal or with --json.
    """
