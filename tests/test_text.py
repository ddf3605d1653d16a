"""CSV and text readers and writers: the reference files, header variants, round trips, bad lines."""

from __future__ import annotations

import io
import sys
import types
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

import evtools.formats.text
from evtools.events import StreamInfo, concatenate, make_events
from evtools.formats import FormatError, create_events, open_events
from evtools.formats.text import CsvWriter, TxtWriter
from tests.conftest import data_file
from tests.helpers import read_all, write_bytes


def read_text(tmp_path, text: str, name: str = "events.csv", **kwargs):
    path = tmp_path / name
    path.write_bytes(text.encode())
    info, events = read_all(path, **kwargs)
    return events, info


@st.composite
def event_arrays(draw, max_events: int = 200):
    n = draw(st.integers(0, max_events))
    width = draw(st.integers(1, 2000))
    height = draw(st.integers(1, 2000))
    t0_us = draw(st.integers(-(10**12), 2**50))
    gaps_us = draw(st.lists(st.integers(0, 3 * 10**6), min_size=n, max_size=n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    t = t0_us + np.cumsum(np.asarray(gaps_us, dtype=np.int64))
    events = make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))
    cuts = draw(st.lists(st.integers(0, n), max_size=6))
    return events, StreamInfo(width, height), cuts


# -- the reference files ------------------------------------------------------------------------------------
def test_csv_sample_gives_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.csv"), chunk_events=10000)
    assert np.array_equal(events, dvxplorer_events)  # absolute microseconds
    assert info.size == (320, 240) and info.format == "csv"  # inferred by a scan


def test_txt_sample_gives_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.events.txt"), sensor_size=(320, 240))
    expected = dvxplorer_events.copy()
    expected["t"] -= expected["t"][0]  # the file stores seconds relative to the first event
    assert np.array_equal(events, expected)
    assert info.format == "txt"


def test_txt_writer_reproduces_the_sample_byte_for_byte(dvxplorer_events):
    original = data_file("derived/dvxplorer_sample.events.txt").read_bytes()
    events = dvxplorer_events.copy()
    events["t"] -= events["t"][0]
    written = write_bytes(TxtWriter, events, [7, 50000], StreamInfo(320, 240))
    assert written == b"320 240\n" + original


def test_csv_writer_reproduces_the_sample_byte_for_byte_but_for_the_sized_header(dvxplorer_events):
    original = data_file("derived/dvxplorer_sample.csv").read_bytes()
    assert original.startswith(b"t,x,y,p\n")
    written = write_bytes(CsvWriter, dvxplorer_events, [3, 99999], StreamInfo(320, 240))
    assert written == b"t,x@320,y@240,on\n" + original[len(b"t,x,y,p\n"):]


# -- header variants ----------------------------------------------------------------------------------------
def test_csv_columns_in_any_order_and_signed_polarity(tmp_path):
    events, _ = read_text(tmp_path, "X, Polarity ,Timestamp,y\n5,-1,10,2\n6,1,11,3\r\n\n", sensor_size=(8, 8))
    assert np.array_equal(events, make_events([10, 11], [5, 6], [2, 3], [False, True]))


def test_csv_faery_header_carries_the_sensor_size(tmp_path):
    events, info = read_text(tmp_path, "t,x@640,y@480,on\n1,2,3,1\n2,4,5,0\n")
    assert info.size == (640, 480)
    assert np.array_equal(events, make_events([1, 2], [2, 4], [3, 5], [1, 0]))


def test_csv_without_header_is_t_x_y_p(tmp_path):
    events, info = read_text(tmp_path, "# a comment\n100,1,2,1\n200,3,4,0")  # no final newline
    assert np.array_equal(events, make_events([100, 200], [1, 3], [2, 4], [1, 0]))
    assert info.size == (4, 5)


def test_txt_with_size_line_comments_and_label_column(tmp_path):
    text = "# v2e output\n# t x y p label\n346 260\n0.5 1 2 1 0\n1.000001 3 4 0 1\n"
    events, info = read_text(tmp_path, text, name="v2e.txt")
    assert info.size == (346, 260)
    assert np.array_equal(events, make_events([500000, 1000001], [1, 3], [2, 4], [1, 0]))


