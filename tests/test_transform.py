"""convert's time slicing and geometry (issue 18 item 3): against a slow reference on random streams and random
options, chunk invariance, round trips, crop + flip = flip + the mirrored crop, and the CLI on a hand-made stream."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from evtools.events import StreamInfo, join, make_events
from evtools.transform import Time, Transform, TransformError
from tests.helpers import assert_clean_error, cut, read_all, run
from tests.naive.transform import naive_transform


def _random(seed, n, width, height):
    rng = np.random.default_rng(seed)
    return make_events(np.cumsum(rng.integers(0, 50, n)) + 1000, rng.integers(0, width, n),
                       rng.integers(0, height, n), rng.integers(0, 2, n))


def _tuples(events):
    return list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()))


@st.composite
def cases(draw):
    width, height = draw(st.integers(1, 20)), draw(st.integers(1, 20))
    crop = None
    if draw(st.booleans()):
        x, y = draw(st.integers(0, width - 1)), draw(st.integers(0, height - 1))
        crop = (x, y, draw(st.integers(1, width - x)), draw(st.integers(1, height - y)))
    start = draw(st.one_of(st.none(), st.integers(0, 3000)))
    end = draw(st.one_of(st.none(), st.integers((start or 0) + 1, 6000)))
    return dict(width=width, height=height, crop=crop, start_us=start, end_us=end,
                polarity=draw(st.sampled_from([None, "on", "off"])), flip_x=draw(st.booleans()),
                flip_y=draw(st.booleans()), transpose=draw(st.booleans()), seed=draw(st.integers(0, 2**16)),
                cuts=draw(st.lists(st.integers(0, 300), max_size=5)))


@settings(max_examples=150, deadline=None)
@given(case=cases())
def test_transform_equals_the_reference_whatever_the_chunks(case):
    width, height, seed, cuts = case.pop("width"), case.pop("height"), case.pop("seed"), case.pop("cuts")
    events = _random(seed, 300, width, height)
    expected, size = naive_transform(_tuples(events), width, height, **case)
    start, end = case.pop("start_us"), case.pop("end_us")
    transform = Transform(StreamInfo(width, height), start=None if start is None else Time(start),
                          end=None if end is None else Time(end), **case)
    got = join([transform.process(part) for part in cut(events, cuts)] + [transform.flush()])
    assert _tuples(got) == expected
    assert (transform.info.width, transform.info.height) == size
    assert _tuples(events) == _tuples(_random(seed, 300, width, height))  # the input was not changed


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**16), width=st.integers(2, 16), height=st.integers(2, 16), data=st.data())
def test_round_trips_and_crop_then_flip_is_flip_then_the_mirrored_crop(seed, width, height, data):
    events = _random(seed, 200, width, height)
    info = StreamInfo(width, height)
    for options in ({"flip_x": True}, {"flip_y": True}, {"transpose": True}):
        once = Transform(info, **options)
        twice = Transform(once.info, **options).process(once.process(events))
        assert np.array_equal(twice, events)
    x = data.draw(st.integers(0, width - 1))
    y = data.draw(st.integers(0, height - 1))
    w, h = data.draw(st.integers(1, width - x)), data.draw(st.integers(1, height - y))
    crop_then_flip = Transform(info, crop=(x, y, w, h), flip_x=True, flip_y=True).process(events)
    flipped = Transform(info, flip_x=True, flip_y=True).process(events)
    mirrored = (width - x - w, height - y - h, w, h)
    assert np.array_equal(crop_then_flip, Transform(info, crop=mirrored).process(flipped))


def test_bad_rectangles_and_slices():
    import pytest

    info = StreamInfo(10, 8)
    for crop in ((0, 0, 11, 8), (5, 0, 6, 8), (0, 0, 0, 3), (-1, 0, 2, 2)):
        with pytest.raises(TransformError, match="not inside the 10x8 sensor"):
            Transform(info, crop=crop)
    with pytest.raises(TransformError, match="not after the start"):
        Transform(info, start=Time(500), end=Time(500))


def test_cli_slices_crops_and_flips_a_hand_made_stream(tmp_path):
    source = tmp_path / "in.csv"
    source.write_text("t,x,y,p\n1000,0,0,1\n1500,3,1,0\n2000,9,7,1\n2600,4,2,1\n3000,5,5,0\n")
    out = tmp_path / "out.csv"
    run("convert", source, "--sensor-size", "10x8", "-o", out, "--start", "500us", "--end", "@3ms", "--crop",
        "2,1,4,4", "--flip-x")
    info, got = read_all(out)
    assert (info.width, info.height) == (4, 4)
    # kept: 1500 (3,1) -> (1,0) -> flip x (2,0); 2600 (4,2) -> (2,1) -> (1,1); 2000 is outside, 3000 at the end
    assert _tuples(got) == [(1500, 2, 0, False), (2600, 1, 1, True)]
    on = tmp_path / "on.csv"
    run("convert", source, "--sensor-size", "10x8", "-o", on, "--polarity", "on", "--transpose")
    info, got = read_all(on)
    assert (info.width, info.height) == (8, 10)
    assert _tuples(got) == [(1000, 0, 0, True), (2000, 7, 9, True), (2600, 2, 4, True)]
    bad = run("convert", source, "--sensor-size", "10x8", "-o", tmp_path / "x.csv", "--crop", "8,0,4,4", check=False)
    assert_clean_error(bad, "not inside the 10x8 sensor")
    usage = run("convert", source, "-o", tmp_path / "x.csv", "--crop", "1,2,3", check=False)
    assert usage.returncode == 2 and b"X,Y,W,H" in usage.stderr
    assert not (tmp_path / "x.csv").exists()


def _slicing_argv(case) -> list[str]:
    argv = []
    if case["start_us"] is not None:
        argv += ["--start", f"{case['start_us']}us"]
    if case["end_us"] is not None:
        argv += ["--end", f"{case['end_us']}us"]
    if case["polarity"]:
        argv += ["--polarity", case["polarity"]]
    if case["crop"]:
        argv += ["--crop", ",".join(map(str, case["crop"]))]
    argv += [flag for flag in ("--flip-x", "--flip-y", "--transpose") if case[flag[2:].replace("-", "_")]]
    return argv


def _pixels_naive(values, case):
    """A (height, width) map under the case's geometry, pixel by pixel (the map follows its events)."""
    kept, (width, height) = naive_transform(
        [(0, x, y, True) for y in range(case["height"]) for x in range(case["width"])], case["width"],
        case["height"], crop=case["crop"], flip_x=case["flip_x"], flip_y=case["flip_y"],
        transpose=case["transpose"])
    out = np.empty((height, width), values.dtype)
    for (_, x, y, _), (_, x0, y0, _) in zip(kept, [(0, x, y, True) for y in range(case["height"])
                                                    for x in range(case["width"]) if _inside(x, y, case)]):
        out[y, x] = values[y0, x0]
    return out


