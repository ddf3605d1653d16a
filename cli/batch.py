"""Several inputs at once: every stream command takes ``IN...``; with more than one input, ``-o`` names a folder,
each output keeps its input's name (with the output format's extension), and the files run ``--jobs`` at a time
in a process pool, or on a Dask cluster with ``--scheduler`` (the ``cluster`` extra).

A command supplies ``one(input, output, **options) -> Outcome``, a module-level function (so a worker process or a
Dask worker can import it), which does the whole work for one file and raises :class:`EvtoolsError` on bad input;
its :class:`Outcome` carries the command's measure of success (valid pixels, events kept), which ``--json`` and the
summary table report beside the counts. One input runs in this process exactly as before; several run as a batch:
a failing file is listed and the others complete, a summary table goes to stderr, and the exit code is 1 when
any file failed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple

import click

from evtools.errors import EvtoolsError
from evtools.formats.io import STDIO, TCP_PREFIX, same_file
from evtools.formats.registry import from_extension

log = logging.getLogger("evtools")


class Outcome(NamedTuple):
    """What one file's run did: events read and written (``events_out`` None: the command writes no events), its
    measure of success as numbers (``measures``, in ``--json``) and in words (``note``, in the table)."""

    events_in: int
    events_out: int | None
    measures: dict | None = None
    note: str = ""
    input_cut: bool = False
    """The input turned out cut (a file without its end mark, or cut inside a packet): the output is marked cut."""

    def as_json(self) -> dict:
        counts = {"events_in": self.events_in}
        if self.events_out is not None:
            counts["events_out"] = self.events_out
        return {**counts, **(self.measures or {}), **({"note": self.note} if self.note else {}),
                **({"cut": True, "input_cut": True} if self.input_cut else {})}


class BatchError(EvtoolsError):
    """Some files of a batch failed (each listed on stderr)."""


def _network_names(ctx, param, value):
    """:func:`evtools.cli.options.network_names` (imported when called: this module is imported before it)."""
    from evtools.cli.options import network_names

    return network_names(ctx, param, value)


inputs_argument = click.argument("inputs", nargs=-1, metavar="[IN]...", callback=_network_names,
                                 type=click.Path(allow_dash=True))  # a folder: the RPG layout
jobs_option = click.option(
    "--jobs", type=click.IntRange(min=1), default=None, metavar="N",
    help="Several inputs: files processed at once (default: the number of cores).")
scheduler_option = click.option(
    "--scheduler", default=None, metavar="local|tcp://HOST:PORT",
    help="Several inputs: run on Dask instead of a process pool - `local` starts a cluster of --jobs workers, "
         "tcp://HOST:PORT joins a running dask.distributed scheduler (needs `pip install evtools[cluster]`).")


OUTPUT_HELP = "Output file (`-` or absent: stdout), or with several inputs the folder that gets one output per input."


def batch_options(function=None, *, output_help: str = OUTPUT_HELP):
    """The options of a stream command that takes one or several inputs: ``IN...``, the input options, ``-o``
    (described by ``output_help``), ``--jobs``, ``--scheduler`` and ``--json`` (the function takes ``inputs,
    reading, output, jobs, scheduler, as_json``; ``reading``: the :class:`evtools.formats.ReadOptions` of
    :func:`evtools.cli.options.input_options`)."""
    if function is None:
        return lambda decorated: batch_options(decorated, output_help=output_help)
    from evtools.cli.options import input_options, serve_early

    batch_output_option = click.option("-o", "--output", default=None, metavar="OUT", callback=serve_early,
                                       type=click.Path(allow_dash=True), help=output_help)

    json_counts = click.option("--json", "as_json", is_flag=True,
                               help="Print the counts as JSON (on stdout when the events go to files, else on "
                                    "stderr) instead of the line or table on stderr.")
    for option in (json_counts, scheduler_option, jobs_option, batch_output_option, input_options, inputs_argument):
        function = option(function)
    return function


def _names_folder(output: str | None) -> bool:
    """Whether ``-o`` names a folder: an existing one, or a path ending with a separator."""
    return output is not None and output != STDIO and (os.path.isdir(output) or output.endswith(os.sep))


def plan(inputs: tuple[str, ...], output: str | None, suffix: str,
         second_is_output: bool = True, check: Callable[[list], None] | None = None) -> list[tuple[str, str]]:
    """The (input, output) pairs the positional names and ``-o`` ask for.

    No input: stdin. One input: ``-o`` or stdout (``-o`` naming a folder: into it, as for several). Two names and
    no ``-o``: the second is the output (as it always was) unless it exists - then it may be a recording the user
    meant as an input, and the command refuses rather than overwrite it. More: ``-o`` must name a folder (made if missing); outputs are named after their inputs
    with ``suffix`` (the output format's extension), and two inputs may not give one output name. A command whose
    output is not a stream (``estimate``) never takes a second name as its output (``second_is_output``).
    ``check(pairs)`` may refuse the pairs (a usage error) before the folder is made.
    """
    inputs = tuple(inputs) or (STDIO,)
    if output is None and len(inputs) == 2 and second_is_output:
        first, second = inputs
        if second != STDIO and os.path.exists(second):
            raise click.UsageError(
                f"{second} exists: to process both files give -o FOLDER; to write into it, name it with -o "
                "(a second name is taken as the output only when it does not exist yet)")
        return _checked([(first, second)], check)
    if len(inputs) == 1 and not _names_folder(output):
        return _checked([(inputs[0], output if output is not None else STDIO)], check)
    if len(inputs) == 1 and inputs[0] == STDIO:
        raise click.UsageError(f"-o {output} is a folder: name the output file of stdin")
    if output is None or output == STDIO:
        raise click.UsageError(f"{len(inputs)} inputs need -o FOLDER (each output is named after its input)")
    if output.startswith(TCP_PREFIX):  # (a folder tcp:/HOST:PORT/ was made, and nothing served: a QA sweep)
        raise click.UsageError(f"-o {output}: a network output serves one stream; give one input, or -o FOLDER")
    if STDIO in inputs:
        raise click.UsageError("stdin (-) can be the only input")
    folder = Path(output)
    if folder.exists() and not folder.is_dir():
        raise click.UsageError(f"-o {output}: with several inputs -o names a folder, and this is a file")
    if not folder.exists() and from_extension(str(folder)) is not None and not output.endswith(os.sep):
        # (made silently, then with a warning and exit 0: a script that meant one file got a folder, QA sweeps)
        raise click.UsageError(f"-o {output}: with several inputs -o names a folder, and this names a recording; "
                               "give each input its own run to write one file each (evtools does not merge "
                               f"recordings), or end it with / for a folder of that name ({output}/)")
    pairs, seen = [], {}
    for name in inputs:
        target = folder / (Path(name).stem + suffix)
        if target in seen:
            raise click.UsageError(f"{seen[target]} and {name} would both be written to {target}")
        seen[target] = name
        pairs.append((name, str(target)))
    _checked(pairs, check)
    folder.mkdir(parents=True, exist_ok=True)
    return pairs


def _checked(pairs: list[tuple[str, str]], check) -> list[tuple[str, str]]:
    """``pairs`` once no output names another input (the same file through a symbolic or a hard link too: one
    input's output would replace another input; an output naming its own input is refused where it is written)
    and ``check`` accepts them."""
    inputs = [name for name, _ in pairs if name != STDIO]
    for name, target in pairs:
        if target == STDIO or not os.path.exists(target):
            continue
        replaced = next((other for other in inputs if other != name and same_file(target, other)), None)
        if replaced is not None:
            raise click.UsageError(f"{name}'s output {target} would replace the input {replaced}; choose another -o")
    if check is not None:
        check(pairs)
    return pairs


def run(one: Callable[..., Outcome], pairs: list[tuple[str, str]], options: dict[str, Any],
        jobs: int | None = None, scheduler: str | None = None, as_json: bool = False) -> None:
    """Run ``one`` on every pair: in this process for a single pair (errors propagate as they always did),
    else as a batch (see the module docstring). ``as_json``: the counts as JSON (see :func:`_echo_json`)."""
    if len(pairs) == 1 and scheduler is None:
        started = time.perf_counter()
        if as_json:
            logging.getLogger("evtools").setLevel(logging.WARNING)  # the JSON replaces the text line
        outcome = one(*pairs[0], **options)
        if as_json:
            _echo_json({"input": pairs[0][0], "output": pairs[0][1], **outcome.as_json(),
                        "seconds": round(time.perf_counter() - started, 6)}, pairs)
        return
    jobs = jobs or os.cpu_count() or 1
    started = time.perf_counter()
    results: dict[str, tuple] = {}
    if scheduler is None:
        from concurrent.futures import ProcessPoolExecutor, as_completed  # (multiprocessing: 12 ms, only here)

        # the workers are forked before the progress display starts its thread (a fork copies no threads but
        # could copy a lock one of them holds)
        with ProcessPoolExecutor(max_workers=min(jobs, len(pairs)), initializer=_quiet_worker) as pool:
            futures = {pool.submit(run_one, one, i, o, options): i for i, o in pairs}
            with _Display([name for name, _ in pairs]) as display:
                try:
                    for future in as_completed(futures):
                        results[futures[future]] = _result_of(future, futures[future])
                        display.done(futures[future], results[futures[future]])
                except KeyboardInterrupt:  # a stop (the command's own handler: no stream read here)
                    results.update(_stopped(futures, results))
    else:
        with _Display([name for name, _ in pairs]) as display:
            for name, result in _run_on_dask(one, pairs, options, jobs, scheduler):
                results[name] = result
                display.done(name, result)
    rows = [(name, results[name]) for name, _ in pairs]
    if as_json:
        files = [_file_json(name, output, result) for (name, output), (_, result) in zip(pairs, rows)]
        _echo_json({"files": files, "failed": sum("error" in f for f in files),
                    "seconds": round(time.perf_counter() - started, 6)}, pairs)
    elif log.getEffectiveLevel() <= logging.INFO:  # not with -q: the table is information, the errors are not
        _summary(rows, time.perf_counter() - started)
    else:
        for name, result in rows:
            if result[0] == "error":
                click.echo(f"evtools: error: {result[1]}", err=True)
    failed = [name for name, _ in pairs if results[name][0] == "error"]
    if failed:
        raise BatchError(f"{len(failed)} of {len(pairs)} files failed: {', '.join(failed)}")


def _file_json(name: str, output: str, result: tuple) -> dict:
    """One file's entry in a batch's ``--json``: its counts (with ``"cut": true`` when a stop ended its reading),
    ``"stopped": true`` (never started: no output) or its error."""
    status = result[0]
    if status in ("ok", "cut"):
        return {"input": name, "output": output, **result[1].as_json(), **({"cut": True} if status == "cut" else {}),
                "seconds": round(result[2], 6)}
    if status == "stopped":
        return {"input": name, "output": None, "stopped": True}
    return {"input": name, "output": output, "error": result[1]}


def _echo_json(summary: dict, pairs: list[tuple[str, str]]) -> None:
    """One JSON object with the command's name first: on stdout unless the events went there, else on stderr."""
    from evtools.cli.options import echo_json

    name = click.get_current_context().command.name
    to_stderr = any(output in (None, STDIO) for _, output in pairs)
    echo_json({"command": name, **summary}, err=to_stderr)


def _stopped(futures: dict, results: dict) -> dict:
    """A stop came while the batch ran: the files not started are cancelled, the signal goes on to the workers (a
    stop sent to the command alone, ``kill PID``, once left them running every file), whose files under way end as
    a stopped command's do (marked cut); returns the results of the files not done yet, ``("stopped", None, 0)``
    for those never started (no output is made for them)."""
    import multiprocessing
    import signal

    from evtools import interrupt

    for future in futures:
        future.cancel()
    for child in multiprocessing.active_children():
        with contextlib.suppress(ProcessLookupError):
            os.kill(child.pid, interrupt.received() or signal.SIGINT)
    return {name: ("stopped", None, 0.0) if future.cancelled() else _result_of(future, name)
            for future, name in futures.items() if name not in results}


def _result_of(future, name: str) -> tuple:
    """A file's result, or its error when its worker died (a pool broken by a killed worker) rather than a
    traceback."""
    try:
        return future.result()
    except Exception as error:  # (concurrent.futures' BrokenProcessPool, a worker's unpicklable error)
        return "error", f"{name}: its worker failed ({error})", 0.0


PARENT_CHECK_S = 0.2
"""How often a batch's worker looks whether the command that started it still runs."""
_busy = False  # a worker is running a file (run_one)


def _exit_with_parent(parent_pid: int) -> None:
    """A worker whose command died (``kill -9``, the OOM killer: no stop reached it) stops as if stopped: the file
    under way ends marked cut (a SIGTERM to itself), none is started, and the worker exits once idle (it went on
    through every file after the command had gone, then waited forever, holding the caller's stdout open)."""
    import signal

    while os.getppid() == parent_pid:
        time.sleep(PARENT_CHECK_S)
    os.kill(os.getpid(), signal.SIGTERM)
    while _busy:
        time.sleep(PARENT_CHECK_S)
    os._exit(128 + signal.SIGTERM)


def run_one(one: Callable[..., Outcome], input: str, output: str, options: dict[str, Any]) -> tuple:
    """``("ok", Outcome, seconds)``, ``("cut", Outcome, seconds)`` (a stop ended the file's reading: its output
    is marked cut), ``("stopped", None, 0)`` (a stop came before the file was started: no output) or ``("error",
    message, seconds)``: a worker never raises for a bad file (the batch goes on)."""
    from evtools import interrupt

    global _busy

    if interrupt.received() is not None:
        return "stopped", None, 0.0
    start = time.perf_counter()
    _busy = True
    try:
        outcome = one(input, output, **options)
        stopped = interrupt.received() is not None and not interrupt.every_stream_whole()
        return "cut" if stopped else "ok", outcome, time.perf_counter() - start
    except EvtoolsError as error:
        return "error", str(error), time.perf_counter() - start
    except click.ClickException as error:
        return "error", error.format_message(), time.perf_counter() - start
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        return "error", f"{where}{error.strerror or error}", time.perf_counter() - start
    except MemoryError:
        return "error", f"{input}: out of memory", time.perf_counter() - start
    finally:
        _busy = False


def _quiet_worker() -> None:
    """Workers report through the summary, not line by line: warnings and errors only; a stop signal ends the file
    under way and starts no other (:func:`evtools.interrupt.install_in_worker`); a worker outlives no command
    (:func:`_exit_with_parent`)."""
    from evtools import interrupt

    interrupt.install_in_worker()
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), name="evtools-parent-watch", daemon=True).start()
    logger = logging.getLogger("evtools")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("evtools: %(levelname)s: %(message)s"))
        logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False


