"""APS frames as data (issue 38 item 1): read as DV and dv-processing write them, written so that DV's readers
(dv-processing, aedat) read them back, kept by HDF5, passed through every stage in order, sliced as the events."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evtools
from evtools.events import join
from evtools.frames import Frame
from tests.conftest import data_file
from tests.helpers import assert_clean_error, assert_same_events, make_events, random_events, run

RECORDINGS = ["davis346_lab_frames.aedat4", "davis346_street_frames.aedat4"]


def _dv_frames(path) -> list:
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) reads the frames")
    reader, frames = dv.io.MonoCameraRecording(str(path)), []
    while (frame := reader.getNextFrame()) is not None:
        frames.append((frame.timestamp, int(frame.exposure.total_seconds() * 1e6 + 0.5), frame.positionX,
                       frame.positionY, frame.image.copy()))
    return frames


def _aedat_frames(path) -> list:
    aedat = pytest.importorskip("aedat", reason="aedat (a dependency of the tests) reads the frames")
    return [packet["frame"] for packet in aedat.Decoder(str(path)) if "frame" in packet]


def _same(ours: list[Frame], theirs: list) -> None:
    """Ours against dv-processing's (timestamp = start of exposure, exposure, position, image)."""
    assert len(ours) == len(theirs) > 0
    for frame, (t, exposure, x, y, image) in zip(ours, theirs):
        assert (frame.exposure_begin_us, frame.exposure_us, frame.offset_x, frame.offset_y) == (t, exposure, x, y)
        np.testing.assert_array_equal(frame.image, image.reshape(frame.image.shape))


@pytest.mark.parametrize("name", RECORDINGS)
def test_the_davis_recordings_frames_read_as_dv_processing_reads_them(name):
    path = data_file(name)
    events, info, frames = evtools.read(path, frames=True)
    _same(frames, _dv_frames(path))
    assert info.metadata["frame_size"] == (346, 260) and all(f.image.shape == (260, 346) for f in frames)
    assert_same_events(events, evtools.read(path)[0])  # the frames change nothing in the events
    for frame, theirs in zip(frames, _aedat_frames(path)):  # all five times, as the aedat package reads them
        assert frame.times() == (theirs["t"], theirs["begin_t"], theirs["end_t"], theirs["exposure_begin_t"],
                                 theirs["exposure_end_t"])


