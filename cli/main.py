"""``evtools``: the command group; the one place that turns library errors into messages and exit codes."""

from __future__ import annotations

import gc
import importlib
import logging
import os
import sys

import click

from evtools import __version__
from evtools.errors import EvtoolsError

EXIT_ERROR = 1
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what `cat` returns when `| head` closes the pipe
EXIT_INTERRUPTED = 130


class _StderrFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"evtools: {record.levelname.lower()}: {record.getMessage()}"


class LazyGroup(click.Group):
    """A group whose subcommands are imported only when used, so a command loads only what it needs (numba, h5py
    and OpenCV take most of a second to import); ``commands`` maps a name to ``"module:function"``."""

    def __init__(self, *args, lazy_commands: dict[str, str] | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_commands = lazy_commands or {}

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy_commands})

    def get_command(self, ctx: click.Context, name: str):
        if name in self.lazy_commands and name not in self.commands:
            module, function = self.lazy_commands[name].split(":")
            self.add_command(getattr(importlib.import_module(module), function), name)
        return super().get_command(ctx, name)


COMMANDS = {
    "info": "cli.info:info",
    "convert": "cli.convert:convert",
    "simulate": "cli.simulate:simulate",
    "render": "cli.render:render",
    "bafilter": "cli.bafilter:bafilter",
    "estimate": "cli.estimate:estimate",
    "correct": "cli.correct:correct",
    "metrics": "cli.metrics:metrics",
}


class EvtoolsGroup(LazyGroup):
    """Runs a subcommand; an :class:`EvtoolsError` becomes one line on stderr and exit code 1, never a traceback."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except EvtoolsError as error:
            click.echo(f"evtools: error: {error}", err=True)
            ctx.exit(EXIT_ERROR)
        except BrokenPipeError:
            # the reader went away (`| head`): stop quietly; point stdout at /dev/null so the final flush is silent
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            ctx.exit(EXIT_BROKEN_PIPE)
        except KeyboardInterrupt:
            click.echo("evtools: interrupted", err=True)
            ctx.exit(EXIT_INTERRUPTED)
        except MemoryError:
            click.echo("evtools: error: out of memory", err=True)
            ctx.exit(EXIT_ERROR)
        except OSError as error:
            if error.filename:
                click.echo(f"evtools: error: {error.filename}: {error.strerror}", err=True)
            else:
                click.echo(f"evtools: error: {error.strerror or error}", err=True)
            ctx.exit(EXIT_ERROR)


@click.group(cls=EvtoolsGroup, lazy_commands=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="evtools")
@click.option("-q", "--quiet", is_flag=True, help="Print errors only, no warnings.")
def cli(quiet: bool) -> None:
    """Event-camera (DVS) noise toolkit: read, convert, simulate, filter, estimate and correct event streams.

    Every command reads a path or `-` (stdin) and writes `-o PATH` or stdout; pipes carry AEDAT 4.0.
    """
    logger = logging.getLogger("evtools")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_StderrFormatter())
        logger.addHandler(handler)
    logger.setLevel(logging.ERROR if quiet else logging.INFO)
    logger.propagate = False




def main() -> None:
    try:
        cli(prog_name="evtools")
    finally:
        # Python's last garbage collections walk every object numba created (~0.2 s per process, measured with
        # `time`); frozen objects are skipped. Files are closed and flushed as usual.
        gc.freeze()
