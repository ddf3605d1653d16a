"""The event model: dtype layout, sensor sizes, stream checks, re-chunking."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evtools.errors import InvalidEventsError
from evtools.events import (EVENT_DTYPE, MAX_TIME_US, StreamChecker, StreamInfo, concatenate, join, make_events,
                            parse_sensor_size, rechunk)
from tests.helpers import cut, random_events


def test_dtype_is_the_aedat4_event_struct():
    assert EVENT_DTYPE.itemsize == 16
    assert [EVENT_DTYPE.fields[name][1] for name in "txyp"] == [0, 8, 10, 12]
    assert [EVENT_DTYPE.fields[name][0].str for name in "txyp"] == ["<i8", "<i2", "<i2", "|b1"]


def test_concatenate_keeps_the_dtype():
    events = random_events(10)
    assert concatenate([events[:3], events[3:]]).dtype == EVENT_DTYPE


def test_concatenate_copies_chunks_of_any_stride_layout_and_count():
    """concatenate (the whole-file read) fills one array chunk by chunk, releasing each: the same records as join."""
    events = random_events(50, seed=5)
    packed = events.astype(np.dtype([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")]))
    for chunks in ([], [events[:0]], [events[::2]], [events[::3], packed[5:9], events[:0], events[::-7]]):
        for expected in (None, 1, 7, 1000):  # a size to expect: under it the result grows, over it is cut
            whole = concatenate(iter(chunks), expected=expected)
            assert whole.dtype == EVENT_DTYPE and whole.flags.c_contiguous
            assert [tuple(e) for e in whole] == [tuple(e) for chunk in chunks for e in chunk.astype(EVENT_DTYPE)]


def test_join_copies_records_of_any_stride_and_converts_other_layouts():
    events = random_events(50, seed=4)
    packed = events.astype(np.dtype([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")]))  # 13-byte records
    joined = join([events[::3], packed[5:9], events[:0], events[::-7]])
    expected = [tuple(e) for e in events[::3]] + [tuple(e) for e in events[5:9]] + [tuple(e) for e in events[::-7]]
    assert joined.dtype == EVENT_DTYPE and joined.flags.c_contiguous
    assert [tuple(e) for e in joined] == expected


@pytest.mark.parametrize("text,size", [("346x260", (346, 260)), ("128X128", (128, 128)), ("640,480", (640, 480))])
def test_parse_sensor_size(text, size):
    assert parse_sensor_size(text) == size


@pytest.mark.parametrize("text", ["0x10", "10", "axb", "40000x10", "-3x4"])
def test_bad_sensor_size(text):
    with pytest.raises(InvalidEventsError):
        parse_sensor_size(text)


def test_checker_reports_the_first_event_outside_the_sensor_by_stream_index():
    checker = StreamChecker(StreamInfo(10, 10), "f.aedat4")
    checker.check(make_events([1, 2], [0, 9], [0, 9], [1, 0]))
    with pytest.raises(InvalidEventsError, match=r"f.aedat4: event 3 at \(x=10, y=0\) lies outside the 10x10"):
        checker.check(make_events([3, 4], [1, 10], [1, 0], [1, 1]))


def test_checker_reports_time_going_backwards_across_chunks():
    checker = StreamChecker(StreamInfo(10, 10), "s")
    checker.check(make_events([5, 7], [0, 0], [0, 0], [1, 1]))
    with pytest.raises(InvalidEventsError, match=r"time goes backwards at event 2 \(6 us after 7 us\)"):
        checker.check(make_events([6], [0], [0], [1]))


def test_checker_accepts_ties():
    checker = StreamChecker(StreamInfo(4, 4))
    checker.check(make_events([1, 1, 1], [0, 1, 2], [0, 0, 0], [1, 0, 1]))
    checker.check(make_events([1], [3], [3], [0]))
    assert checker.events_seen == 4


@settings(max_examples=50, deadline=None)
@given(cuts=st.lists(st.integers(0, 1000), max_size=8), size=st.integers(1, 300))
def test_rechunk_gives_fixed_sizes_whatever_the_input_cuts(cuts, size):
    events = random_events(777, seed=3)
    out = list(rechunk(cut(events, cuts), size))
    assert all(len(chunk) == size for chunk in out[:-1]) and 0 < len(out[-1]) <= size
    np.testing.assert_array_equal(concatenate(out), events)


def test_checker_refuses_times_outside_the_supported_range():
    """Kernels add windows to times and keep 2^63 - 1 for "no event yet": times beyond +-2^62 us are refused by
    event index, whatever the reader (the CSV reader refuses them by line)."""
    info = StreamInfo(4, 4)
    chunk = make_events([0, 2**62, 2**62 + 1], [0, 0, 0], [0, 0, 0], [1, 1, 1])
    with pytest.raises(InvalidEventsError, match=r"s: event 2 has time 4611686018427387905 us, outside"):
        StreamChecker(info, "s").check(chunk)
    early = make_events([-(2**62) - 1, 0], [0, 0], [0, 0], [1, 1])
    with pytest.raises(InvalidEventsError, match=r"event 0 has time -4611686018427387905 us"):
        StreamChecker(info, "s").check(early)
    assert len(StreamChecker(info, "s").check(chunk[:2])) == 2


def test_a_whole_read_sized_beyond_what_the_system_reserves_still_reads(monkeypatch):
    """``concatenate``'s ``expected`` is an upper bound from a file's size; when the system refuses to reserve that
    much, a quarter is tried (down to a million events) and the result grows as needed: the events, not an error."""
    from evtools.events import concatenate

    real_empty = np.empty

    def refusing(shape, *args, **kwargs):
        if isinstance(shape, int) and shape > 3_000_000:
            raise MemoryError(f"cannot reserve {shape} events")
        return real_empty(shape, *args, **kwargs)

    chunks = [random_events(1000, seed=k) for k in range(5)]
    monkeypatch.setattr(np, "empty", refusing)
    out = concatenate(iter(chunks), expected=10**9)
    monkeypatch.undo()
    expected = np.concatenate(chunks)
    assert len(out) == len(expected)
    assert all(np.array_equal(out[field], expected[field]) for field in ("t", "x", "y", "p"))


def _first_faults_naive(t, x, y, p, width, height, last_t):
    """The first event of each kind of fault, one plain loop (the reference of evtools/_kernels/check.py)."""
    found = [-1, -1, -1, -1]
    for i in range(len(t)):
        tests = (not (0 <= int(x[i]) < width and 0 <= int(y[i]) < height), int(p[i]) > 1,
                 not -MAX_TIME_US <= int(t[i]) <= MAX_TIME_US,
                 (i > 0 and int(t[i]) < int(t[i - 1])) or (i == 0 and last_t is not None and int(t[0]) < last_t))
        for kind, bad in enumerate(tests):
            if bad and found[kind] < 0:
                found[kind] = i
    return tuple(found)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 60), st.integers(1, 9), st.integers(1, 9), st.lists(st.tuples(
    st.sampled_from(["x", "y", "p", "t", "back", "far"]), st.integers(0, 59)), max_size=4),
    st.one_of(st.none(), st.integers(-5, 2000)), st.integers(0, 2**31 - 1))
def test_the_check_kernel_finds_each_first_fault_as_a_plain_loop_does(n, width, height, faults, last_t, seed):
    """The stream check in one compiled pass (issue 42): on random chunks with random faults planted (coordinates
    off the sensor or negative, polarity bytes above 1, times beyond 2^62 us, time going backwards, within the
    chunk or against the last event of the one before), the first index of each kind equals a plain loop's, and
    the checker raises the first kind in its order with the stream index."""
    from evtools._kernels.check import first_faults

    rng = np.random.default_rng(seed)
    chunk = make_events(np.sort(rng.integers(0, 1000, n)), rng.integers(0, width, n), rng.integers(0, height, n),
                        rng.integers(0, 2, n))
    for kind, at in faults:
        if at >= n:
            continue
        if kind == "x":
            chunk["x"][at] = rng.choice([width, -1, 32767])
        elif kind == "y":
            chunk["y"][at] = rng.choice([height, -3])
        elif kind == "p":
            chunk["p"].view(np.uint8)[at] = rng.integers(2, 256)
        elif kind == "t":
            chunk["t"][at] = rng.choice([MAX_TIME_US + 1, -MAX_TIME_US - 1])
        elif kind == "back" and at > 0:
            chunk["t"][at] = chunk["t"][at - 1] - 1
        else:
            chunk["t"][at] = 10**12 + at
    expected = _first_faults_naive(chunk["t"], chunk["x"], chunk["y"], chunk["p"].view(np.uint8), width, height,
                                   last_t)
    got = first_faults(chunk["t"], chunk["x"], chunk["y"], chunk["p"].view(np.uint8), width, height,
                       0 if last_t is None else last_t, last_t is not None, MAX_TIME_US)
    assert tuple(got) == expected
    checker = StreamChecker(StreamInfo(width, height), "s")
    checker.events_seen, checker.last_t = 1000, last_t
    messages = ("sensor", "polarity byte", "+-2^62", "time goes backwards")
    first = next((kind for kind in range(4) if expected[kind] >= 0), None)
    if first is None:
        assert len(checker.check(chunk)) == n
    else:
        with pytest.raises(InvalidEventsError) as caught:
            checker.check(chunk)
        assert f"event {1000 + expected[first]}" in str(caught.value) and messages[first] in str(caught.value)


def test_records_built_from_columns_have_zero_padding():
    """make_events, as_chunk's conversion and from_columns give records whose 3 padding bytes are zero, whatever the
    memory held before (np.empty left it: a test that wrote another writer's padding with |= then failed 1 run in 6
    under numba, when the allocator handed back memory of earlier tests)."""
    from evtools.events import as_chunk

    for _ in range(20):  # freed memory full of ones, likely handed back to the next small allocations
        garbage = np.full(4096, 255, np.uint8)
        del garbage
        built = [make_events([1, 2, 3], [4, 5, 6], [7, 8, 9], [1, 0, 1]),
                 as_chunk(np.array([(1, 2, 3, True)], [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")]))]
        for events in built:
            assert not events.view(np.uint8).reshape(-1, 16)[:, 13:].any()


def test_selected_copied_and_transformed_records_keep_zero_padding():
    """Record-wise copies keep the zero padding that numpy's structured indexing and copy() leave undefined:
    events.select, convert's polarity, crop and flip (evtools.transform), correct with every pixel at the target."""
    from evtools.correction import ThresholdCorrector
    from evtools.events import StreamInfo, select
    from evtools.transform import Transform

    rng = np.random.default_rng(0)
    events = make_events(np.arange(2000), rng.integers(0, 32, 2000), rng.integers(0, 24, 2000),
                         rng.integers(0, 2, 2000))
    for _ in range(20):
        garbage = np.full(1 << 16, 255, np.uint8)  # freed memory full of ones, likely handed back next
        del garbage
        outputs = [select(events, events["x"] > 10), select(events, np.arange(0, 2000, 3))]
        for options in ({"polarity": "on"}, {"crop": (2, 3, 20, 15)}, {"flip_x": True}, {"transpose": True}):
            outputs.append(Transform(StreamInfo(32, 24), **options).process(events))
        at_target = np.full((24, 32), 0.2)
        outputs.append(ThresholdCorrector(32, 24, at_target, at_target, target=0.2).process(events))
        for output in outputs:
            assert len(output) and not output.view(np.uint8).reshape(-1, 16)[:, 13:].any()
    mask = events["x"] > 10
    for field in ("t", "x", "y", "p"):  # the same events as numpy's indexing gives
        assert (select(events, mask)[field] == events[mask][field]).all()