def _frames(rng, count: int, width: int, height: int, dtype=np.uint8, t0_us: int = 0) -> list[Frame]:
    frames, t = [], t0_us
    top = 255 if dtype == np.uint8 else 65535
    for _ in range(count):
        t += int(rng.integers(1, 50_000))
        exposure = int(rng.integers(0, 20_000))
        image = rng.integers(0, top + 1, (height, width)).astype(dtype)
        frames.append(Frame(image, t + exposure // 2, t, t + exposure, t - 1000, t + exposure + 9000))
        t += exposure
    return frames


def _recording(path, seed: int, frame_count: int, event_count: int, width: int, height: int, dtype=np.uint8):
    """An AEDAT 4.0 file at ``path`` of random events and frames (drawn from ``seed``): (events, frames)."""
    frames = _frames(np.random.default_rng(seed), frame_count, width, height, dtype)
    events = random_events(event_count, width, height, seed=seed)
    evtools.write(path, events, evtools.StreamInfo(width, height), frames=frames)
    return events, frames


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.integers(1, 80), height=st.integers(1, 60),
       count=st.integers(1, 5), compression=st.sampled_from(["none", "lz4", "zstd"]))
def test_evtools_frames_read_back_by_dv_processing_and_aedat(tmp_path_factory, seed, width, height, count,
                                                             compression):
    rng = np.random.default_rng(seed)
    frames = _frames(rng, count, width, height)
    events = random_events(500, width, height, seed=seed)
    path = tmp_path_factory.mktemp("frames") / "f.aedat4"
    evtools.write(path, events, evtools.StreamInfo(width, height), frames=frames, compression=compression)
    back, info, ours = evtools.read(path, frames=True)
    assert_same_events(back, events)
    assert len(ours) == count and all(a.same_as(b) for a, b in zip(ours, frames))
    _same(frames, _dv_frames(path))
    for frame, theirs in zip(frames, _aedat_frames(path)):
        assert frame.times() == (theirs["t"], theirs["begin_t"], theirs["end_t"], theirs["exposure_begin_t"],
                                 theirs["exposure_end_t"])
        np.testing.assert_array_equal(np.asarray(theirs["pixels"]).reshape(height, width), frame.image)


def test_frames_written_by_dv_processing_read_with_their_times_and_colour_converted(tmp_path):
    """dv-processing's writer (as DV records): t = start of exposure, end of exposure = t + exposure, no readout
    times; a BGR frame is read as gray by OpenCV's weights, with a warning."""
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) writes the file")
    import cv2

    path = tmp_path / "dv.aedat4"
    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.DAVISConfig("DAVIS346", (64, 48)))
    colour = (np.arange(64 * 48 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    gray = (np.arange(64 * 48) % 253).astype(np.uint8).reshape(48, 64)
    writer.writeFrame(dv.Frame(1000, 500, 0, 0, colour, dv.FrameSource.SENSOR))
    writer.writeFrame(dv.Frame(2000, 700, 0, 0, gray, dv.FrameSource.SENSOR))
    store = dv.EventStore()
    store.push_back(1200, 3, 4, True)
    writer.writeEvents(store)
    del writer
    _, _, frames = evtools.read(path, frames=True)
    assert [f.times() for f in frames] == [(1000, 0, 0, 1000, 1500), (2000, 0, 0, 2000, 2700)]
    np.testing.assert_array_equal(frames[0].image, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(frames[1].image, gray)
    done = run("info", path, "--json")
    assert "colour frames" in done.stderr.decode() and '"count": 2' in done.stdout.decode()


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_hdf5_keeps_every_frame_field_and_csv_says_it_drops_them(tmp_path, dtype):
    source = tmp_path / "s.aedat4"
    events, frames = _recording(source, 3, 4, 300, 20, 10, dtype)
    run("convert", source, "-o", tmp_path / "s.h5")
    back, info, ours = evtools.read(tmp_path / "s.h5", frames=True)
    assert_same_events(back, events)
    assert info.metadata["frame_size"] == (20, 10) and all(a.same_as(b) for a, b in zip(ours, frames))
    done = run("convert", tmp_path / "s.h5", "-o", tmp_path / "s.csv")
    assert "does not store APS frames" in done.stderr.decode() and "4 frames" in done.stderr.decode()


class _Recorder:
    """A writer that notes the order of what it is given."""

    def __init__(self):
        self.calls = []

    def write(self, chunk):
        self.calls.append(chunk.copy())

    def write_frame(self, frame):
        self.calls.append(frame)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), chunk_events=st.integers(50, 3000),
       stage=st.sampled_from(["bafilter", "hotpixel", "correct"]))
def test_stages_pass_every_frame_on_after_the_events_before_it(tmp_path_factory, seed, chunk_events, stage):
    """Whatever the chunks: every frame goes out once, in order, after every output event before the end of its
    exposure (a stage that holds events back, correct or a learning hotpixel filter, holds the frame too), and
    the events are those of a run without frames."""
    from evtools.cli.progress import process_stream
    from evtools.correction import ThresholdCorrector
    from evtools.filters import BAFilter

    rng = np.random.default_rng(seed)
    events = random_events(4000, 16, 12, seed=seed)
    frames = _frames(rng, 6, 16, 12, t0_us=int(events["t"][0]))
    path = tmp_path_factory.mktemp("relay") / "f.aedat4"
    evtools.write(path, events, evtools.StreamInfo(16, 12), frames=frames)

    def processor():
        if stage == "correct":
            on = np.full((12, 16), 0.18, np.float32)
            return ThresholdCorrector(16, 12, on, on * 1.1, target=0.2, max_gap_us=2000, hold_us=500)
        return BAFilter(16, 12, "baf" if stage == "bafilter" else "hotpixel", **(
            {"learn_us": 20_000} if stage == "hotpixel" else {}))

    recorder = _Recorder()
    with evtools.open(path, chunk_events=chunk_events) as stream:
        process_stream(stream, processor(), recorder, "test")
    written = [call for call in recorder.calls if isinstance(call, Frame)]
    assert len(written) == len(frames) and all(a.same_as(b) for a, b in zip(written, frames))
    out = [call for call in recorder.calls if not isinstance(call, Frame)]
    expected = processor()
    whole = join([expected.process(events), expected.flush()])
    assert_same_events(join(out) if out else whole[:0], whole)
    for index, call in enumerate(recorder.calls):
        if isinstance(call, Frame):
            later = [c for c in recorder.calls[index + 1:] if not isinstance(c, Frame)]
            assert all(int(c["t"].min()) >= call.order_us for c in later if len(c))


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), chunk_events=st.integers(50, 3000))
def test_simulate_on_events_passes_the_frames_on(tmp_path_factory, seed, chunk_events):
    """`simulate EVENTS` (noise added to a recording) left a DAVIS recording's APS frames out, silently: now each
    goes out once, after every output event before it, and the events are the injector's whatever the chunks."""
    from evtools.cli.simulate import _run_injector
    from evtools.noise import NoiseInjector

    rng = np.random.default_rng(seed)
    events = random_events(4000, 16, 12, seed=seed)
    frames = _frames(rng, 6, 16, 12, t0_us=int(events["t"][0]))
    path = tmp_path_factory.mktemp("inject") / "f.aedat4"
    evtools.write(path, events, evtools.StreamInfo(16, 12), frames=frames)
    recorder = _Recorder()
    with evtools.open(path, chunk_events=chunk_events) as stream:
        _run_injector(NoiseInjector(16, 12, seed=3, shot_noise_rate_hz=20.0), stream, recorder, None,
                      np.zeros(4, np.int64))
    written = [call for call in recorder.calls if isinstance(call, Frame)]
    assert len(written) == len(frames) and all(a.same_as(b) for a, b in zip(written, frames))
    out = [call for call in recorder.calls if not isinstance(call, Frame)]
    whole, _ = evtools.inject_noise(events, evtools.StreamInfo(16, 12), seed=3, shot_noise_rate_hz=20.0)
    assert_same_events(join(out), whole)
    for index, call in enumerate(recorder.calls):
        if isinstance(call, Frame):
            later = [c for c in recorder.calls[index + 1:] if not isinstance(c, Frame)]
            assert all(int(c["t"].min()) >= call.order_us for c in later if len(c))