def _inside(x, y, case):
    if not case["crop"]:
        return True
    cx, cy, cw, ch = case["crop"]
    return cx <= x < cx + cw and cy <= y < cy + ch


@settings(max_examples=20, deadline=None)
@given(cases())
def test_every_stream_command_slices_as_convert_does(tmp_path_factory, case):
    """bafilter, estimate and correct take the slicing options too (issue 18 item 3; --polarity in bafilter too
    since issue 39): their output on a sliced
    stream equals their output on the stream sliced beforehand (slow reference), and correct's thresholds map is cut
    and turned with the events (reference: the map moved pixel by pixel)."""
    from click.testing import CliRunner

    from evtools.cli.main import cli
    from evtools.formats import create_events
    from evtools.formats.thresholds import ThresholdMap, write_thresholds

    folder = tmp_path_factory.mktemp("slice")
    events = _random(case["seed"], 400, case["width"], case["height"])
    with create_events(folder / "in.aedat4", StreamInfo(case["width"], case["height"])) as writer:
        writer.write(events)
    kept, (width, height) = naive_transform(_tuples(events), case["width"], case["height"], case["start_us"],
                                            case["end_us"], case["polarity"], case["crop"], case["flip_x"], case["flip_y"],
                                            case["transpose"])
    if not kept:
        return
    with create_events(folder / "pre.aedat4", StreamInfo(width, height)) as writer:
        writer.write(make_events(*(np.array(column) for column in zip(*kept))))
    rng = np.random.default_rng(case["seed"])
    on, off = rng.uniform(0.1, 0.4, (2, case["height"], case["width"]))
    valid = rng.random((case["height"], case["width"])) < 0.9
    write_thresholds(str(folder / "map.h5"), ThresholdMap(on, off, valid, {"method": "test"}))
    write_thresholds(str(folder / "premap.h5"), ThresholdMap(*(_pixels_naive(v, case) for v in (on, off, valid)),
                                                             {"method": "test"}))
    slicing = _slicing_argv(case)
    runner = CliRunner()
    for name, command, prepared in (
            ("bafilter", ["bafilter", "--method", "baf", "--dt-us", "200"], []),
            ("estimate", ["estimate", "--method", "offe", "--segment-us", "500", "--min-events", "2"], []),
            ("correct", ["correct", "--thresholds"], ["map.h5", "premap.h5"])):
        outputs = []
        for source, extra, output in (("in.aedat4", slicing, "a"), ("pre.aedat4", [], "b")):
            maps = [str(folder / prepared[len(outputs)])] if prepared else []
            suffix = ".h5" if name == "estimate" else ".aedat4"
            result = runner.invoke(cli, ["-q", *command, *maps, str(folder / source), *extra, "-o",
                                         str(folder / (output + suffix))])
            named = result.stderr.replace(str(folder / source), "IN")
            for given in maps:  # the map each run was given
                named = named.replace(given, "MAP")
            outputs.append((result.exit_code, named, folder / (output + suffix)))
        (code_a, text_a, path_a), (code_b, text_b, path_b) = outputs
        assert code_a == code_b, (name, text_a, text_b)
        if code_a:  # the same refusal (too few events for a map, say)
            assert text_a == text_b, (name, text_a, text_b)
            continue
        if name == "estimate":  # the sliced run's map is the camera's: cut and turned, it is the other's
            first, second = read_all_thresholds(path_a), read_all_thresholds(path_b)
            assert (first.width, first.height) == (case["width"], case["height"])
            for field in ("on", "off", "valid"):
                np.testing.assert_array_equal(_pixels_naive(getattr(first, field), case), getattr(second, field))
            assert first.valid.sum() == second.valid.sum()  # none valid outside the crop
        else:
            assert read_all(path_a)[0].width == width and read_all(path_a)[0].height == height
            expected = read_all(path_b)[1]
            if name == "correct" and case["end_us"] is not None:  # (its output keeps t < end too: a run's excess
                expected = expected[expected["t"] < int(events["t"][0]) + case["end_us"]]  # may lie beyond)
            np.testing.assert_array_equal(read_all(path_a)[1], expected)


