"""``evtools``: the command group; the one place that turns library errors into messages and exit codes."""

from __future__ import annotations

import gc
import contextlib
import importlib
import logging
import os
import signal
import sys
import threading

import click

from evtools import __version__, interrupt
from evtools.errors import EvtoolsError, UsageMistake
from evtools.inputs import guarding_inputs

EXIT_ERROR = 1
EXIT_USAGE = 2  # as click: a mistake in the command line
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what `cat` returns when `| head` closes the pipe


class _StderrFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"evtools: {record.levelname.lower()}: {record.getMessage()}"


def _set_verbosity(ctx, param, value) -> None:
    """-q: errors only; -v: also the details (debug); neither: errors, warnings and the counts (info)."""
    if value:
        logging.getLogger("evtools").setLevel(logging.ERROR if param.name == "quiet" else logging.DEBUG)


def _max_latency(ctx, param, value):
    """``--max-latency`` into the reading options of the command (:func:`evtools.cli.options.input_options`)."""
    if value is not None:
        from evtools.cli.options import LIVE_OPTIONS, Duration

        ctx.meta.setdefault(LIVE_OPTIONS, {})["max_latency_s"] = Duration(minimum_us=0).convert(value, param, ctx) / 1e6
    return value


def _timeout(ctx, param, value):
    """``--timeout`` into the reading options of the command: to connect to a network input, and its silence."""
    if value is not None:
        from evtools.cli.options import LIVE_OPTIONS, Duration

        # (up to a year: a socket's timeout is a C time; 1e10 s overflowed it into a traceback, a QA sweep)
        seconds = Duration(minimum_us=1000, maximum_us=365 * 86_400_000_000).convert(value, param, ctx) / 1e6
        ctx.meta.setdefault(LIVE_OPTIONS, {}).update(connect_timeout_s=seconds, read_timeout_s=seconds)
    return value


MAX_LATENCY_HELP = ("How long a live input's (pipe, socket, tcp://) first waiting events may be held while more "
                    "keep arriving (they then go on together); nothing waits when no more has arrived. [default: 20ms]")
TIMEOUT_HELP = ("How long a network input (tcp://) may take to connect and may then stay silent before it is an "
                "error. [default: 10s to connect, 60s of silence]")
GLOBAL_OPTIONS = (
    lambda: click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, callback=_set_verbosity,
                         help="Print errors only: no warnings, no counts."),
    lambda: click.Option(["-v", "--verbose"], is_flag=True, expose_value=False, callback=_set_verbosity,
                         help="Print details too (debug messages)."),
    lambda: click.Option(["--max-latency"], metavar="TIME", expose_value=False, callback=_max_latency,
                         help=MAX_LATENCY_HELP),
    lambda: click.Option(["--timeout"], metavar="TIME", expose_value=False, callback=_timeout, help=TIMEOUT_HELP),
)
"""Accepted before the subcommand (the group's) and after it (added to every subcommand)."""


