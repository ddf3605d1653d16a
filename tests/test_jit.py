"""Kernels called through their stored machine code (evtools/_kernels/jit.py) give numba's results and pure
Python's, for every kind of argument the C wrapper passes; the store is rebuilt when stale or damaged; a process
with a warm store never imports numba."""

from __future__ import annotations

import os
import pickle
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evtools._kernels import jit
from evtools._kernels import store as kernel_store
from evtools.events import EVENT_DTYPE

ROOT = Path(__file__).resolve().parents[1]

PAIR = np.dtype([("t", "<i8"), ("x", "<i2"), ("flag", "?")], align=True)


def _twice(value):
    return 2 * value


def scale_and_count(values, factor, threshold, out):
    """out = factor * values (an inline helper does the doubling); returns how many exceed threshold."""
    count = 0
    for i in range(values.size):
        out[i] = values[i] * factor
        count += out[i] > threshold
    return _twice_kernel(count) // 2


def field_sum(strided, table):
    """Sum of a strided field plus the records' t where flag is set, and whether that sum is even (a tuple of an
    int and a bool)."""
    total = 0
    for i in range(strided.size):
        total += strided[i]
    for i in range(table.size):
        if table[i]["flag"]:
            total += table[i]["t"]
            table[i]["x"] += 1
    return total, total % 2 == 0


def mean_of(read_only):
    """A float result from a read-only 2-D array."""
    return read_only.sum() / read_only.size


_twice_kernel = jit.kernel(_twice, inline=True)


@pytest.fixture
def store(tmp_path, monkeypatch):
    """An empty store of machine code, used by the kernels made in the test."""
    monkeypatch.setattr(kernel_store, "cache_dir", lambda: tmp_path)
    return tmp_path


def _arguments(seed: int):
    rng = np.random.default_rng(seed)
    values = rng.normal(size=50)
    table = np.zeros(20, PAIR)
    table["t"] = rng.integers(-1000, 1000, 20)
    table["flag"] = rng.integers(0, 2, 20).astype(bool)
    events = np.zeros(30, EVENT_DTYPE)
    events["x"] = rng.integers(0, 100, 30)
    read_only = rng.normal(size=(4, 6))
    read_only.flags.writeable = False
    return values, table, events, read_only


def _run(scale, fields, mean, seed):
    values, table, events, read_only = _arguments(seed)
    out = np.zeros_like(values)
    count = scale(values, np.float32(1.5), 0.25, out)
    total = fields(events["x"], table)  # a field of events: a strided view (every 8th int16)
    return count, out, total, table, mean(read_only)


def _assert_same(a, b):
    for left, right in zip(a, b):
        if isinstance(left, np.ndarray):
            np.testing.assert_array_equal(left, right)
        else:
            assert left == right and type(left) is type(right)


@pytest.mark.parametrize("seed", [0, 1])
def test_stored_code_gives_numbas_and_pythons_results(store, seed):
    kernels = [jit.kernel(f) for f in (scale_and_count, field_sum, mean_of)]
    native = _run(*kernels, seed)
    assert {"scale_and_count", "field_sum", "mean_of"} == {p.name.split(".")[2] for p in store.glob("*/*.pkl")}
    # a second set of kernels loads the stored objects instead of compiling
    fresh = [jit.kernel(f) for f in (scale_and_count, field_sum, mean_of)]
    from_store = _run(*fresh, seed)
    assert [call.origin for k in kernels for call in k._calls.values()] == ["compiled"] * 3
    assert [call.origin for k in fresh for call in k._calls.values()] == ["store"] * 3
    by_numba = _run(*(k.dispatcher for k in kernels), seed)
    by_python = _run(scale_and_count, field_sum, mean_of, seed)
    for result in (from_store, by_numba):
        _assert_same(native, result)
    assert native[0] == by_python[0] and native[2] == by_python[2]
    np.testing.assert_allclose(native[1], by_python[1])
    assert native[4] == pytest.approx(by_python[4])
    assert isinstance(native[2][1], bool) and isinstance(native[4], float)


