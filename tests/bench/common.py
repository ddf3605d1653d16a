"""What every benchmark shares: run a measurement in a fresh process and read its peak RSS from ``wait4``
(through a small launcher, see :data:`_LAUNCHER`)."""

from __future__ import annotations

import json
import os
import statistics
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
    """:func:`fastest` for several ``(measure, *args)`` at once, measured in turns (see :func:`paired`)."""
    rounds, _ = paired(runs, contenders)
    return [{**min(results, key=lambda result: result[key]), "peak_mb": max(result["peak_mb"] for result in results)}
            for results in rounds]


def paired(runs: int, contenders: list[tuple]) -> tuple[list[list[dict]], list[float]]:
    """Every ``(measure, *args)`` of ``contenders`` run once a round, in turns (A B C, then C B A, ...), ``runs``
    rounds: ``results[contender][round]`` and the machine's load (1-minute average) at each round's start.

    A slow minute of a shared machine then falls on every contender of a round, so ratios taken within a round
    (:func:`ratios`) hold where times alone vary by up to 2x; alternating the order cancels a drift within a round.
    """
    results: list[list[dict]] = [[] for _ in contenders]
    loads = []
    for round_index in range(max(runs, 1)):
        loads.append(os.getloadavg()[0])
        order = range(len(contenders)) if round_index % 2 == 0 else reversed(range(len(contenders)))
        for index in order:
            measure, *args = contenders[index]
            results[index].append(measure(*args))
    return results, loads


def ratios(peer: list[dict], ours: list[dict], key: str) -> tuple[float, float]:
    """Min and median over rounds of ``peer[key] / ours[key]`` taken round by round (> 1: ours is faster)."""
    values = [p[key] / o[key] for p, o in zip(peer, ours)]
    return min(values), statistics.median(values)


def median(results: list[dict], key: str) -> float:
    return statistics.median(result[key] for result in results)


def install_kind() -> str:
    """How evtools is installed in this environment: "editable" (``pip install -e``: an import hook in ``site``) or
    "wheel" (a plain install), from the distribution's ``direct_url.json`` (PEP 610)."""
    import importlib.metadata
    import sysconfig

    installed = list(importlib.metadata.distributions(name="evtools", path=[sysconfig.get_paths()["purelib"]]))
    if not installed:  # (a checkout's own evtools.egg-info is not an install)
        return "not installed"
    url = json.loads(installed[0].read_text("direct_url.json") or "{}")
    return "editable" if url.get("dir_info", {}).get("editable") else "wheel"


def scratch_dir(needed_bytes: int) -> str | None:
    """Where benchmarks put their files: ``/dev/shm`` (memory) when it has room, so that a file-to-file row
    measures the tools rather than the disk's write-back; else the default temporary directory (None)."""
    import shutil

    if os.path.isdir("/dev/shm") and shutil.disk_usage("/dev/shm").free > 2 * needed_bytes:
        return "/dev/shm"
    return None