def test_txt_absolute_seconds_are_exact(tmp_path):
    events, _ = read_text(tmp_path, "1605537493.718345 1 2 1\n1605537494.308262 3 4 0\n", "a.txt")
    assert list(events["t"]) == [1605537493718345, 1605537494308262]


def test_txt_whose_times_are_all_whole_numbers_is_refused_as_microseconds(tmp_path):
    """Found by a QA sweep: 't x y p' lines with integer microseconds (as many tools write them) were read as
    seconds: a 1 s recording lasted 11.6 days and bafilter removed every event. Ten or more lines of whole-number
    times are refused with the remedy (read as CSV: microseconds); a few whole seconds, or seconds with a point,
    are read as before."""
    lines = "".join(f"{1000 + 37 * k} {k % 4} 1 {k % 2}\n" for k in range(12))
    with pytest.raises(FormatError, match=r"a.txt: lines 2-13: every time is a whole number, read as seconds .*"
                                          r"\(407 s .*--input-format csv"):
        read_text(tmp_path, "4 2\n" + lines, "a.txt")
    path = tmp_path / "us.txt"
    path.write_text(lines)
    assert read_all(path, format="csv", sensor_size=(4, 2))[1]["t"].tolist() == [1000 + 37 * k for k in range(12)]
    events, _ = read_text(tmp_path, "4 2\n" + "".join(f"{k} 1 1 1\n" for k in range(9)), "b.txt")
    assert events["t"].tolist() == [k * 1_000_000 for k in range(9)]
    events, _ = read_text(tmp_path, "4 2\n" + lines.replace("1000 ", "1000.5 "), "c.txt")
    assert events["t"][0] == 1_000_500_000


def test_many_blocks_keep_line_numbers_and_events(tmp_path):
    rng = np.random.default_rng(5)
    n = 30000
    events = make_events(np.arange(n) * 3, rng.integers(0, 100, n), rng.integers(0, 90, n), rng.integers(0, 2, n))
    path = tmp_path / "big.csv"
    path.write_bytes(write_bytes(CsvWriter, events, [], StreamInfo(100, 90)))
    _, got = read_all(path, sensor_size=(100, 90), chunk_events=1000)  # 64 KB blocks
    assert np.array_equal(got, events)
    lines = path.read_bytes().split(b"\n")
    lines[25000] = b"75000,1,x2,0"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(FormatError, match=r"big\.csv: line 25001: 'x2' is not a number"):
        read_all(path, sensor_size=(100, 90), chunk_events=1000)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), comments=st.lists(st.integers(1, 12000), max_size=6),
       csv=st.booleans(), bad=st.integers(3, 12000))
def test_comment_lines_among_the_events_are_left_out_and_line_numbers_kept(tmp_path, seed, comments, csv, bad):
    """``#`` comment lines anywhere among the events (evtools writes one after a cut input's events) are left out
    whatever the blocks, and a bad line after them is named by its own line number."""
    rng = np.random.default_rng(seed)
    n = 12000
    events = make_events(np.arange(n) * 3, rng.integers(0, 100, n), rng.integers(0, 90, n), rng.integers(0, 2, n))
    writer_class = CsvWriter if csv else TxtWriter
    lines = write_bytes(writer_class, events, [], StreamInfo(100, 90)).split(b"\n")
    for at in sorted(comments, reverse=True):
        lines.insert(at, b"  # a note, 1,2,3")
    path = tmp_path / ("c.csv" if csv else "c.txt")
    path.write_bytes(b"\n".join(lines))
    _, got = read_all(path, sensor_size=(100, 90), chunk_events=500)  # 16 KB blocks
    assert np.array_equal(got, events)
    if lines[bad].lstrip().startswith(b"#") or not lines[bad]:
        return
    lines[bad] = lines[bad] + b" 7" if not csv else lines[bad] + b",7"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(FormatError, match=rf"line {bad + 1}: 5 columns"):
        read_all(path, sensor_size=(100, 90), chunk_events=500)


def test_reads_csv_from_stdin(monkeypatch):
    data = b"t,x@10,y@10,p\n1,2,3,1\n"
    monkeypatch.setattr(sys, "stdin", types.SimpleNamespace(buffer=io.BufferedReader(io.BytesIO(data))))
    info, events = read_all("-")
    assert info.size == (10, 10) and np.array_equal(events, make_events([1], [2], [3], [1]))