def test_a_pipeline_keeps_the_frames_and_convert_slices_them_as_the_events(tmp_path):
    source = tmp_path / "s.aedat4"
    events, frames = _recording(source, 5, 5, 3000, 32, 24)
    piped = run("bafilter", "-", input=run("convert", source, "-o", "-").stdout).stdout
    (tmp_path / "piped.aedat4").write_bytes(piped)
    _, _, back = evtools.read(tmp_path / "piped.aedat4", frames=True)
    assert len(back) == 5 and all(a.same_as(b) for a, b in zip(back, frames))
    start, end = frames[1].order_us, frames[3].order_us
    run("convert", source, "--start", f"@{start}us", "--end", f"@{end}us", "--crop", "2,3,20,10",
        "--flip-x", "--transpose", "-o", tmp_path / "cut.aedat4")
    _, info, cut_frames = evtools.read(tmp_path / "cut.aedat4", frames=True)
    assert info.metadata["frame_size"] == (10, 20) == info.size
    assert [f.order_us for f in cut_frames] == [frames[1].order_us, frames[2].order_us]
    np.testing.assert_array_equal(cut_frames[0].image, frames[1].image[3:13, 2:22][:, ::-1].T)


def _first_packet_of(data: bytes, stream_id: int) -> int:
    """Byte position of the first packet of ``stream_id`` in an AEDAT 4.0 file (its 8-byte packet header)."""
    position = 14 + 4 + int(np.frombuffer(data, "<u4", 1, 14)[0])
    while int(np.frombuffer(data, "<i4", 1, position)[0]) != stream_id:
        position += 8 + int(np.frombuffer(data, "<u4", 1, position + 4)[0])
    return position