def test_a_map_estimated_on_a_sliced_stream_is_the_cameras(tmp_path):
    """Found by a QA sweep: `estimate --flip-x` wrote its map flipped, with nothing to say so, and `correct` (which
    takes the camera's map) applied it unflipped: count CV 0.18 -> 0.25, worse than no correction. A map is now
    always the camera's: a per-pixel method gives the same map whatever the flips, and a crop's map is the
    camera's with the pixels outside it not valid, offline and online, and says how it was made."""
    from evtools.formats.thresholds import read_thresholds

    source = tmp_path / "flicker.aedat4"
    run("simulate", "scene:flicker", "--size", "16x12", "--duration", "1s", "--sigma-thres", "0.03", "--seed", "7",
        "-o", source)
    maps = {}
    for name, extra in (("plain", []), ("flipped", ["--flip-x", "--flip-y"]),
                        ("cut", ["--crop", "2,1,9,7", "--transpose"])):
        run("estimate", source, "--method", "stimulus", *extra, "-o", tmp_path / f"{name}.h5")
        maps[name] = read_thresholds(str(tmp_path / f"{name}.h5"))
    plain, flipped, cut = maps["plain"], maps["flipped"], maps["cut"]
    assert plain.valid.all() and "sliced" not in plain.attributes
    for field in ("on", "off", "valid", "fit"):
        np.testing.assert_array_equal(getattr(flipped, field), getattr(plain, field))
    inside = np.zeros((12, 16), bool)
    inside[1:8, 2:11] = True
    assert (cut.width, cut.height) == (16, 12) and np.array_equal(cut.valid, inside)
    np.testing.assert_array_equal(cut.on[inside], plain.on[inside])
    assert "--crop 2,1,9,7 --transpose" in cut.attributes["sliced"] and cut.attributes["width"] == 16
    run("estimate", source, "--method", "stimulus", "--crop", "2,1,9,7", "--online", "--interval", "300ms",
        "-o", tmp_path / "series.h5")
    series = read_thresholds(str(tmp_path / "series.h5"), series=True)
    assert series.on.shape[1:] == (12, 16) and not series.valid[:, ~inside].any()
    run("correct", source, "--thresholds", tmp_path / "cut.h5", "--crop", "2,1,9,7", "--transpose", "-o",
        tmp_path / "corrected.aedat4")  # the same options cut the camera's map back to the stream


def read_all_thresholds(path):
    from evtools.formats.thresholds import read_thresholds

    return read_thresholds(str(path))


def test_a_start_after_the_last_event_is_said(tmp_path):
    """--start past the stream's end kept nothing with no word of why ("31,035 events in, 0 out"; estimate said
    the stream had no events: a QA sweep): a warning names the start and where the stream ends; a start within it
    says nothing."""
    import evtools

    stream = tmp_path / "s.aedat4"
    evtools.write(stream, make_events([1_000, 500_000, 1_001_000], [0, 1, 2], [0, 1, 2], [1, 0, 1]), StreamInfo(4, 4))
    late = run("convert", stream, "--start", "2s", "-o", tmp_path / "late.aedat4").stderr.decode()
    assert "the start (2 s) lies after the stream's last event (1 s after its first" in late, late
    within = run("convert", stream, "--start", "400ms", "-o", tmp_path / "within.aedat4").stderr.decode()
    assert "lies after" not in within and len(read_all(tmp_path / "within.aedat4")[1]) == 2
