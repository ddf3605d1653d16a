"""``evtools metrics thresholds``: (being built)."""

from __future__ import annotations

import click


@click.command()
def thresholds():
    """(being built)"""
    raise click.UsageError("not built yet")


COMMANDS = [thresholds]
"""The subcommands of ``evtools metrics`` this module defines."""