def test_stdin_without_size_asks_for_it(monkeypatch):
    stdin = io.BufferedReader(io.BytesIO(b"t,x,y,p\n1,2,3,1\n"))
    monkeypatch.setattr(sys, "stdin", types.SimpleNamespace(buffer=stdin))
    with pytest.raises(FormatError, match="sensor-size"):
        open_events("-")


# -- round trips --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("writer_class,suffix", [(CsvWriter, "csv"), (TxtWriter, "txt")])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=event_arrays())
def test_round_trip_and_bytes_independent_of_chunking(writer_class, suffix, case, tmp_path_factory):
    events, info, cuts = case
    with mock.patch.object(evtools.formats.text, "WRITE_ROWS", 5):
        chunked = write_bytes(writer_class, events, cuts, info)
    assert chunked == write_bytes(writer_class, events, [], info)
    path = tmp_path_factory.mktemp("rt") / f"events.{suffix}"
    path.write_bytes(chunked)
    # both carry the sensor size: CSV in its faery header, txt in its first line
    got_info, got = read_all(path, chunk_events=3)
    assert np.array_equal(got, events)
    assert got_info.size == info.size


def test_csv_size_is_inferred_from_the_events_without_a_sized_header(tmp_path):
    (tmp_path / "a.csv").write_text("t,x,y,p\n1,4,7,1\n2,9,1,1\n3,0,2,0\n")
    info, got = read_all(tmp_path / "a.csv")
    assert np.array_equal(got, make_events([1, 2, 3], [4, 9, 0], [7, 1, 2], [1, 1, 0])) and info.size == (10, 8)


def test_csv_writer_header_keeps_the_sensor_size(tmp_path):
    events = make_events([1, 2, 3], [4, 9, 0], [7, 1, 2], [1, 1, 0])
    with create_events(tmp_path / "a.csv", StreamInfo(640, 480)) as writer:
        writer.write(events)
    info, got = read_all(tmp_path / "a.csv")
    assert np.array_equal(got, events) and info.size == (640, 480)


def test_end_to_end_txt(tmp_path, dvxplorer_events):
    with create_events(tmp_path / "a.txt", StreamInfo(320, 240)) as writer:
        for part in np.array_split(dvxplorer_events, 5):
            writer.write(part)
    info, got = read_all(tmp_path / "a.txt")
    assert np.array_equal(got, dvxplorer_events) and info.size == (320, 240)


# -- bad inputs ---------------------------------------------------------------------------------------------
def test_csv_line_with_letters_names_file_and_line(tmp_path):
    with pytest.raises(FormatError, match=r"bad\.csv: line 3: 'abc' is not a number"):
        read_text(tmp_path, "t,x,y,p\n1,2,3,1\n2,abc,3,1\n3,4,5,0\n", "bad.csv", sensor_size=(8, 8))


def test_csv_wrong_number_of_columns(tmp_path):
    with pytest.raises(FormatError, match=r"cols\.csv: line 4: 3 columns, expected 4"):
        read_text(tmp_path, "t,x,y,p\n1,2,3,1\n2,2,3,1\n3,4,5\n", "cols.csv", sensor_size=(8, 8))


def test_compensating_column_counts_are_caught(tmp_path):
    with pytest.raises(FormatError, match=r"line 2: 3 columns"):
        read_text(tmp_path, "1,2,3,1\n2,2,3\n3,4,5,0,1\n", "c.csv", sensor_size=(8, 8))


def test_txt_bad_lines(tmp_path):
    with pytest.raises(FormatError, match=r"t\.txt: line 3: 'nope' is not a number"):
        read_text(tmp_path, "10 10\n0.1 1 2 1\n0.2 nope 2 1\n", "t.txt")
    with pytest.raises(FormatError, match=r"u\.txt: line 2: 3 columns"):
        read_text(tmp_path, "0.1 1 2 1\n0.2 2 1\n", "u.txt", sensor_size=(8, 8))


def test_csv_header_without_needed_columns(tmp_path):
    with pytest.raises(FormatError, match=r"h\.csv: line 1: .*lacks column\(s\) p"):
        read_text(tmp_path, "t,x,y,brightness\n1,2,3,4\n", "h.csv", sensor_size=(8, 8))