def test_views_and_empty_arrays_reach_the_stored_code_at_their_own_addresses(store):
    # writeable contiguous arrays pass their address through the buffer protocol: views that start inside
    # another array, empty ones, and the same array read-only (passed the other way) give Python's results
    scale, mean = jit.kernel(scale_and_count), jit.kernel(mean_of)
    values = np.random.default_rng(5).normal(size=40)
    out = np.full(60, np.nan)
    for begin, end in [(0, 40), (7, 40), (13, 21), (40, 40)]:
        view, target = values[begin:end], out[begin + 10:end + 10]
        assert scale(view, np.float32(2.0), 0.5, target) == int(np.sum(view * np.float32(2.0) > 0.5))
        np.testing.assert_array_equal(target, view * np.float32(2.0))
    assert np.isnan(out[:10]).all() and np.isnan(out[50:]).all()  # nothing written outside the views
    matrix = np.arange(24.0).reshape(4, 6)
    assert mean(matrix[1:3]) == matrix[1:3].mean()
    matrix.flags.writeable = False
    assert mean(matrix[2:]) == matrix[2:].mean()


@settings(max_examples=200, deadline=None)
@given(dtype=st.sampled_from(["i1", "<i8", ">i4", "f4", "<f8", "?", "m8[us]", PAIR, EVENT_DTYPE]),
       shape=st.lists(st.integers(0, 4), max_size=3), step=st.integers(-3, 3).filter(bool),
       writeable=st.booleans(), field=st.booleans())
def test_an_array_is_described_as_without_the_lookup(dtype, shape, step, writeable, field):
    # the kinds looked up by dtype, dimensions, flags and stride are those described from scratch
    array = np.zeros(shape, dtype)
    if array.ndim:
        array = array[::step]
    if field and array.dtype.names:
        array = array[array.dtype.names[0]]
    array.flags.writeable = writeable
    assert kernel_store._describe(array) == kernel_store._describe_array(array)
    assert kernel_store._describe(array) == kernel_store._describe_array(array)  # and again, from the table


def test_arguments_the_wrapper_cannot_pass_go_to_numba(store):
    mean = jit.kernel(mean_of)
    matrix = np.arange(24.0).reshape(4, 6)
    assert mean(matrix[:, ::2]) == matrix[:, ::2].mean()  # 2-D, not contiguous
    assert kernel_store._describe(matrix[:, ::2]) is None and kernel_store._describe([1, 2]) is None
    assert kernel_store._describe(1 << 64) is None and kernel_store._describe(np.float16(1)) is None
    assert mean._calls[tuple([None])] is False
    assert not list(store.glob("**/*.pkl"))


def test_a_damaged_or_stale_store_entry_is_rebuilt(store, monkeypatch):
    values = np.arange(5.0)
    jit.kernel(scale_and_count)(values, 2.0, 3.0, np.zeros(5))
    [entry] = store.glob("*/*.pkl")
    entry.write_bytes(b"not a pickle")
    out = np.zeros(5)
    assert jit.kernel(scale_and_count)(values, 2.0, 3.0, out) == 3
    assert pickle.loads(entry.read_bytes())["object"]
    monkeypatch.setattr(kernel_store, "_SOURCES", b"edited kernels")
    assert jit.kernel(scale_and_count)(values, 2.0, 3.0, out) == 3
    [rebuilt] = store.glob("*/*.pkl")
    assert rebuilt.name != entry.name  # the stale entry is gone, the new one written
    monkeypatch.setattr(kernel_store, "_ENVIRONMENT", "another-machine")
    assert jit.kernel(scale_and_count)(values, 2.0, 3.0, out) == 3
    assert rebuilt.exists() and len(list(store.glob("*/*.pkl"))) == 2  # each environment keeps its own
    np.testing.assert_array_equal(out, 2 * values)


def test_an_unresolvable_symbol_falls_back_to_numba(store):
    values = np.arange(5.0)
    jit.kernel(scale_and_count)(values, 2.0, 3.0, np.zeros(5))
    [entry] = store.glob("*/*.pkl")
    record = pickle.loads(entry.read_bytes())
    assert kernel_store._load(record)  # loads as stored, by llvmlite and as a shared library
    library = entry.with_suffix(".so")
    assert library.exists() == ("slots" in record)
    if library.exists():
        assert kernel_store._load_library(record, library)
    record["undefined"].append("evtools_no_such_symbol")
    entry.write_bytes(pickle.dumps(record))
    count = jit.kernel(scale_and_count)
    assert count(values, 2.0, 3.0, np.zeros(5)) == 3
    assert list(count._calls.values()) == [False]