@pytest.mark.parametrize("suffix", [".aedat4", ".h5"])
def test_write_refuses_frames_its_readers_would_refuse_or_mangle(tmp_path, suffix):
    """evtools.write checks frames as it checks events: out of time order, colour, float or int64 images and images
    outside the frame stream are refused naming the frame, no file left (AEDAT 4.0 stored them, and evtools then
    refused the file; floats within 0-1 were cut to 0 or 1 and large integers wrapped, silently)."""
    import dataclasses

    events, frames = _recording(tmp_path / "good.aedat4", 3, 3, 200, 16, 12)
    info, path = evtools.StreamInfo(16, 12), tmp_path / f"bad{suffix}"
    image = frames[0].image
    bad = {
        "before the frame before it": [frames[1], frames[0]],
        "float32 array": [dataclasses.replace(frames[0], image=(image / 255).astype(np.float32))],
        "int64 array": [dataclasses.replace(frames[0], image=image.astype(np.int64) * 1000)],
        "shape (12, 16, 3)": [dataclasses.replace(frames[0], image=np.stack([image] * 3, -1))],
        "outside the 16 x 12 frame stream": [dataclasses.replace(frames[0], offset_x=1)],
        "before it begins": [dataclasses.replace(frames[0], exposure_begin_us=frames[0].exposure_end_us + 1)],
        "has an empty image (16 x 0)": [dataclasses.replace(frames[0], image=image[:0])],
    }
    for said, given_frames in bad.items():
        with pytest.raises(evtools.InvalidEventsError, match=re.escape(said)):
            evtools.write(path, events, info, frames=given_frames)
        assert list(tmp_path.iterdir()) == [tmp_path / "good.aedat4"], said
    evtools.write(path, events, info, frames=frames)  # the good ones, in order, as before
    assert len(evtools.read(path, frames=True)[2]) == len(frames)


def test_bad_frames_are_one_line_errors_naming_the_file(tmp_path):
    good = tmp_path / "good.aedat4"
    events, frames = _recording(good, 7, 3, 200, 16, 12)
    data = good.read_bytes()
    # frames whose times go backwards
    backwards = tmp_path / "backwards.aedat4"
    swapped = [frames[1], frames[0], frames[2]]
    evtools.write(backwards, events, evtools.StreamInfo(16, 12), frames=frames[:1])
    import evtools.formats.aedat4 as aedat4

    body = [aedat4._frame_body(f) for f in swapped]
    head_end = _first_packet_of(data, 1)  # the first frame packet
    packets = b"".join(np.array([1, len(b)], "<i4").tobytes() + b for b in body)
    backwards.write_bytes(data[:head_end] + packets)
    done = run("info", backwards, check=False)
    assert done.returncode == 1 and "frames go back in time" in done.stderr.decode() and "backwards" in \
        done.stderr.decode()
    # a frame packet cut short: the file read up to it, said, marked cut
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(data[:head_end] + np.array([1, len(body[0])], "<i4").tobytes() + body[0][:100])
    done = run("info", cut, "--json", check=False)
    assert done.returncode == 0 and "cut.aedat4: truncated AEDAT 4.0 packet" in done.stderr.decode()
    assert json.loads(done.stdout)["cut"] is True
    # a frame larger than the frame stream
    big = Frame(np.zeros((13, 16), np.uint8), 5, 5, 5)
    large = tmp_path / "large.aedat4"
    large.write_bytes(data[:head_end] + np.array([1, len(aedat4._frame_body(big))], "<i4").tobytes()
                      + aedat4._frame_body(big))
    done = run("info", large, check=False)
    assert done.returncode == 1 and "outside the 16 x 12 frame stream" in done.stderr.decode()
    # an exposure that ends before it begins: refused by the reader as by the writer (read, it could not be written)
    reversed_exposure = Frame(frames[0].image, 5, 9, 5)
    body = aedat4._frame_body(reversed_exposure)
    reversed_path = tmp_path / "reversed.aedat4"
    reversed_path.write_bytes(data[:head_end] + np.array([1, len(body)], "<i4").tobytes() + body)
    done = run("info", reversed_path, check=False)
    assert done.returncode == 1 and "reversed.aedat4: frame packet at byte" in done.stderr.decode() and \
        "ends its exposure (5 us) before it begins (9 us)" in done.stderr.decode()