def test_coordinates_outside_int16(tmp_path):
    with pytest.raises(FormatError, match=r"o\.csv: line 2: x or y outside"):
        read_text(tmp_path, "t,x,y,p\n1,70000,3,1\n", "o.csv", sensor_size=(8, 8))


def test_polarity_must_be_zero_one_or_minus_one_plus_one(tmp_path):
    """CSV polarity 2, 0.5 and -7 used to become 1, 1 and 0: refused with the line number."""
    from tests.helpers import assert_clean_error, run

    for value in ("2", "0.5", "-7"):
        path = tmp_path / "p.csv"
        path.write_text(f"t,x,y,p\n1,1,1,1\n2,1,1,{value}\n")
        assert_clean_error(run("info", path, "--sensor-size", "4x4", check=False), "p.csv", "line 3", "p must be")
    path.write_text("t,x,y,p\n1,1,1,-1\n2,1,1,1\n3,1,1,-1\n")
    assert run("info", path, "--sensor-size", "4x4").returncode == 0


@pytest.mark.parametrize("t,fits", [(2**62, True), (-(2**62), True), (2**62 + 1, False), (2**63 - 1, False),
                                    (2**63, False), (-(2**63), False), (10**30, False)])
def test_times_beyond_the_supported_range_are_refused_by_name(tmp_path, t, fits):
    """t = 2^63 - 1 was refused as "does not fit in 64 bits" (it does; the parser saturates there, so the two
    could not be told apart): times are supported in +-2^62 us, and a time outside is refused as such."""
    text = f"t,x,y,p\n0,1,1,1\n{t},1,1,1\n" if t > 0 else f"t,x,y,p\n{t},1,1,1\n0,1,1,1\n"
    if fits:
        events, _ = read_text(tmp_path, text, "r.csv", sensor_size=(4, 4))
        assert int(events["t"].max() if t > 0 else events["t"].min()) == t
    else:
        with pytest.raises(FormatError, match=r"r\.csv: line \d: t is outside the \+-2\^62 us"):
            read_text(tmp_path, text, "r.csv", sensor_size=(4, 4))


@st.composite
def _text_file(draw):
    """Lines of t x y p in the syntaxes files have (CSV or whitespace, CR LF, blank lines, tabs, a 5th label
    column), times increasing."""
    csv = draw(st.booleans())
    floats = not csv or draw(st.booleans())
    polarities = draw(st.sampled_from([["0", "1"], ["-1", "1"] + (["+1"] if csv else [])]))  # (one file, one way)
    lines, t = [], 0
    for _ in range(draw(st.integers(0, 40))):
        if draw(st.integers(0, 9)) == 0:
            lines.append(draw(st.sampled_from(["", "\r"] if csv else ["", "  ", "\t\r"])))
            continue
        t += draw(st.integers(0, 10**draw(st.sampled_from([1, 6, 12]))))
        if floats and not csv:
            t_text = draw(st.sampled_from([f"{t / 1e6:.6f}", f"{t / 1e6:.9f}", repr(t / 1e6), f"{t / 1e6:.3f}"]))
        else:
            t_text = str(t) + (draw(st.sampled_from(["", ".0", ".000"])) if floats else "")  # (.5: refused)
        x, y = draw(st.integers(0, 2047)), draw(st.integers(0, 2047))
        p = draw(st.sampled_from(polarities))
        fields = [t_text, str(x).zfill(draw(st.integers(1, 4))), str(y), p]
        separator = "," if csv else draw(st.sampled_from([" ", "\t", "  "]))
        line = separator.join(fields) + (draw(st.sampled_from(["", " ", "\r"])) if not csv else draw(
            st.sampled_from(["", "\r"])))
        lines.append(line)
    return csv, lines


