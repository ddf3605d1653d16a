"""``evtools correct``: (being built)."""

from __future__ import annotations

import click


@click.command()
def correct():
    """(being built)"""
    raise click.UsageError("not built yet")