def test_a_process_with_a_warm_store_does_not_import_numba(tmp_path):
    source = tmp_path / "in.csv"
    source.write_text("t,x,y,p\n" + "".join(f"{10 * i},{i % 7},{i % 5},{i % 2}\n" for i in range(200)))
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    outputs, imported = [], []
    for run in range(2):  # the first run may compile and store; the second loads
        output = tmp_path / f"out{run}.csv"
        probe = ("import sys; from evtools.cli.main import cli; "
                 f"cli(['-q', 'bafilter', {str(source)!r}, '--method', 'hotpixel,refractory,stcf', "
                 f"'--sensor-size', '8x8', '-o', {str(output)!r}], standalone_mode=False); "
                 "print('numba' in sys.modules, 'llvmlite' in sys.modules)")
        result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT,
                                env=environment, timeout=300)
        assert result.returncode == 0, result.stderr
        imported.append(result.stdout.strip())
        outputs.append(output.read_text().splitlines())
    linked = bool(shutil.which(os.environ.get("CC") or "cc")) and platform.machine() in kernel_store._TRAMPOLINES
    assert imported[1] == ("False False" if linked else "False True")  # a shared library needs no llvmlite
    assert outputs[0] == outputs[1] and 1 < len(outputs[1]) < 201


def test_kernel_modules_imported_after_numba_get_their_extensions_built():
    probe = ("from evtools._kernels import jit; jit.numba_module(); "
             "from evtools._kernels import bafilter, pixel; "
             "print(type(bafilter.prefetch).__name__, pixel._OVERLOADS)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=300,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["_Intrinsic", "True"]


def allocate_or_raise(values):
    """numba's runtime (an array allocated and freed) and its exception helpers, reached from a shared library
    through the trampolines of kernel_store._link."""
    if values[0] < 0:
        raise ValueError("a negative first value")
    scratch = np.empty(3)
    scratch[:] = values[0]
    return scratch.sum()


@pytest.mark.skipif(not shutil.which(os.environ.get("CC") or "cc")
                    or platform.machine() not in kernel_store._TRAMPOLINES,
                    reason="no C compiler (or trampolines) for shared libraries here: llvmlite loads the objects")
def test_a_shared_library_reaches_numbas_runtime_and_exceptions(tmp_path):
    probe = ("import sys, numpy as np; from pathlib import Path; from evtools._kernels import jit; "
             "from evtools._kernels import store as kernel_store; "
             f"kernel_store.cache_dir = lambda: Path({str(tmp_path)!r}); "
             "from tests.test_jit import allocate_or_raise; k = jit.kernel(allocate_or_raise); "
             "print(k(np.array([2.5])), k(np.array([-1.0])), type(kernel_store._KEEP[-1]).__name__)")
    runs = [subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=300,
                           env={**os.environ, "PYTHONPATH": str(ROOT)}) for _ in range(2)]
    assert [run.returncode for run in runs] == [0, 0], runs[1].stderr
    assert list(tmp_path.glob("*/*.so"))
    first, second = (run.stdout.split() for run in runs)
    assert first[:2] == second[:2] == ["7.5", "0.0"]  # (the C wrapper returns 0 after printing the exception)
    assert second[2] == "CDLL" and "ValueError: a negative first value" in runs[1].stderr


def test_an_inline_kernel_is_inlined_by_numba_not_called():
    """``inline=True`` is numba's ``inline="always"``: the helper's body is compiled into its caller, never on its
    own. numba reads the option from the callee's ``targetoptions``; without them the option was silently ignored
    and every helper compiled and called as a function (correct's kernels: 7-10 % slower)."""
    numba = jit.numba_module()
    helper = jit.kernel(_twice, inline=True)
    called = jit.kernel(_twice)

    def through(kernel_):
        def outer(value):
            return kernel_(value) + 1
        return outer

    for kernel_, compiled_alone in ((helper, 0), (called, 1)):
        outer = numba.njit(through(kernel_))
        assert outer(20) == 41
        assert len(kernel_.dispatcher.overloads) == compiled_alone


def test_numbas_cache_of_a_kernel_goes_stale_when_any_kernel_source_changes(monkeypatch):
    """A kernel inlines helpers of other kernel modules (mlpf inlines bafilter's): numba's own cache stamp (the
    kernel's file alone) would keep their old code. The stamp is the digest of every kernel source instead."""
    kernel_ = jit.kernel(scale_and_count)
    jit.numba_module()
    locator = jit._kernels_cache(kernel_)._impl.locator
    before = locator.get_source_stamp()
    assert before == kernel_store._sources(kernel_)
    monkeypatch.setattr(kernel_store, "_SOURCES", b"another kernel module changed")
    assert locator.get_source_stamp() != before


