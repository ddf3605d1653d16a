"""``evtools bafilter``: (being built)."""

from __future__ import annotations

import click


@click.command()
def bafilter():
    """(being built)"""
    raise click.UsageError("not built yet")