@pytest.mark.parametrize("suffix", [".aedat4", ".h5"])
def test_a_region_of_interest_frame_reads_back_and_writes_again(tmp_path, suffix):
    """A frame of a region (4 x 4 at (8, 6) of a 16 x 12 sensor) keeps its frame stream's size through HDF5 as
    through AEDAT 4.0 (HDF5 stored no size and read the first image's, 4 x 4: the file read back could not be
    written again, its frame outside its own frame stream)."""
    events = random_events(300, 16, 12, seed=4)
    region = Frame(np.arange(16, dtype=np.uint8).reshape(4, 4), 1000, 900, 1100, offset_x=8, offset_y=6)
    path = tmp_path / f"roi{suffix}"
    evtools.write(path, events, evtools.StreamInfo(16, 12), frames=[region])
    back, info, frames = evtools.read(path, frames=True)
    assert info.metadata["frame_size"] == (16, 12) and len(frames) == 1 and frames[0].same_as(region)
    again = tmp_path / f"again{suffix}"
    evtools.write(again, back, info, frames=frames)
    assert evtools.read(again, frames=True)[2][0].same_as(region)
    if suffix == ".h5":  # a stated size that is no number is damage, one line
        import h5py

        with h5py.File(again, "r+") as f:
            f["frames"].attrs["width"] = "abc"
        assert_clean_error(run("info", again, check=False), "again.h5: frames/ states a frame size of abc x 12")


def test_hdf5_frames_without_an_exposure_are_read_by_their_time(tmp_path):
    """A frame whose exposure end is unknown (0) is placed by its time, as :attr:`Frame.order_us` and the other
    readers place it (HDF5 placed it by the 0: a frame of unknown exposure between two known ones was "going
    backwards", and every such frame was read with the first chunk of events, at 0.13 s instead of 2.5 s)."""
    rng = np.random.default_rng(5)
    events = make_events(np.sort(rng.integers(0, 3_000_000, 20_000)), rng.integers(0, 16, 20_000),
                         rng.integers(0, 12, 20_000), rng.integers(0, 2, 20_000))
    frames = [Frame(np.full((12, 16), 1, np.uint8), 1_000_000, 0, 0),
              Frame(np.full((12, 16), 2, np.uint8), 2_000_000, 1_990_000, 2_010_000),
              Frame(np.full((12, 16), 3, np.uint8), 2_500_000, 0, 0)]
    path = tmp_path / "s.h5"
    evtools.write(path, events, evtools.StreamInfo(16, 12), frames=frames)
    with evtools.open(path, chunk_events=1000) as stream:
        taken = []  # (frame time, the last event read before it was taken)
        last_us = -1
        for chunk in stream:
            taken += [(frame.order_us, last_us) for frame in stream.take_frames()]
            last_us = int(chunk["t"][-1])
        taken += [(frame.order_us, last_us) for frame in stream.take_frames()]
    assert [t for t, _ in taken] == [1_000_000, 2_010_000, 2_500_000]
    assert all(t - 400_000 < before_us <= t for t, before_us in taken), taken