class LazyGroup(click.Group):
    """A group whose subcommands are imported only when used, so a command loads only what it needs (numba, h5py
    and OpenCV take most of a second to import). ``lazy_commands`` maps a name to ``("module:function", summary)``;
    ``--help`` lists the summaries without importing anything (a test keeps them equal to the commands' own)."""

    def __init__(self, *args, lazy_commands: dict[str, tuple[str, str]] | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_commands = lazy_commands or {}

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy_commands})

    def get_command(self, ctx: click.Context, name: str):
        if name in self.lazy_commands and name not in self.commands:
            module, function = self.lazy_commands[name][0].split(":")
            command = getattr(importlib.import_module(module), function)
            if not isinstance(command, click.Group):  # -q, -v, --max-latency, --timeout after the subcommand too
                command.params += [option() for option in GLOBAL_OPTIONS]
            self.add_command(command, name)
        return super().get_command(ctx, name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        names = self.list_commands(ctx)
        if not names:
            return
        limit = formatter.width - 6 - max(len(name) for name in names)
        rows = []
        for name in names:
            if name in self.lazy_commands and name not in self.commands:
                rows.append((name, click.utils.make_default_short_help(self.lazy_commands[name][1], limit)))
            else:
                command = self.get_command(ctx, name)
                if command is not None and not command.hidden:
                    rows.append((name, command.get_short_help_str(limit)))
        with formatter.section("Commands"):
            formatter.write_dl(rows)


COMMANDS = {
    "info": ("evtools.cli.info:info",
             "Format, sensor size, event count, time span, rate and ON fraction of each FILE (`-` = stdin), and its "
             "APS frames (count, rate, exposure, size) where it has them."),
    "convert": ("evtools.cli.convert:convert",
                "Convert IN (default stdin) to OUT or -o OUT (default stdout), chunk by chunk in bounded memory."),
    "simulate": ("evtools.cli.simulate:simulate",
                 "Simulate a DVS looking at SOURCE: a video file, a folder of images, or scene:NAME; or add "
                 "labelled noise to SOURCE when it is an event stream (any readable format, `-` for stdin)."),
    "render": ("evtools.cli.render:render",
               "Draw IN (default stdin) as event frames, or a thresholds map with --map: users look before they "
               "read."),
    "bafilter": ("evtools.cli.bafilter:bafilter",
                 "Remove background activity from IN (default stdin), writing OUT or -o OUT (default stdout)."),
    "estimate": ("evtools.cli.estimate:estimate",
                 "Estimate every pixel's ON and OFF contrast thresholds from IN (default stdin), streaming, into "
                 "-o FILE."),
    "correct": ("evtools.cli.correct:correct",
                "Re-sample every pixel of IN (default stdin) at one target threshold; write -o OUT (default "
                "stdout)."),
    "metrics": ("evtools.cli.metrics:metrics",
                "Measure denoising (denoise, roc, esr), threshold estimation (thresholds), uniformity "
                "(uniformity) and reconstruction (reconstruction)."),
}


class EvtoolsGroup(LazyGroup):
    """Runs a subcommand; an :class:`EvtoolsError` becomes one line on stderr and exit code 1, never a traceback; a
    usage mistake (click's, or a :class:`UsageMistake` found when a value is used) one line and exit code 2."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as error:  # (the global options: one line too)
            if type(error).__name__ == "NoArgsIsHelpError":  # (click >= 8.2: no arguments show the help)
                raise
            click.echo(f"evtools: usage: {error.format_message()} (see evtools --help)", err=True)
            sys.exit(EXIT_USAGE)
        except KeyboardInterrupt:  # (a stop while the global options load their modules: click would say
            click.echo("evtools: interrupted", err=True)  # "Aborted!" and exit 1)
            sys.exit(interrupt.exit_code())

    def invoke(self, ctx: click.Context):
        try:
            with guarding_inputs():  # no output replaces a file the command reads
                result = super().invoke(ctx)
            interrupt.work_done()
        except click.UsageError as error:  # (a subcommand's options: one line, where click prints three)
            if type(error).__name__ == "NoArgsIsHelpError":
                raise
            command = (error.ctx.command_path if error.ctx is not None  # (click's parser gives none: an option's
                       else f"{ctx.command_path} {ctx.invoked_subcommand or ''}".strip())  # arguments missing)
            click.echo(f"evtools: usage: {error.format_message()} (see {command} --help)", err=True)
            ctx.exit(EXIT_USAGE)
        except UsageMistake as error:
            click.echo(f"evtools: usage: {error} (see {ctx.command_path} {ctx.invoked_subcommand} --help)", err=True)
            ctx.exit(EXIT_USAGE)
        except EvtoolsError as error:
            click.echo(f"evtools: error: {error}", err=True)
            ctx.exit(EXIT_ERROR)
        except BrokenPipeError:
            # the reader went away (`| head`): stop quietly; point stdout at /dev/null so the final flush is silent
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            ctx.exit(EXIT_BROKEN_PIPE)
        except (KeyboardInterrupt, interrupt.StopReading):  # (a stop that came as a wait for input ended, past
            click.echo("evtools: interrupted", err=True)  # the reader's own catch: seen once as a traceback)
            ctx.exit(interrupt.exit_code())
        except MemoryError:
            click.echo("evtools: error: out of memory", err=True)
            ctx.exit(EXIT_ERROR)
        except OSError as error:
            if error.filename:
                click.echo(f"evtools: error: {error.filename}: {error.strerror}", err=True)
            else:
                click.echo(f"evtools: error: {error.strerror or error}", err=True)
            ctx.exit(EXIT_ERROR)
        if interrupt.received() is not None:  # a stream ended early: its outputs are complete up to there
            click.echo(f"evtools: stopped by {signal.Signals(interrupt.received()).name}; the outputs hold every "
                       "event processed until then", err=True)
            ctx.exit(interrupt.exit_code())
        return None  # (not the command's value: main() takes a number from the group as its exit code)


@click.group(cls=EvtoolsGroup, lazy_commands=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="evtools")
@click.option("-q", "--quiet", is_flag=True, help="Print errors only: no warnings, no counts.")
@click.option("-v", "--verbose", is_flag=True, help="Print details too (debug messages).")
@click.option("--max-latency", metavar="TIME", default=None, callback=_max_latency, help=MAX_LATENCY_HELP)
@click.option("--timeout", metavar="TIME", default=None, callback=_timeout, help=TIMEOUT_HELP)
def cli(quiet: bool, verbose: bool, max_latency, timeout) -> None:
    """Event-camera (DVS) noise toolkit: read, convert, simulate, filter, estimate and correct event streams.

    Every command reads a path or `-` (stdin) and writes `-o PATH` or stdout; pipes carry AEDAT 4.0.
    """
    logger = logging.getLogger("evtools")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_StderrFormatter())
        logger.addHandler(handler)
    logger.setLevel(logging.ERROR if quiet else logging.DEBUG if verbose else logging.INFO)
    logger.propagate = False




BLAS_THREADS = {"OPENBLAS_NUM_THREADS": "1"}
"""numpy's BLAS thread pool, one thread unless the user's environment says otherwise: its idle threads spin for
0.1 CPU-s a process (docs/performance.md), which the kernels' own threads need on a small machine; the only BLAS
call, MLPF's two small products, is as fast on one."""


def main() -> None:
    for name, value in BLAS_THREADS.items():  # before numpy is imported (``evtools`` loads it on first use)
        os.environ.setdefault(name, value)
    try:  # EVTOOLS_KERNELS checked before any command runs (jit.py owns its values; it imports no numpy)
        from evtools._kernels import jit  # noqa: F401
    except ValueError as error:
        sys.stderr.write(f"evtools: usage: {error}\n")
        sys.exit(EXIT_USAGE)
    try:
        interrupt.install()  # Ctrl-C / SIGTERM end the input stream: outputs complete, exit 130 / 143
        # click's standalone mode would turn a stop that lands outside the group's own handling (between the
        # handlers' installation and the parsing, or before the command is invoked: a busy machine descheduled
        # the process there in CI) into "Aborted!" and exit 1; here every stop ends as the others do
        code = cli.main(prog_name="evtools", standalone_mode=False)
    except click.Abort as stop:  # (click's word for a KeyboardInterrupt, or an EOFError, that reached it)
        if isinstance(stop.__cause__, EOFError):
            click.echo("evtools: error: unexpected end of input", err=True)
            code = EXIT_ERROR
        else:
            click.echo("evtools: interrupted", err=True)
            code = interrupt.exit_code()
    except KeyboardInterrupt:
        click.echo("evtools: interrupted", err=True)
        code = interrupt.exit_code()
    except click.ClickException as error:  # (no arguments: the help)
        error.show()
        code = error.exit_code
    except SystemExit as done:
        code = done.code
    finally:
        if threading.current_thread() is threading.main_thread():  # the work is done (its outputs committed): a
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # stop now changes nothing; the interpreter's own ending
            signal.signal(signal.SIGTERM, signal.SIG_IGN)  # would restore the default and die of it
        # When numba is loaded (a kernel compiled, or an argument only numba takes), Python's last garbage
        # collections walk every object it created (~0.2 s per process, measured with `time`); frozen objects are
        # skipped. Files are closed and flushed as usual.
        gc.freeze()
    if code not in (None, 0):
        # A failed run has closed its outputs and removed its temporaries (context managers) and said why; it ends
        # here, without the interpreter's finalisation: h5py crashes (SIGSEGV) freeing the objects of a file whose
        # write failed (a full disk), which would turn exit 1 into a crash
        with contextlib.suppress(Exception):
            sys.stdout.flush()
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os._exit(code if isinstance(code, int) else EXIT_ERROR)
