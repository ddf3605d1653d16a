"""What every benchmark shares: run a measurement in a fresh process and read its peak RSS from ``wait4``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def measure_command(argv, stdin=None, stdout=None) -> dict:
    """Run ``argv`` to its end: its wall time (start-up included) and peak RSS in MB; exits if it fails."""
    start = time.perf_counter()
    process = subprocess.Popen(argv, cwd=ROOT, stdin=stdin, stdout=stdout)
    output = process.stdout.read() if stdout == subprocess.PIPE else None
    _, status, usage = os.wait4(process.pid, 0)
    if status != 0:
        raise SystemExit(f"benchmark {argv} failed")
    return {"seconds": time.perf_counter() - start, "peak_mb": usage.ru_maxrss / 1024, "output": output}


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


def scratch_dir(needed_bytes: int) -> str | None:
    """Where benchmarks put their files: ``/dev/shm`` (memory) when it has room, so that a file-to-file row
    measures the tools rather than the disk's write-back; else the default temporary directory (None)."""
    import shutil

    if os.path.isdir("/dev/shm") and shutil.disk_usage("/dev/shm").free > 2 * needed_bytes:
        return "/dev/shm"
    return None
