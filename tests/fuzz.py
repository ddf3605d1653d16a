"""Fuzzing the readers (issue 19): mutants of a small seed file of every format, read to the end under a memory and
a time limit; every outcome must be a stream that passes the stream checks or an evtools error naming the file.

Run by ``tests/test_fuzz.py`` (a few dozen mutants per format, in ``make test``) and by ``make fuzz`` (``python -m
tests.fuzz all 2000``: 2,000 per format). Each format runs in a child process of its own so that its memory limit
(``resource.setrlimit``, 1 GiB of address space beyond the interpreter's) cannot touch the test runner. Prints one
JSON line per format: the mutants tried, how many read whole, how many were refused cleanly, the "damaged but valid"
class (payload-only bit flips: refused, read the same, or read as other events without a word), peak RSS.
Mutations (hypothesis): truncation at any offset, bit flips, spliced files, a corrupted header, huge length fields.
"""

from __future__ import annotations

import importlib
import json
import os
import resource
import signal
import struct
import sys
import tempfile
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SEED_EVENTS = 3000
MEMORY_LIMIT_BYTES = 1 << 30  # beyond what the interpreter has when the fuzzing starts
TIME_LIMIT_S = 20
FORMATS = ("aedat4", "aedat4-lz4", "aedat4-zstd", "aedat2", "aedat3", "hdf5", "hdf5-ecf", "csv", "txt", "evt3", "evt2",
           "evt21", "dat")


def _events():
    import evtools

    events, info = evtools.read(DATA / "dvxplorer_sample.aedat4")
    return events[:SEED_EVENTS], info


def seed(name: str, folder: Path) -> Path:
    """A small valid file of format ``name`` (written by evtools, or cut from a shared recording)."""
    import evtools

    events, info = _events()
    if name.startswith("aedat4"):
        path = folder / "seed.aedat4"
        evtools.write(path, events, info, compression=name.split("-")[1] if "-" in name else None)
    elif name in ("aedat2", "hdf5", "csv", "txt"):
        path = folder / ("seed." + {"aedat2": "aedat", "hdf5": "h5", "csv": "csv", "txt": "txt"}[name])
        evtools.write(path, events, evtools.StreamInfo(346, 260) if name == "aedat2" else info)
    elif name == "aedat3":
        path = folder / "seed.aedat3"
        path.write_bytes((DATA / "derived" / "dvxplorer_sample.aedat3").read_bytes())
    elif name == "evt3":
        path = folder / "seed.raw"
        path.write_bytes((DATA / "gen41_sample.evt3.raw").read_bytes()[:40_000])
    elif name == "evt2":
        path = folder / "seed.raw"
        words, high = [], -1  # a time-high word whenever t >> 6 changes, then the CD event
        for t, x, y, p in zip((events["t"] - events["t"][0]).tolist(), events["x"].tolist(), events["y"].tolist(),
                              events["p"].tolist()):
            if t >> 6 != high:
                high = t >> 6
                words.append((8 << 28) | high)
            words.append((int(p) << 28) | ((t & 0x3F) << 22) | (x << 11) | y)
        path.write_bytes(b"% evt 2.0\n% geometry 320x240\n% end\n" + struct.pack(f"<{len(words)}I", *words))
    elif name == "evt21":  # IMX636's layout (the words' halves swapped), as the naive encoder writes it
        from tests.naive import evt21_encode_naive

        path = folder / "seed.raw"
        path.write_bytes(evt21_encode_naive(list(zip((events["t"] - events["t"][0]).tolist(), events["x"].tolist(),
                                                     events["y"].tolist(), events["p"].astype(int).tolist())),
                                            320, 240, legacy=True, seed=0))
    elif name == "hdf5-ecf":  # Metavision's layout, ECF chunks of 500 events in every mode
        from tests.naive import write_metavision_h5

        path = folder / "seed.hdf5"
        write_metavision_h5(path, list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(),
                                           events["p"].astype(int).tolist())), 320, 240, seed=0, chunk=500)
    elif name == "dat":
        path = folder / "seed.dat"
        records = np.empty(len(events), [("t", "<u4"), ("w", "<u4")])
        records["t"] = events["t"] - events["t"][0]
        records["w"] = events["x"].astype(np.uint32) | (events["y"].astype(np.uint32) << 14) | (
            events["p"].astype(np.uint32) << 28)
        path.write_bytes(b"% Version 2\n% Width 320\n% Height 240\n" + bytes([0x0C, 8]) + records.tobytes())
    else:
        raise ValueError(name)
    return path


def mutations():
    """A hypothesis strategy of functions bytes -> bytes."""
    from hypothesis import strategies as st

    def truncate(point):
        return lambda data: data[: int(point * len(data))]

    def flips(points, bits):
        def apply(data):
            data = bytearray(data)
            for point, bit in zip(points, bits):
                if data:
                    data[int(point * (len(data) - 1))] ^= 1 << bit
            return bytes(data)
        return apply

    def splice(a, b):
        return lambda data: data[: int(a * len(data))] + data[int(b * len(data)):]

    def header(point, junk):
        return lambda data: data[: int(point * min(len(data), 512))] + junk + data[int(point * min(len(data), 512))
                                                                                 + len(junk):]

    def huge(point, value):
        def apply(data):
            at = int(point * max(len(data) - 4, 0))
            return data[:at] + struct.pack("<I", value) + data[at + 4:]
        return apply

    unit = st.floats(0, 1, allow_nan=False)
    return st.one_of(
        st.builds(truncate, unit),
        st.builds(flips, st.lists(unit, min_size=1, max_size=8), st.lists(st.integers(0, 7), min_size=8, max_size=8)),
        st.builds(splice, unit, unit),
        st.builds(header, unit, st.binary(min_size=1, max_size=16)),
        st.builds(huge, unit, st.sampled_from([0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 1 << 24, 1 << 30, 0])),
    )