@settings(max_examples=150, deadline=None)
@given(_text_file(), st.integers(16, 4096))
def test_text_files_read_as_the_naive_parser_reads_them(tmp_path_factory, case, block_bytes):
    """Random text files (both syntaxes, any block size): the events are Python's own parse of each line, whether
    the kernel or numpy's parser read a block."""
    from evtools.formats.text import TextReader
    from tests.naive.text import naive_text_events

    csv, lines = case
    path = tmp_path_factory.mktemp("text") / ("events.csv" if csv else "events.txt")
    path.write_bytes(("".join(line + "\n" for line in lines)).encode())
    expected = naive_text_events(lines, csv)
    assume(expected)  # a file of no events is refused as empty (tested elsewhere)
    if csv and expected and len({("." in line) for line in lines if line.strip()}) > 1:
        block_bytes = 1 << 20  # a CSV file mixing integer and decimal times is read as floats block by block
    with open_events(path, sensor_size=(2048, 2048), check=False) as stream:
        assert isinstance(stream.reader, TextReader)
        stream.reader.block_bytes = block_bytes
        events = concatenate(stream)
    assert list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(),
                    events["p"].astype(int).tolist())) == expected


@st.composite
def _token(draw):
    """A decimal number as files write them: sign, leading zeros, decimals with trailing zeros, up to 22
    significant digits, now and then an exponent (which the kernel leaves to numpy)."""
    count = draw(st.sampled_from([1, 3, 6, 12, 15, 16, 17, 18, 19, 22]))
    digits = "0" * draw(st.sampled_from([0, 0, 1, 25])) + "".join(
        draw(st.lists(st.sampled_from("0123456789"), min_size=count, max_size=count)))
    text = draw(st.sampled_from(["", "-", "+"])) + digits
    if draw(st.booleans()):
        cut = draw(st.integers(0, len(digits)))
        text = text[:len(text) - len(digits)] + digits[:cut] + "." + digits[cut:] + "0" * draw(st.integers(0, 4))
    if draw(st.integers(0, 19)) == 0:
        text += draw(st.sampled_from(["e3", "E-2", "e+0"]))
    return text


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(_token(), min_size=4, max_size=4), min_size=1, max_size=30), st.booleans())
@example([["0." + "0" * 21 + "1", "-0.0", "900719925474099.1", "1"]], False)  # 22 decimals; 2^53 - 1: read
@example([["0." + "0" * 22 + "1", "2", "3", "4"]], True)  # 23 decimals: numpy's
@example([["900719925474099.2", "2", "3", "4"]], False)  # a mantissa of 2^53: numpy's
def test_the_kernel_reads_each_number_as_pythons_float_bit_for_bit(rows, csv):
    """Every number the kernel reads is ``float(token)`` exactly (the correctly rounded double, which numpy's parser
    gives too); a plain decimal of up to 15 significant digits and 22 decimals is always read by the kernel, never
    left to numpy."""
    from evtools._kernels.text import OTHER_SYNTAX, PARSED, parse_text
    from evtools.formats.text import _POWERS_OF_TEN_FLOAT

    block = "".join((", " if csv else " \t").join(row) + "\n" for row in rows).encode()
    mantissas, decimals = np.empty((len(rows), 4), np.int64), np.empty((len(rows), 4), np.int64)
    lines = np.empty(len(rows), np.int64)
    status, n, _, _, point = parse_text(np.frombuffer(block, np.uint8), 4, csv, mantissas, decimals, lines, -1)
    tokens = [token for row in rows for token in row]
    plain = all("e" not in token.lower() and len(token.lstrip("+-").replace(".", "").lstrip("0")) <= 15
                and len(token.partition(".")[2].rstrip("0")) <= 22 for token in tokens)
    if plain:
        assert status == PARSED
    if status == PARSED:
        assert n == len(rows) and lines[:n].tolist() == list(range(n))
        assert point == any("." in token for token in tokens)
        values = mantissas[:n].astype(np.float64) / _POWERS_OF_TEN_FLOAT[decimals[:n]]
        expected = np.array([[float(token) for token in row] for row in rows])
        assert values.tobytes() == np.where(expected == 0, 0.0, expected).tobytes()  # -0 is read as 0
    else:
        assert status == OTHER_SYNTAX and not plain


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(event_arrays(), st.sampled_from([",", ";", " ", "\t", "  "]), st.sampled_from(["none", "plain", "faery"]),
       st.sampled_from(["extension", "option"]))
