"""``evtools estimate``: (being built)."""

from __future__ import annotations

import click


@click.command()
def estimate():
    """(being built)"""
    raise click.UsageError("not built yet")
