"""What every benchmark shares: run a measurement in a fresh process and read its peak RSS from ``wait4``
(through a small launcher, see :data:`_LAUNCHER`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


_LAUNCHER = """
import os, sys
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as report:
    report.write(f"{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}")
"""
"""A small interpreter that forks and runs the command, then writes its exit code and peak RSS (KiB). A child's
``ru_maxrss`` includes the memory of the process it was forked from (Linux carries the old image's high-water mark
across exec): forked from the benchmark itself, every command measured at least the benchmark's own RSS (51 MiB
for a 29 MiB run). Forked from this launcher (about 10 MiB, less than any Python command), it measures its own."""


USER_ENVIRONMENT = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
"""Commands run as on a user's machine, with Python's bytecode caches (a sandbox that sets PYTHONDONTWRITEBYTECODE
would have every evtools process compile its modules again: ~10 ms of start-up a peer's compiled core does not
pay)."""


def measure_command(argv, stdin=None, stdout=None) -> dict:
    """Run ``argv`` to its end: its wall time (start-up included) and peak RSS in MB; exits if it fails."""
    import tempfile

    with tempfile.NamedTemporaryFile("r", suffix=".rusage") as report:
        start = time.perf_counter()
        process = subprocess.Popen([sys.executable, "-S", "-c", _LAUNCHER, report.name, *map(str, argv)], cwd=ROOT,
                                   stdin=stdin, stdout=stdout, env=USER_ENVIRONMENT)
        output = process.stdout.read() if stdout == subprocess.PIPE else None
        process.wait()
        seconds = time.perf_counter() - start
        code, peak_kib = (int(value) for value in (report.read().split() or ["-1", "0"]))
    if process.returncode != 0 or code != 0:
        raise SystemExit(f"benchmark {argv} failed")
    return {"seconds": seconds, "peak_mb": peak_kib / 1024, "output": output}


def measure_child(module: str, *args) -> dict:
    """Run ``python -m tests.bench.MODULE --child ARGS`` in a fresh interpreter: its JSON result, its peak RSS
    (``peak_mb``) and its whole wall time (``wall_seconds``, interpreter start-up and imports included)."""
    run = measure_command([sys.executable, "-m", f"tests.bench.{module}", "--child", *map(str, args)],
                          stdout=subprocess.PIPE)
    return {**json.loads(run["output"]), "peak_mb": run["peak_mb"], "wall_seconds": run["seconds"]}


def fastest(runs: int, measure, *args, key: str = "seconds") -> dict:
    """The fastest of ``runs`` calls of ``measure(*args)`` (smallest ``key``), with the largest peak RSS among them.

    Timings on a shared 2-core machine vary by up to 2x between identical runs (other tenants, page cache); the
    minimum is the figure that repeats, so every benchmark row reports it (``--repeat``).
    """
    results = [measure(*args) for _ in range(max(runs, 1))]
    return {**min(results, key=lambda result: result[key]), "peak_mb": max(result["peak_mb"] for result in results)}


def fastest_each(runs: int, contenders: list[tuple], key: str = "seconds") -> list[dict]:
    """:func:`fastest` for several ``(measure, *args)`` at once, measured in turns (A B C, A B C, ...) rather than
    one after the other: a slow minute of the shared machine then falls on every contender, not on one, so
    their ratios hold better."""
    rounds = [[measure(*args) for measure, *args in contenders] for _ in range(max(runs, 1))]
    return [{**min(results, key=lambda result: result[key]), "peak_mb": max(result["peak_mb"] for result in results)}
            for results in zip(*rounds)]


def scratch_dir(needed_bytes: int) -> str | None:
    """Where benchmarks put their files: ``/dev/shm`` (memory) when it has room, so that a file-to-file row
    measures the tools rather than the disk's write-back; else the default temporary directory (None)."""
    import shutil

    if os.path.isdir("/dev/shm") and shutil.disk_usage("/dev/shm").free > 2 * needed_bytes:
        return "/dev/shm"
    return None