def test_numbas_cache_of_a_kernel_goes_where_numba_cache_dir_says(tmp_path, monkeypatch):
    numba = jit.numba_module()
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    locator = jit._kernels_cache(jit.kernel(scale_and_count))._impl.locator
    assert locator.get_cache_path().startswith(str(tmp_path))
    assert locator.get_source_stamp() == kernel_store._sources(jit.kernel(scale_and_count))


def test_a_terminal_is_told_once_that_kernels_are_being_compiled(monkeypatch):
    """Issue 39: the first run of a command compiled its kernels for seconds without a word; on a terminal one line
    says so, once a process, and nothing is written when stderr is not a terminal."""
    import io

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(kernel_store, "_SAID", [])
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    kernel_store._say_compiling("a.kernel")
    kernel_store._say_compiling("another.kernel")
    assert terminal.getvalue().count("compiling machine code") == 1
    monkeypatch.setattr(kernel_store, "_SAID", [])
    piped = io.StringIO()
    monkeypatch.setattr("sys.stderr", piped)
    kernel_store._say_compiling("a.kernel")
    assert piped.getvalue() == ""


def test_the_numba_mode_runs_numbas_dispatchers_and_gives_the_same_results(tmp_path):
    """Issue 40 item 3, the fence: EVTOOLS_KERNELS=numba runs every kernel on numba's own dispatcher (no stored
    machine code is made or loaded) with the same results; an unknown mode is refused in one line (exit 2)."""
    code = (
        "import gc, numpy as np, evtools\n"
        "from evtools._kernels import jit\n"
        "events, _ = evtools.simulate('bars', size=(32, 24), duration_us=300_000, seed=1)\n"
        "kept = evtools.bafilter(events, (32, 24), method='stcf')\n"
        "calls = sum(len(k._calls) for k in gc.get_objects() if isinstance(k, jit.Kernel))\n"
        "print(jit.MODE, len(kept), int(kept['t'].sum() % 1000003), calls)\n"
    )
    results = {}
    for mode in ("store", "numba"):
        environment = {**os.environ, "EVTOOLS_KERNELS": mode, "XDG_CACHE_HOME": str(tmp_path / mode)}
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment)
        assert done.returncode == 0, done.stderr
        results[mode] = done.stdout.split()
    assert results["store"][0] == "store" and results["numba"][0] == "numba"
    assert results["store"][1:3] == results["numba"][1:3]  # the same events kept
    assert int(results["store"][3]) > 0 and int(results["numba"][3]) == 0  # no native call made in numba mode
    assert not (tmp_path / "numba" / "evtools" / "native").exists() or not any(
        (tmp_path / "numba" / "evtools" / "native").rglob("*.pkl"))
    assert any((tmp_path / "store" / "evtools" / "native").rglob("*.pkl"))  # the store: the user's cache, never
    # inside the package
    bad = subprocess.run([str(Path(sys.executable).with_name("evtools")), "info", "--help"], capture_output=True,
                         text=True, env={**os.environ, "EVTOOLS_KERNELS": "fast"})
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "EVTOOLS_KERNELS" in bad.stderr


@pytest.mark.skipif(jit.MODE != "store", reason="the store is not used under EVTOOLS_KERNELS=numba")
def test_processes_started_together_on_an_empty_store_compile_a_kernel_once(tmp_path):
    """A QA sweep: four `correct` started at once on a fresh install each compiled every kernel (1 min 47 s on 2
    cores). A process that needs a kernel another one is compiling waits for it (a lock in the store) and loads
    it: of two processes started together on an empty store, no kernel is compiled by both."""
    probe = ("import sys, numpy as np; import evtools._kernels.store as store; compiled = []; real = store._compile\n"
             "def spy(kernel, args, kinds):\n"
             "    compiled.append(kernel.__module__ + '.' + kernel.__qualname__); return real(kernel, args, kinds)\n"
             "store._compile = spy\n"
             "from evtools.filters import BAFilter; from evtools.events import make_events\n"
             "BAFilter(8, 8, 'baf').process(make_events(np.arange(5), np.arange(5), np.arange(5), np.ones(5, bool)))\n"
             "print(' '.join(compiled))")
    environment = {**os.environ, "XDG_CACHE_HOME": str(tmp_path), "PYTHONPATH": str(ROOT)}
    processes = [subprocess.Popen([sys.executable, "-c", probe], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, cwd=ROOT, env=environment) for _ in range(2)]
    results = [process.communicate(timeout=600) for process in processes]
    assert all(process.returncode == 0 for process in processes), results
    compiled = [name for out, _ in results for name in out.split()]
    assert compiled and len(compiled) == len(set(compiled)), results  # (each kernel once, by one of them)