def _run_on_dask(one, pairs, options, jobs, scheduler):
    """Yield (input, result) as the files finish on a Dask cluster (``local``: a LocalCluster of ``jobs``
    single-threaded worker processes; else the address of a running scheduler)."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed as dask_completed
    except ImportError:
        raise EvtoolsError("--scheduler needs Dask: pip install 'evtools[cluster]'") from None
    cluster = None
    try:
        if scheduler == "local":
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None)
            client = Client(cluster)
        elif scheduler.startswith("tcp://"):
            client = Client(scheduler, timeout="30s")
        else:
            raise click.UsageError(f"--scheduler {scheduler}: give local or tcp://HOST:PORT")
    except OSError as error:
        raise EvtoolsError(f"--scheduler {scheduler}: cannot connect ({error})") from None
    try:
        client.run(_quiet_worker)
        futures = {client.submit(run_one, one, i, o, options, pure=False): i for i, o in pairs}
        for future in dask_completed(futures):
            yield futures[future], future.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class _Display:
    """A progress line per file on stderr when it is a terminal (waiting, done, failed)."""

    def __init__(self, names: list[str]) -> None:
        self.names = names
        self.progress = None

    def __enter__(self) -> "_Display":
        if sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

            self.progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                                     console=Console(stderr=True), transient=True)
            self.progress.start()
            self.tasks = {name: self.progress.add_task(name, total=1) for name in self.names}
        return self

    def done(self, name: str, result: tuple) -> None:
        if self.progress is not None:
            mark = {"ok": "done", "cut": "stopped (cut)", "stopped": "not started"}.get(result[0], "FAILED")
            self.progress.update(self.tasks[name], completed=1, description=f"{name}: {mark}")

    def __exit__(self, *exc) -> None:
        if self.progress is not None:
            self.progress.stop()


def _summary(rows: list[tuple[str, tuple]], seconds: float) -> None:
    """The table of files, events in and out, time and failures, on stderr (errors listed under it)."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{len(rows)} files in {seconds:.1f} s", title_justify="left")
    writes_events = any(result[0] in ("ok", "cut") and result[1].events_out is not None for _, result in rows)
    columns = [("file", "left"), ("events in", "right")] + ([("events out", "right")] if writes_events else [])
    for column, justify in columns + [("result", "left"), ("s", "right"), ("", "left")]:
        table.add_column(column, justify=justify)
    total_in = total_out = 0
    for name, result in rows:
        if result[0] in ("ok", "cut"):
            outcome = result[1]
            total_in += outcome.events_in
            total_out += outcome.events_out or 0
            out = [f"{outcome.events_out:,}"] if writes_events else []
            table.add_row(name, f"{outcome.events_in:,}", *out, outcome.note, f"{result[2]:.2f}",
                          "stopped: cut" if result[0] == "cut" else "input cut: output cut" if outcome.input_cut
                          else "ok")
        elif result[0] == "stopped":
            table.add_row(name, "", *([""] if writes_events else []), "", "", "not started: no output")
        else:
            table.add_row(name, "", *([""] if writes_events else []), "", f"{result[2]:.2f}", "failed")
    failed = sum(result[0] == "error" for _, result in rows)
    stopped = sum(result[0] in ("cut", "stopped") for _, result in rows)
    verdict = ", ".join(([f"{failed} failed"] if failed else []) + ([f"{stopped} stopped"] if stopped else [])) or "ok"
    table.add_row("all", f"{total_in:,}", *([f"{total_out:,}"] if writes_events else []), "", f"{seconds:.2f}",
                  verdict, style="bold")
    console = Console(stderr=True, width=None if sys.stderr.isatty() else 120)
    console.print(table)
    for name, result in rows:
        if result[0] == "error":
            console.print(f"evtools: error: {result[1]}", markup=False, highlight=False)