def read_outcome(path: Path) -> tuple[str, str | None]:
    """``("read", None)`` when the file reads whole (the stream checks on), ``("refused", None)`` when an evtools
    error naming the file refuses it, else ``("bad", what went wrong, with the traceback)``."""
    from evtools.errors import EvtoolsError
    from evtools.formats import open_events

    def alarm(signum, frame):
        raise TimeoutError(f"no result within {TIME_LIMIT_S} s")

    signal.signal(signal.SIGALRM, alarm)
    signal.alarm(TIME_LIMIT_S)
    try:
        with open_events(path) as stream:
            for _ in stream:
                pass
        return "read", None
    except EvtoolsError as error:
        if str(path) in str(error):
            return "refused", None
        return "bad", f"message without the file name: {error}"
    except KeyboardInterrupt:
        raise
    except BaseException as error:  # noqa: BLE001 - every other outcome is the finding
        return "bad", f"{type(error).__name__}: {error}\n{traceback.format_exc()}"
    finally:
        signal.alarm(0)


def fuzz(name: str, examples: int) -> dict:
    """Read ``examples`` mutants of format ``name``; raises (through hypothesis, with the smallest mutant found)
    at the first outcome that is not clean."""
    with tempfile.TemporaryDirectory(prefix=f"evtools-fuzz-{name}-") as folder:
        return _fuzz_in(name, examples, Path(folder))


def _fuzz_in(name: str, examples: int, folder: Path) -> dict:
    """:func:`fuzz` with its seed and mutants in ``folder`` (removed afterwards)."""
    from hypothesis import HealthCheck, given, settings

    original = seed(name, folder)
    data = original.read_bytes()
    assert read_outcome(original)[0] == "read", f"the {name} seed itself does not read"
    mutant = folder / ("mutant" + original.suffix)
    counts = {"format": name, "mutants": 0, "read": 0, "refused": 0}

    @settings(max_examples=examples, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(mutation=mutations())
    def check(mutation):
        mutant.write_bytes(mutation(data))
        outcome, problem = read_outcome(mutant)
        assert problem is None, problem
        counts["mutants"] += 1
        counts[outcome] += 1

    check()
    counts.update(payload_damage(data, mutant, examples))
    counts["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return counts


def _decoded(path: Path):
    """The events of a file, or None when it is refused (an evtools error naming it)."""
    import evtools
    from evtools.errors import EvtoolsError

    try:
        return evtools.read(path)[0]
    except EvtoolsError:
        return None


def payload_damage(data: bytes, mutant: Path, examples: int) -> dict:
    """The "damaged but valid" class (issue 37): one to four bit flips in the second half of the file, where every
    format holds payload (events, compressed blocks), none in a header. Each mutant is refused, read as the seed's
    events (the flip hit padding or a field the reader ignores), or read as other events without a word: a damage no
    check of the format can see (none of these formats carries a checksum). Counted, not asserted: the rates are
    the finding; a crash or a message without the file name still fails."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    original = _decoded(mutant.with_name("seed" + mutant.suffix))
    tally = {"payload_mutants": 0, "payload_refused": 0, "payload_same": 0, "payload_silently_different": 0}
    half = len(data) // 2

    @settings(max_examples=max(examples // 2, 1), deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(points=st.lists(st.integers(half, len(data) - 1), min_size=1, max_size=4),
           bits=st.lists(st.integers(0, 7), min_size=4, max_size=4))
    def check(points, bits):
        damaged = bytearray(data)
        for point, bit in zip(points, bits):
            damaged[point] ^= 1 << bit
        mutant.write_bytes(bytes(damaged))
        outcome, problem = read_outcome(mutant)
        assert problem is None, problem
        tally["payload_mutants"] += 1
        if outcome == "refused":
            tally["payload_refused"] += 1
            return
        events = _decoded(mutant)
        same = events is not None and len(events) == len(original) and all(
            np.array_equal(events[name], original[name]) for name in ("t", "x", "y", "p"))
        tally["payload_same" if same else "payload_silently_different"] += 1

    check()
    return tally


def _limit_memory() -> None:
    with open("/proc/self/statm") as statm:
        used = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (used + MEMORY_LIMIT_BYTES, resource.RLIM_INFINITY))


def main() -> None:
    which, examples = sys.argv[1], int(sys.argv[2])
    names = FORMATS if which == "all" else which.split(",")
    if len(names) > 1:  # one child per format: its own memory limit and peak RSS
        import subprocess

        failed = [name for name in names
                  if subprocess.run([sys.executable, "-m", "tests.fuzz", name, str(examples)], cwd=ROOT).returncode]
        sys.exit(f"fuzzing failed for {', '.join(failed)}" if failed else 0)
    import logging

    importlib.import_module("evtools.formats")  # imports and kernels loaded before the limit

    logging.getLogger("evtools").setLevel(logging.ERROR)  # mutants' warnings (inferred sizes) are not findings

    _events()
    _limit_memory()
    print(json.dumps(fuzz(names[0], examples)), flush=True)


if __name__ == "__main__":
    main()
