"""Correction benchmark (issues 6, 12): throughput, peak memory and latency of ThresholdCorrector at 346 x 260.

Two streams, generated chunk by chunk (1M events each) and never held together; each row runs in a fresh process,
so its peak RSS (from ``wait4``) is its own. Only ``process``/``flush`` are timed (the re-sampling kernel plus the
sort-and-merge release).

- ``random``: random pixels and polarities, about 20 Mev/s of stream time: the worst case for the per-pixel state
  (a cache miss per event) and for ``turns``/``highpass`` (a reversal at every other event of a pixel, each one
  waiting for the pixel's next event).
- ``texture``: a natural moving texture from the tests' independent generator (:func:`texture_period`), 2 s
  repeated in time: curved runs and turns everywhere (issue 36).
- ``walk``: a real recording (``../shared/data/dvs128_walk.aedat``, DVS128, 290k events) tiled six times over
  the 346 x 260 sensor (tiles shifted by 1 ms each) and repeated in time: real runs and rests.

Latency is how far the output trails the input in stream time: the newest input time minus the newest released
event's time, after each chunk (at most the corrector's ``latency_us``, 3 x 300 ms by default with turns; the
chunk's own span comes on top, as for any processor). ``--baseline DIR`` adds a row
for the default mode of the evtools in DIR (e.g. a worktree of an older commit), measured in the same run.

Run: ``python -m tests.bench.bench_correct [--events N] [--baseline DIR]``. Target: >= 20 Mev/s.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from tests.bench.common import ROOT, measure_child

WIDTH, HEIGHT = 346, 260
CHUNK = 1 << 20
TARGET_MEV_S = 20.0
WALK = ROOT.parent / "shared" / "data" / "dvs128_walk.aedat"
TILES = [(0, 0), (128, 0), (218, 0), (0, 128), (128, 128), (218, 128)]  # 128 x 128 tiles over 346 x 260


def random_chunks(total: int, rng):
    from evtools.events import make_events

    t0 = 0
    for start in range(0, total, CHUNK):
        n = min(CHUNK, total - start)
        t = t0 + np.sort(rng.integers(0, n // 20 + 1, n))  # ~20 events per us
        t0 = int(t[-1])
        yield make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n), rng.integers(0, 2, n))


def walk_chunks(total: int):
    from evtools.events import concatenate, join
    try:
        from evtools.formats import open_events
    except ImportError:  # a baseline checkout from before formats/ was installed as evtools.formats
        from formats import open_events

    with open_events(str(WALK)) as stream:
        recording = concatenate(stream)
    recording["t"] -= recording["t"][0]
    tiles = []
    for k, (dx, dy) in enumerate(TILES):
        tile = recording.copy()
        tile["x"] += dx
        tile["y"] += dy
        tile["t"] += 1000 * k
        tiles.append(tile)
    period = join(tiles)
    yield from repeated(period[np.argsort(period["t"], kind="stable")], total)


def repeated(period, total: int):
    """``total`` events of ``period`` (time-sorted) repeated in time, 1 ms apart, in chunks of :data:`CHUNK`."""
    span_us = int(period["t"][-1]) + 1000
    produced, repeat = 0, 0
    while produced < total:
        for start in range(0, len(period), CHUNK):
            chunk = period[start:start + min(CHUNK, total - produced)].copy()
            chunk["t"] += repeat * span_us
            produced += len(chunk)
            yield chunk
            if produced >= total:
                return
        repeat += 1


def texture_period():
    """A natural moving texture (``tests/naive/texture.py``: a hand-held wobble of 4 px over a random multi-scale
    log texture, ideal pixels with exact crossings, thresholds 0.2 +/- 0.03) on the 346 x 260 sensor, 2 s of it:
    made once and kept in the temporary folder (it takes about a minute)."""
    import tempfile

    from evtools.events import make_events

    path = Path(tempfile.gettempdir()) / f"evtools-bench-texture-{WIDTH}x{HEIGHT}.npy"
    if not path.exists():
        from tests.naive.texture import crossings, texture_signal

        times, levels = texture_signal(WIDTH, HEIGHT, 2_000_000, seed=1, wobble_px=4.0, step_us=500)
        rng = np.random.default_rng(1)
        on, off = rng.normal(0.2, 0.03, (2, HEIGHT, WIDTH)).clip(0.05)
        events = crossings(times, levels, on, off)
        np.save(path, np.stack([events["t"], events["x"], events["y"], events["p"]]).astype(np.int64))
    t, x, y, p = np.load(path)
    return make_events(t, x, y, p)


def texture_chunks(total: int):
    yield from repeated(texture_period(), total)


def child(total: int, mode: str, source: str) -> dict:
    repo = os.environ.get("EVTOOLS_BENCH_REPO")
    if repo:  # another checkout's evtools (the baseline row)
        sys.path.insert(0, repo)
        for name in [m for m in sys.modules if m == "evtools" or m.startswith("evtools.")]:
            del sys.modules[name]
    try:
        from evtools.correction import ThresholdCorrector
    except ImportError:  # a baseline checkout from before the module was named correction
        from evtools.correct import ThresholdCorrector
    from evtools.events import make_events

    rng = np.random.default_rng(0)
    on = rng.normal(0.2, 0.03, (HEIGHT, WIDTH)).clip(0.05)
    off = rng.normal(0.2, 0.03, (HEIGHT, WIDTH)).clip(0.05)
    options = {} if mode == "default" else {"mode": mode}
    warm = make_events([0, 1], [0, 1], [0, 0], [1, 0])  # the first call (loading the stored kernel) is not throughput
    ThresholdCorrector(WIDTH, HEIGHT, on, off, target=0.2, **options).process(warm)
    corrector = ThresholdCorrector(WIDTH, HEIGHT, on, off, target=0.2, **options)
    chunks = {"random": lambda: random_chunks(total, rng), "walk": lambda: walk_chunks(total),
              "texture": lambda: texture_chunks(total)}[source]()
    spent, produced, latency_us = 0.0, 0, 0
    for chunk in chunks:
        begin = time.perf_counter()
        out = corrector.process(chunk)
        spent += time.perf_counter() - begin
        produced += len(out)
        if len(out):
            latency_us = max(latency_us, int(chunk["t"][-1]) - int(out["t"][-1]))
    begin = time.perf_counter()
    produced += len(corrector.flush())
    spent += time.perf_counter() - begin
    return {"events": total, "produced": produced, "seconds": spent, "latency_ms": latency_us / 1000}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--events", type=int, default=100_000_000)
    parser.add_argument("--baseline", metavar="DIR", help="also measure the default mode of the evtools in DIR")
    parser.add_argument("--child", nargs=3, metavar=("N", "MODE", "SOURCE"))
    parser.add_argument("--sources", default="random,walk,texture", help="streams: random, walk, texture")
    parser.add_argument("--modes", default="exponential,highpass,turns,step,foh")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(int(args.child[0]), args.child[1], args.child[2])))
        return
    from rich.console import Console
    from rich.table import Table

    parser_sources = args.sources.split(",")
    sources = [s for s in parser_sources if s != "walk" or WALK.exists()]
    if not WALK.exists():
        print(f"{WALK} is missing: the real-recording rows are left out", file=sys.stderr)
    table = Table(title=f"correct, {WIDTH} x {HEIGHT}, {args.events:,} events")
    for column in ("stream", "mode", "Mev/s", "peak RSS MB", "max latency ms", "target"):
        table.add_column(column, justify="right")
    for source in sources:
        rows = [(mode, None) for mode in args.modes.split(",")]
        if args.baseline:
            rows.append(("default", args.baseline))
        for mode, repo in rows:
            if repo:
                os.environ["EVTOOLS_BENCH_REPO"] = str(Path(repo).resolve())
            row = measure_child("bench_correct", args.events, mode, source)
            os.environ.pop("EVTOOLS_BENCH_REPO", None)
            rate = row["events"] / row["seconds"] / 1e6
            label = f"{mode} ({Path(repo).name})" if repo else mode
            table.add_row(source, label, f"{rate:.1f}", f"{row['peak_mb']:.0f}", f"{row['latency_ms']:.0f}",
                          f">= {TARGET_MEV_S:.0f} Mev/s {'ok' if rate >= TARGET_MEV_S else 'MISSED'}")
    Console().print(table)


if __name__ == "__main__":
    main()