def test_render_draws_the_events_over_the_latest_aps_frame(tmp_path):
    """render --aps: a pixel without events shows the gray of the frame whose exposure ended last before the
    window's end; a pixel with events keeps its event colour; without --aps, neither shows the frame."""
    import cv2

    events = evtools.from_columns([15_000, 15_000], [3, 5], [2, 2], [True, False])
    image = (np.arange(8 * 6) * 5).astype(np.uint8).reshape(6, 8)
    frames = [Frame(np.zeros((6, 8), np.uint8), 1000, 0, 2000), Frame(image, 9000, 8000, 10_000),
              Frame(np.full((6, 8), 255, np.uint8), 29_000, 28_000, 30_000)]
    source = tmp_path / "s.aedat4"
    evtools.write(source, events, evtools.StreamInfo(8, 6), frames=frames)
    run("render", source, "--aps", "--window-us", "10000", "--start", "@10000us", "--scale", "1",
        "-o", tmp_path / "aps.png")
    run("render", source, "--window-us", "10000", "--start", "@10000us", "--scale", "1", "-o", tmp_path / "plain.png")
    drawn = cv2.imread(str(tmp_path / "aps.png"))[..., ::-1]
    plain = cv2.imread(str(tmp_path / "plain.png"))[..., ::-1]
    quiet = np.ones((6, 8), bool)
    quiet[2, 3] = quiet[2, 5] = False
    np.testing.assert_array_equal(drawn[quiet], np.repeat(image[quiet][:, None], 3, axis=1))
    np.testing.assert_array_equal(drawn[~quiet], plain[~quiet])
    assert not (plain[quiet] == np.repeat(image[quiet][:, None], 3, axis=1)).all()


def _rpg_folder(folder, events, frames, info):
    """The RPG dataset layout written by plain code: events.txt by evtools' text writer, images.txt and PNGs."""
    import cv2

    (folder / "images").mkdir(parents=True)
    evtools.write(folder / "events.txt", events, info)
    lines = []
    for k, frame in enumerate(frames):
        name = f"images/frame_{k:08d}.png"
        cv2.imwrite(str(folder / name), frame.image)
        lines.append(f"{frame.t_us / 1e6:.6f} {name}")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")


def test_an_rpg_folder_is_read_with_its_images_as_frames(tmp_path):
    """Issue 38: the RPG layout (events.txt, images.txt, images/): its events as the text reader reads them, its
    images as frames at their times (8 and 16 bit), through the command line too (info, bafilter keeps them)."""
    rng = np.random.default_rng(9)
    for dtype in (np.uint8, np.uint16):
        frames = _frames(rng, 4, 20, 10, dtype)
        events = random_events(500, 20, 10, seed=9)
        folder = tmp_path / f"rpg{np.dtype(dtype).itemsize}"
        _rpg_folder(folder, events, frames, evtools.StreamInfo(20, 10))
        back, info, read = evtools.read(folder, frames=True)
        assert_same_events(back, evtools.read(folder / "events.txt")[0])
        assert info.metadata["frame_size"] == (20, 10) and len(read) == 4
        for ours, theirs in zip(read, frames):
            assert ours.t_us == ours.exposure_end_us == theirs.t_us
            np.testing.assert_array_equal(ours.image, theirs.image)
    run("bafilter", tmp_path / "rpg1", "-o", tmp_path / "kept.aedat4")
    assert len(evtools.read(tmp_path / "kept.aedat4", frames=True)[2]) == 4
    assert '"count": 4' in run("info", tmp_path / "rpg1", "--json").stdout.decode()
    # every command that reads one stream takes the folder (render refused it as "a directory", exit 2: a QA sweep)
    run("render", tmp_path / "rpg1", "--aps", "-o", tmp_path / "overlay.png")
    import cv2

    assert cv2.imread(str(tmp_path / "overlay.png")) is not None
    measured = run("metrics", "uniformity", tmp_path / "rpg1", "--json", check=False)
    assert measured.returncode != 2 and b"is a directory" not in measured.stderr, measured.stderr


