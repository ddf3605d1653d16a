"""``evtools metrics uniformity``: (being built)."""

from __future__ import annotations

import click


@click.command()
def uniformity():
    """(being built)"""
    raise click.UsageError("not built yet")


COMMANDS = [uniformity]
"""The subcommands of ``evtools metrics`` this module defines."""