def test_a_csv_keeps_microseconds_whatever_its_separator(tmp_path_factory, case, separator, header, declared):
    """A file read as CSV (its .csv extension, or --input-format csv on another name) has t in microseconds with
    commas, semicolons, spaces or tabs between its fields (faery writes any separator), a header or none: never
    taken for rpg text with t in seconds (a factor 10^6, silently, before)."""
    events, info, _ = case
    assume(len(events) > 0)
    names = {"none": None, "plain": ["t", "x", "y", "p"], "faery": ["t", f"x@{info.width}", f"y@{info.height}", "on"]}
    lines = ([separator.join(names[header])] if names[header] else []) + [
        separator.join(str(int(v)) for v in row) for row in zip(events["t"], events["x"], events["y"], events["p"])]
    path = tmp_path_factory.mktemp("sep") / ("events.csv" if declared == "extension" else "events.data")
    path.write_text("\n".join(lines) + "\n")
    options = {"format": "csv"} if declared == "option" else {}
    read_info, read = read_all(path, sensor_size=(info.width, info.height), **options)
    assert read_info.format == "csv"
    assert np.array_equal(read, events)


def test_a_space_separated_txt_keeps_seconds_and_commas_anywhere_mean_csv(tmp_path):
    """The .txt convention is unchanged: whitespace-separated t in seconds; a first line with commas is CSV."""
    events, info = read_text(tmp_path, "0.5 1 2 1\n1.25 3 4 0\n", name="events.txt", sensor_size=(8, 8))
    assert (info.format, events["t"].tolist()) == ("txt", [500_000, 1_250_000])
    events, info = read_text(tmp_path, "t,x,y,p\n5,1,2,1\n", name="events.txt", sensor_size=(8, 8))
    assert events["t"].tolist() == [5]


@pytest.mark.parametrize("text, name, line", [("t,x,y,p\n5,1,2,1\n0.5,1,2,1\n", "events.csv", 3),
                                              ("0.000010,1,2,1\n", "events.txt", 1),
                                              ("0.5 1 2 1\n", "events.csv", 1)])
def test_csv_times_that_are_not_whole_microseconds_are_refused(tmp_path, text, name, line):
    """CSV times are integer microseconds: a fraction (seconds written to a CSV, an rpg file named .csv) was rounded
    to a whole microsecond, silently (a recording of seconds collapsed into 1 us). Whole numbers written as
    floats or with an exponent are taken."""
    with pytest.raises(FormatError, match=rf"{name}: line {line}: t is not a whole number of microseconds.*separated by spaces"):
        read_text(tmp_path, text, name=name, sensor_size=(8, 8))
    events, _ = read_text(tmp_path, "t,x,y,p\n1e3,1,2,1\n2000.0,3,4,0\n", sensor_size=(8, 8))
    assert events["t"].tolist() == [1000, 2000]


@pytest.mark.parametrize("text, name", [("t,x,y,p\n5,1,2,1\n", "events.csv"), ("5,1,2,1\n", "events.csv"),
                                        ("0.000005 1 2 1\n", "events.txt")])
def test_a_byte_order_mark_is_not_part_of_the_first_field(tmp_path, text, name):
    """Excel writes UTF-8 CSV with a byte-order mark: it was read into the header's first name ("lacks column t")
    or the first number."""
    path = tmp_path / name
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    _, events = read_all(path, sensor_size=(8, 8))
    assert (events["t"].tolist(), events["x"].tolist()) == ([5], [1])


@settings(max_examples=40, deadline=None)
@given(base=st.one_of(st.integers(2**53 - 50, 2**53 + 50), st.integers(-10**17, 10**17),
                      st.integers(10**17, 10**18 - 100)), gaps=st.lists(st.integers(0, 3), min_size=1, max_size=20))
def test_txt_times_in_seconds_are_read_to_the_microsecond(tmp_path_factory, base, gaps):
    """rpg text holds seconds with 6 decimals, which the writer makes exactly; read through float64 seconds they lost
    1 us near 2^53 us (a QA sweep): read as decimals in integers, every time up to 10^18 us comes back exact."""
    t = base + np.cumsum(gaps)
    events = make_events(t, np.zeros(len(t), int), np.zeros(len(t), int), np.ones(len(t), int))
    path = tmp_path_factory.mktemp("txt") / "a.txt"
    path.write_bytes(write_bytes(TxtWriter, events, [], StreamInfo(4, 4)))
    assert np.array_equal(read_all(path)[1]["t"], t)