def test_bad_rpg_folders_are_one_line_errors(tmp_path):
    frames = _frames(np.random.default_rng(2), 3, 8, 6)
    events = random_events(100, 8, 6, seed=2)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert_clean_error(run("info", empty, check=False), "empty", "no events.txt")
    backwards = tmp_path / "backwards"
    _rpg_folder(backwards, events, frames, evtools.StreamInfo(8, 6))
    lines = (backwards / "images.txt").read_text().splitlines()
    (backwards / "images.txt").write_text("\n".join([lines[1], lines[0], lines[2]]) + "\n")
    assert_clean_error(run("info", backwards, check=False), "images.txt", "backwards")
    missing = tmp_path / "missing"
    _rpg_folder(missing, events, frames, evtools.StreamInfo(8, 6))
    (missing / "images" / "frame_00000001.png").unlink()
    assert_clean_error(run("info", missing, check=False), "frame_00000001.png", "no such image")
    (missing / "images" / "frame_00000001.png").write_bytes(b"not a png")
    assert_clean_error(run("info", missing, check=False), "frame_00000001.png", "not a readable image")


def test_aedat3_frame_packets_are_read_as_16_bit_frames(tmp_path):
    """AEDAT 3.1 frame events (libcaer's layout, written by plain code): 16-bit gray frames with their four times,
    the events unchanged, the frames kept by convert to AEDAT 4.0 (a file: its frame size is known upfront) and
    left out with a warning from a pipe."""
    from tests.naive import aedat3_with_frames

    rng = np.random.default_rng(4)
    events = random_events(2000, 24, 16, seed=4)
    frames = [(5_000 + 10_000 * k, 9_000 + 10_000 * k, rng.integers(0, 65536, (16, 24)).astype(np.uint16))
              for k in range(3)]
    path = tmp_path / "davis.aedat3"
    path.write_bytes(aedat3_with_frames(events, frames, 24, 16))
    back, info, read = evtools.read(path, frames=True)
    assert_same_events(back, events)
    assert info.metadata["frame_size"] == (24, 16) and len(read) == 3
    for ours, (begin, end, image) in zip(read, frames):
        assert (ours.exposure_begin_us, ours.exposure_end_us, ours.begin_us, ours.end_us) == (begin, end, begin - 100,
                                                                                               end + 100)
        assert ours.image.dtype == np.uint16
        np.testing.assert_array_equal(ours.image, image)
    run("convert", path, "-o", tmp_path / "kept.aedat4")
    kept = evtools.read(tmp_path / "kept.aedat4", frames=True)[2]
    assert len(kept) == 3 and all(a.same_as(b) for a, b in zip(kept, read))
    piped = run("convert", "-", "-o", tmp_path / "piped.aedat4", input=path.read_bytes())
    assert "3 APS frames left out" in piped.stderr.decode()


