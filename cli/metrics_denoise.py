"""``evtools metrics denoise``: (being built)."""

from __future__ import annotations

import click


@click.command()
def denoise():
    """(being built)"""
    raise click.UsageError("not built yet")


COMMANDS = [denoise]
"""The subcommands of ``evtools metrics`` this module defines."""