@pytest.mark.parametrize("first, second", [(0, -1), (-1, 0)])
def test_a_csv_that_mixes_polarity_conventions_is_refused(tmp_path, first, second):
    """0 and -1 both taken as OFF in one file (a QA sweep: a file joined from two writers passed silently): the
    first line of the other convention is named; either convention alone is read."""
    lines = [f"{t},1,1,{p}" for t, p in enumerate([1, first] * 300 + [1, second], start=1)]
    path = tmp_path / "mixed.csv"
    path.write_text("t,x,y,p\n" + "\n".join(lines) + "\n")
    for chunk_events in (100, 100_000):  # (the two conventions in one block or in two)
        with pytest.raises(FormatError, match=f"line 603: p is {second} where earlier lines wrote OFF as {first}"):
            read_all(path, sensor_size=(4, 4), chunk_events=chunk_events)
    path.write_text("t,x,y,p\n" + "\n".join(lines[:-1]) + "\n")
    assert read_all(path, sensor_size=(4, 4))[1]["p"].sum() == 301


@settings(max_examples=60, deadline=None)
@given(times=st.lists(st.tuples(st.integers(-10**12, 2 * 10**15), st.integers(0, 999), st.integers(1, 3)),
                      min_size=1, max_size=20))
def test_txt_times_with_more_decimals_round_half_to_even(tmp_path_factory, times):
    """Times in seconds with 7-9 decimals (nanoseconds, as ROS exports write) went through float64 (1 us off at
    Unix times, two microseconds merged: a QA sweep): read in integers, rounded half to even to the microsecond, as
    Python's decimal module rounds them."""
    from decimal import ROUND_HALF_EVEN, Decimal

    times = sorted(times)
    lines, expected = [], []
    for us, sub, places in times:
        text = f"{Decimal(us) / 10**6 + Decimal(sub) / 10**9:.{6 + places}f}"
        lines.append(f"{text} 1 1 1")
        expected.append(int((Decimal(text) * 10**6).quantize(Decimal(1), rounding=ROUND_HALF_EVEN)))
    path = tmp_path_factory.mktemp("ns") / "ns.txt"
    path.write_text("4 4\n" + "\n".join(lines) + "\n")
    assert read_all(path)[1]["t"].tolist() == expected


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(suffix=st.sampled_from(["csv", "txt"]), n=st.integers(1, 300), seed=st.integers(0, 2**31),
       at=st.floats(0, 1, exclude_max=True))
def test_a_text_file_cut_inside_its_last_line_keeps_the_lines_before_it(tmp_path, suffix, n, seed, at):
    """A CSV or text file cut mid-line (its writer stopped) was refused whole. Its last line, without its newline,
    is now left out when it does not read as an event (said, the stream marked cut); a line cut exactly before its
    newline is whole. Whatever the cut, the events read are the written ones' prefix, and the stream is marked cut
    exactly when a line was lost."""
    from tests.helpers import random_events

    events = random_events(n, 64, 48, seed=seed)
    whole = tmp_path / f"whole_{seed}_{n}.{suffix}"
    with create_events(whole, StreamInfo(64, 48)) as writer:
        writer.write(events)
    data = whole.read_bytes()
    header = data.index(b"\n") + 1  # (CSV: the column names; text: the sensor size)
    position = header + int(at * (len(data) - header))
    cut = tmp_path / f"cut_{seed}_{n}.{suffix}"
    cut.write_bytes(data[:position])
    with open_events(cut, sensor_size=(64, 48)) as stream:
        got = concatenate(stream)
        was_cut = stream.was_cut
    complete_lines = data[header:position].count(b"\n")
    partial = data[header:position].rsplit(b"\n", 1)[-1]
    whole_last = partial != b"" and data[position:position + 1] == b"\n"  # (cut just before a newline: a whole line)
    assert len(got) == complete_lines + whole_last
    assert np.array_equal(got["t"], events["t"][:len(got)]) and np.array_equal(got["x"], events["x"][:len(got)])
    assert np.array_equal(got["p"], events["p"][:len(got)])
    assert was_cut == (partial != b"" and not whole_last)