def test_a_dsec_sequence_folder_is_read_with_its_images_as_frames(tmp_path):
    """Issue 38: a DSEC sequence (events/left/events.h5 with t_offset, images/left/rectified/*.png,
    images/timestamps.txt, and exposure_timestamps.txt where the release has it), written by a naive writer: the
    events with t_offset added, the colour images as gray frames of their own size at their times and exposures,
    through the command line too; a timestamps file that does not match the images is one line naming it."""
    import cv2

    from tests.naive.dsec import write_dsec_sequence

    rng = np.random.default_rng(12)
    offset = 1_000_000_000
    events = sorted((offset + int(t), int(x), int(y), int(p)) for t, x, y, p in zip(
        rng.integers(0, 400_000, 600), rng.integers(0, 20, 600), rng.integers(0, 10, 600), rng.integers(0, 2, 600)))
    images = [rng.integers(0, 256, (8, 12, 3), dtype=np.uint8) for _ in range(3)]
    times = [offset + 50_000, offset + 150_000, offset + 250_000]
    exposures = [(t - 5_000, t + 5_000) for t in times]
    for name, written in (("with_exposures", exposures), ("without", None)):
        folder = tmp_path / name
        write_dsec_sequence(folder, events, images, times, offset, written)
        back, info, frames = evtools.read(folder, frames=True)
        assert back["t"].tolist() == [e[0] for e in events] and back["x"].tolist() == [e[1] for e in events]
        assert back["p"].tolist() == [bool(e[3]) for e in events]
        assert info.metadata["frame_size"] == (12, 8) and info.metadata["layout"] == "dsec" and len(frames) == 3
        for frame, image, t, (begin, end) in zip(frames, images, times, written or [(t, t) for t in times]):
            assert (frame.t_us, frame.exposure_begin_us, frame.exposure_end_us) == (t, begin, end)
            np.testing.assert_array_equal(frame.image, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    done = run("info", tmp_path / "with_exposures", "--json")
    assert '"count": 3' in done.stdout.decode() and '"width": 640' in done.stdout.decode()  # DSEC's event camera
    assert "sensor size" not in done.stderr.decode()  # (its events.h5 does not store its size: no guess to warn of)
    assert "colour frames are read as gray" in done.stderr.decode()
    run("convert", tmp_path / "with_exposures", "-o", tmp_path / "x.aedat4")
    kept = evtools.read(tmp_path / "x.aedat4", frames=True)[2]
    assert [f.exposure_end_us for f in kept] == [end for _, end in exposures]
    stamps = tmp_path / "without" / "images" / "timestamps.txt"
    stamps.write_text(stamps.read_text() + f"{offset + 300_000}\n")
    assert_clean_error(run("info", tmp_path / "without", check=False), "timestamps.txt", "4 times for 3 images")
    stamps.write_text(f"{offset + 150_000}\n{offset + 50_000}\n{offset + 250_000}\n")
    assert_clean_error(run("info", tmp_path / "without", check=False), "timestamps.txt", "backwards")


def test_what_a_command_cannot_carry_is_said(tmp_path):
    """The IMU and trigger packets of a DV recording where the output has no place for them (HDF5; AEDAT 4.0 carries
    them: tests/test_aedat4.py), the APS/IMU words of a jAER one: bafilter, correct and convert said nothing and the
    samples were gone."""
    recording = data_file("davis346_lab_frames.aedat4")
    out = tmp_path / "out.h5"
    said = run("bafilter", recording, "-o", out).stderr.decode()
    assert "davis346_lab_frames.aedat4: 24 packets of its imu, triggers streams are not in the output" in said
    assert len(evtools.read(out, frames=True)[2]) == 3  # the frames are carried
    said = run("simulate", recording, "--seed", 1, "-o", out).stderr.decode()  # noise added: frames kept too
    assert "24 packets of its imu, triggers streams are not in the output" in said
    assert len(evtools.read(out, frames=True)[2]) == 3
    jaer = tmp_path / "davis.aedat"
    words = np.array([1 << 31, 0, 0x00000800, 5], ">u4")  # an APS sample word, then an ON event (DAVIS layout)
    jaer.write_bytes(b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346red\r\n" + words.tobytes())
    said = run("convert", jaer, "-o", out).stderr.decode()
    assert "1 APS/IMU words are not in the output" in said
    clean = tmp_path / "clean.aedat4"
    evtools.write(clean, random_events(100, 32, 24), evtools.StreamInfo(32, 24))
    assert "not in the output" not in run("convert", clean, "-o", out).stderr.decode()
