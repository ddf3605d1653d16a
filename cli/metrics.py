"""``evtools metrics``: the group of measurements; each subcommand lives in its own ``cli/metrics_*.py`` module."""

from __future__ import annotations

import click

from cli import metrics_denoise, metrics_thresholds, metrics_uniformity


@click.group()
def metrics() -> None:
    """Measure denoising (denoise, roc, esr), threshold estimation (thresholds) and uniformity (uniformity).

    Each prints a table on a terminal and JSON when stdout is not a terminal or with --json.
    """


for module in (metrics_denoise, metrics_thresholds, metrics_uniformity):
    for command in module.COMMANDS:
        metrics.add_command(command)
