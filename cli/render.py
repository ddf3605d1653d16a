"""``evtools render``: look at a stream (event frames as a PNG or a video) or at a thresholds map (a PNG)."""

from __future__ import annotations

import itertools
import logging
import os
from collections import deque

import click
import numpy as np

from evtools import interrupt
from evtools.cli.options import (FINITE, MICROSECONDS, FiniteRange, TimeBound, check_time_span, figure_path,
                                 merged_alias, read_options)
from evtools.cli.progress import with_progress
from evtools.render import (
    BACKGROUNDS,
    EventFramer,
    MODES,
    RenderError,
    auto_scale,
    check_image_size,
    upscale,
)
from evtools.formats import open_events
from evtools.formats.io import STDIO, atomic_path, output_stream, same_file
from evtools.formats.thresholds import read_thresholds
from evtools.formats.video import quiet_stderr
from evtools.transform import sliced

log = logging.getLogger("evtools")

DEFAULT_WINDOW_US = 33_333
"""One thirtieth of a second: at the default 30 frames per second a video plays in real time."""
DEFAULT_FPS = 30.0
IMAGE_EXTENSIONS = {".png": "PNG image", ".jpg": "JPEG image", ".jpeg": "JPEG image", ".svg": "SVG picture",
                    ".pdf": "PDF document"}
"""Pictures by extension: PNG and JPEG encoded by OpenCV; SVG and PDF (for papers) by matplotlib, the frame embedded
as a raster image the size of the upscaled frame (pixels stay sharp: no smoothing)."""
MANY_FRAMES = 18_000
"""A video reaching this many frames (10 minutes at 30 fps) gets a warning naming --window-us."""
MAX_FRAMES = 1_000_000
"""A video is refused when it would pass this many frames (9 hours at 30 fps; ``--window-us 1`` made a frame for
every microsecond of stream, without end): the error names the count and --window-us, nothing is left."""
VIDEO_FOURCC = {".mp4": ("avc1", "mp4v"), ".avi": ("MJPG",)}
"""Video containers by extension and the codecs OpenCV's FFmpeg backend may write into each, the first it can
open taken: H.264 (``avc1``) where the OpenCV build has an encoder for it (the PyPI wheels do not: patents), else
MPEG-4 Part 2 (``mp4v``), which every player reads."""


def _extension(output: str) -> str:
    extension = os.path.splitext(output)[1].lower()
    if extension not in IMAGE_EXTENSIONS and extension not in VIDEO_FOURCC:
        known = ", ".join([*IMAGE_EXTENSIONS, *VIDEO_FOURCC])
        raise click.BadParameter(f"{output}: cannot tell what to write from the extension; give one of {known}",
                                 param_hint="-o")
    return extension


def _known_colormap(ctx, param, value):
    if value is None:
        return None
    from evtools.render import colormap_table

    try:
        colormap_table(value)
    except RenderError as error:
        raise click.BadParameter(str(error)) from None
    return value


OLD_NAMES = {"fps": "old_fps"}
"""Options with an older, hidden name (``--fps`` is ``--frame-rate``, simulate's name)."""


def _given(ctx: click.Context, name: str) -> bool:
    return any(ctx.get_parameter_source(one) not in (None, click.core.ParameterSource.DEFAULT)
               for one in (name, OLD_NAMES.get(name)) if one)


def _refuse(ctx: click.Context, names: dict[str, str], why: str) -> None:
    for name, option in names.items():
        if _given(ctx, name):
            raise click.UsageError(f"{option} {why}")


@click.command()
@read_options
@click.option("-o", "--output", required=True, metavar="OUT", type=click.Path(dir_okay=False),
              help="OUT.png (or .jpg, .svg, .pdf): one window; OUT.mp4 (or .avi): a video of the whole stream.")
@click.option("--window-us", type=MICROSECONDS, default=DEFAULT_WINDOW_US, show_default=True,
              help="Time window accumulated into one frame, microseconds.")
@click.option("--start", "start", type=TimeBound(), default=None, metavar="TIME",
              help="Start of the first window, from the stream's first event (2s, 500ms), or on the stream's clock "
                   "after @ (@136.6s); default: the first event.")
@click.option("--end", "end", type=TimeBound(), default=None, metavar="TIME",
              help="Events from this time on are not drawn (as --start); a PNG without --window-us shows --start "
                   "to --end as one window.")
@click.option("--scale", type=click.IntRange(1, 64), default=None, metavar="K",
              help="Enlarge K times, nearest neighbour (default: enough for about 480 pixels).")
@click.option("--frame-rate", "fps", type=FiniteRange(min=0.01, max=1000), default=None, metavar="HZ",
              help=f"Video playback rate, frames per second (one frame per window).  [default: {DEFAULT_FPS:g}]")
@click.option("--fps", "old_fps", type=FiniteRange(min=0.01, max=1000), default=None, hidden=True,
              help="The same as --frame-rate (kept for older scripts).")
@click.option("--background", type=click.Choice(sorted(BACKGROUNDS)), default="dark", show_default=True,
              help="Event frames: ON orange and OFF blue on dark, or vermillion and blue on white.")
@click.option("--map", "map_path", type=click.Path(), default=None, metavar="THRESHOLDS.h5",
              help="Draw the thresholds map of this HDF5 file (datasets on, off; optional valid) instead of events.")
@click.option("--range", "value_range", type=FINITE, nargs=2, default=None, metavar="LOW HIGH",
              help="--map: values at the ends of the colour scale (default: the maps' range without outliers).")
@click.option("--mode", type=click.Choice(MODES), default="accumulate",
              show_default=True,
              help="accumulate: each window's events alone; decay: every event adds +-1 that fades by e each window; "
                   "time-surface: each pixel's last event, fading by e each window since.")
@click.option("--colormap", default=None, metavar="NAME", callback=_known_colormap,
              help="decay, time-surface: colour each pixel's signed value (OFF -1 .. ON +1) with this matplotlib "
                   "colormap (coolwarm, RdBu_r, viridis, gray...) instead of the ON/OFF colours; --map: the maps' "
                   "colormap (default viridis).")
@click.option("--caption", is_flag=True,
              help="Write each frame's time window on it (seconds from the first event, and the window's length).")
@click.option("--aps", is_flag=True,
              help="Draw each window over the APS frame (a DAVIS camera's image) whose exposure ended last before "
                   "the window's end: pixels without events show its gray.")
@click.option("--rate", is_flag=True,
              help="Draw the event rate over time (ON, OFF) and the per-pixel rate map of the whole stream "
                   "instead of frames (-o FIG.png, .svg or .pdf).")
@click.pass_context
def render(ctx, input, reading, output, window_us, start, end, scale, fps,
           old_fps, background, map_path, value_range, mode, colormap, caption, aps, rate):
    """Draw IN (default stdin) as event frames, or a thresholds map with --map: users look before they read.

    A frame colours each pixel by the events of one time window: ON (brighter) orange, OFF (darker) blue,
    both as often grey. A PNG shows the window from --start; a video shows every window of the stream.

    \b
    evtools render recording.aedat4 -o frame.png --window-us 10000
    evtools render recording.aedat4 -o part.png --start 1s --end 1.5s --mode decay --colormap coolwarm
    evtools simulate scene:bars --size 128x96 | evtools render -o bars.mp4
    evtools render --map thresholds.h5 -o thresholds.png

    Videos are H.264 where the OpenCV build encodes it, else MPEG-4 Part 2 (the PyPI wheels), which is said.
    """
    fps = merged_alias("--frame-rate", fps, "--fps", old_fps) or DEFAULT_FPS  # (given or not: _refuse asks ctx)
    if rate:
        _refuse(ctx, {"window_us": "--window-us", "start": "--start", "end": "--end", "fps": "--frame-rate",
                      "background": "--background", "map_path": "--map", "value_range": "--range", "scale": "--scale",
                      "mode": "--mode", "colormap": "--colormap", "caption": "--caption", "aps": "--aps"},
                "does not apply to --rate")
        _render_rate(input, output, reading)
        return
    extension = _extension(output)
    if map_path is not None:
        if input != STDIO:
            raise click.UsageError("give either an event stream IN or --map THRESHOLDS.h5, not both")
        _refuse(ctx, {"window_us": "--window-us", "start": "--start", "end": "--end", "fps": "--frame-rate",
                      "background": "--background", "input_format": "--input-format", "sensor_size": "--sensor-size",
                      "aedat2_layout": "--aedat2-layout", "mode": "--mode", "caption": "--caption", "aps": "--aps",
                      "scale": "--scale"},
                "applies to event streams, not to --map (a figure, drawn at print resolution)")
        figure_path(output, "-o", (map_path,))
        if value_range is not None and not value_range[0] < value_range[1]:
            raise click.BadParameter(f"{value_range[0]:g} {value_range[1]:g}: LOW must be below HIGH",
                                     param_hint="'--range'")
        _render_map(map_path, output, value_range, colormap)
        return
    _refuse(ctx, {"value_range": "--range"}, "applies to --map only")
    if colormap is not None and mode == "accumulate":
        raise click.UsageError("--colormap colours --mode decay and time-surface (and --map); accumulate frames use "
                               "the ON/OFF colours of --background")
    check_time_span(start, end)
    if extension in IMAGE_EXTENSIONS:
        _refuse(ctx, {"fps": "--frame-rate"}, "applies to video outputs (.mp4, .avi) only")
    if same_file(output, input):
        raise RenderError(f"{output}: output would overwrite the input; choose another -o")
    with open_events(input, reading) as opened:
        stream = sliced(opened, {"end": end})  # events from --end on are neither drawn nor read
        info = stream.info
        scale = scale or auto_scale(info.width, info.height)
        try:
            check_image_size(info.width, info.height, scale)
        except RenderError as error:
            raise RenderError(f"{output}: {error}") from None
        chunks = iter(stream)
        first = next(chunks, None)  # its first event is where a relative --start counts from
        first_us = None if first is None else int(first["t"][0])
        start_us = None if start is None or first is None else start.resolve(first_us)
        if end is not None and first is not None and extension in IMAGE_EXTENSIONS and not _given(ctx, "window_us"):
            window_us = max(1, end.resolve(first_us) - (first_us if start_us is None else start_us))  # start .. end
        chunks = itertools.chain([] if first is None else [first], chunks)
        framer = EventFramer(info.width, info.height, window_us, start_us=start_us, background=background, mode=mode,
                             colormap=colormap)
        backdrop = _ApsBackdrop(stream, framer) if aps else None
        if extension in IMAGE_EXTENSIONS:
            _render_image(chunks, stream, framer, output, extension, scale, start_us, caption, backdrop)
        else:
            _render_video(chunks, stream, framer, output, extension, scale, fps, start_us, caption, backdrop)
        if backdrop is not None and backdrop.current is None:
            log.warning("%s: no APS frame before the windows drawn (--aps): the events are drawn on the background",
                        stream.name)


def _render_rate(input: str, output: str, reading) -> None:
    from evtools.formats.figures import save_figure
    from evtools.plots import RateCounter, rate_figure

    figure_path(output, "-o")
    if same_file(output, input):
        raise RenderError(f"{output}: output would overwrite the input; choose another -o")
    with open_events(input, reading) as stream:
        counter = RateCounter(stream.info.width, stream.info.height)
        for chunk in with_progress(stream, stream, f"counting {stream.name}"):
            counter.add(chunk)
    if counter.first_us is None:
        raise RenderError(f"{stream.name}: no events to plot (the stream is empty)")
    save_figure(rate_figure(counter, f"event rate of {os.path.basename(stream.name)}"), output)


def _within_frames(chunks, window_us: int, output: str):
    """``chunks``, refused as soon as the time they span asks for more than :data:`MAX_FRAMES` frames (a gap of
    hours between two events once drew empty frames for minutes before the count reached the bound: a QA sweep)."""
    first_us = None
    for chunk in chunks:
        if len(chunk):
            first_us = int(chunk["t"][0]) if first_us is None else first_us
            frames = (int(chunk["t"][-1]) - first_us) // window_us + 1
            if frames > MAX_FRAMES:
                raise RenderError(f"{output}: the events span {frames:,} frames of --window-us {window_us} us: "
                                  f"more than {MAX_FRAMES:,} frames; give a larger --window-us (or --start / --end)")
        yield chunk


def _frames(chunks, framer: EventFramer, backdrop=None):
    """Every window's frame; a stop signal ends them at the next frame (a chunk of a sparse stream drawn with a
    short window holds millions: the reader's own stop, at its next chunk, came minutes later)."""
    for chunk in chunks:
        for window_start_us, frame in framer.process(chunk):
            if interrupt.received() is not None:
                return
            yield window_start_us, frame if backdrop is None else backdrop.under(window_start_us, frame)
    for window_start_us, frame in framer.flush():
        yield window_start_us, frame if backdrop is None else backdrop.under(window_start_us, frame)


class _ApsBackdrop:
    """``--aps``: each window drawn over the APS frame whose exposure ended last before the window's end (frames
    taken from the stream as it is read); a pixel without events shows the frame's gray (16-bit frames by their
    high byte), a pixel outside a frame's region the background."""

    def __init__(self, stream, framer: EventFramer) -> None:
        self.stream, self.framer = stream, framer
        self.pending: deque = deque()
        self.current = None
        self._gray: np.ndarray | None = None

    def under(self, window_start_us: int, frame: np.ndarray) -> np.ndarray:
        self.pending.extend(self.stream.take_frames())
        end_us = window_start_us + self.framer.window_us
        while self.pending and self.pending[0].order_us <= end_us:
            self.current, self._gray = self.pending.popleft(), None
        if self.current is None:
            return frame
        if self._gray is None:
            self._gray = self._gray_of(self.current)
        quiet = (frame == np.array(self.framer.background_rgb, np.uint8)).all(axis=-1)
        out = frame.copy()
        out[quiet] = self._gray[quiet]
        return out

    def _gray_of(self, aps) -> np.ndarray:
        image = aps.image if aps.image.dtype == np.uint8 else (aps.image >> 8).astype(np.uint8)
        rgb = np.broadcast_to(np.array(self.framer.background_rgb, np.uint8),
                              (self.framer.height, self.framer.width, 3)).copy()
        x0, y0 = aps.offset_x, aps.offset_y
        part = image[: max(0, self.framer.height - y0), : max(0, self.framer.width - x0)]
        rgb[y0:y0 + part.shape[0], x0:x0 + part.shape[1]] = part[..., None]
        return rgb


def _nothing_to_draw(name: str, framer: EventFramer, start_us: int | None) -> RenderError:
    if framer.last_t_us is None:
        return RenderError(f"{name}: no events to render (the stream is empty)")
    return RenderError(f"{name}: no events at or after --start {start_us} us (the stream's events run from "
                       f"{framer.first_t_us} us to {framer.last_t_us} us)")


def _write_image(output: str, extension: str, rgb: np.ndarray) -> None:
    if extension in (".svg", ".pdf"):
        import io

        from matplotlib.image import imsave

        buffer = io.BytesIO()
        imsave(buffer, np.ascontiguousarray(rgb), format=extension[1:],
               metadata={"Date": None} if extension == ".pdf" else None)
        encoded = buffer.getvalue()
    else:
        import cv2

        ok, encoded = cv2.imencode(extension, np.ascontiguousarray(rgb[..., ::-1]))
        if not ok:
            raise RenderError(f"{output}: OpenCV could not encode the picture as {extension}")
        encoded = encoded.tobytes()
    with output_stream(output, binary_name=IMAGE_EXTENSIONS[extension], needs_seek=True) as stream:
        stream.write(encoded)


def _captioned(image: np.ndarray, framer: EventFramer, window_start_us: int) -> np.ndarray:
    """``image`` (RGB or BGR: the text is grey) with its window written at the bottom left: seconds since the first
    event, window length."""
    import cv2

    text = f"{(window_start_us - framer.first_t_us) / 1e6:.3f} s  +{framer.window_us / 1e3:g} ms"
    height, width = image.shape[:2]
    size = max(0.35, min(width / 700, 1.5))
    red, green, blue = framer.background_rgb
    colour = (0, 0, 0) if 0.299 * red + 0.587 * green + 0.114 * blue > 128 else (235, 235, 235)
    image = np.ascontiguousarray(image)
    cv2.putText(image, text, (4, height - 6), cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)
    return image


def _render_image(chunks, stream, framer: EventFramer, output: str, extension: str, scale: int, start_us,
                  caption: bool = False, backdrop=None) -> None:
    """The first window only: reading stops as soon as it is complete."""
    first = next(_frames(chunks, framer, backdrop), None)
    if first is None:
        raise _nothing_to_draw(stream.name, framer, start_us)
    window_start_us, frame = first
    if not (frame != framer.palette.table()[1]).any():
        log.warning("%s: no events in the window %d us .. %d us (the stream starts at %d us); the picture is empty",
                    stream.name, window_start_us, window_start_us + framer.window_us, framer.first_t_us)
    image = upscale(frame, scale)
    _write_image(output, extension, _captioned(image, framer, window_start_us) if caption else image)
    log.info("render: %s events in %g ms from %.3f s (%s) -> %s", f"{framer.events_used:,}", framer.window_us / 1e3,
             (window_start_us - framer.first_t_us) / 1e6, framer.mode, output)


def _even(image: np.ndarray, colour) -> np.ndarray:
    """Pad an odd height or width by one row or column: FFmpeg's mp4v drops odd lines instead."""
    height, width = image.shape[:2]
    if height % 2 == 0 and width % 2 == 0:
        return image
    padded = np.empty((height + height % 2, width + width % 2, 3), dtype=np.uint8)
    padded[:] = colour
    padded[:height, :width] = image
    return padded


def _open_video(temporary: str, output: str, extension: str, fps: float, size: tuple[int, int]) -> tuple:
    """An OpenCV VideoWriter with the first codec of :data:`VIDEO_FOURCC` that this build can open (FFmpeg's
    messages while it probes silenced), and that codec's name."""
    import cv2

    codecs = VIDEO_FOURCC[extension]
    for codec in codecs:
        with quiet_stderr():
            writer = cv2.VideoWriter(temporary, cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*codec), fps, size)
        if writer.isOpened():
            return writer, codec
        writer.release()
    raise RenderError(f"{output}: OpenCV cannot write {extension} video (codecs tried: {', '.join(codecs)})")


def _render_video(chunks, stream, framer: EventFramer, output: str, extension: str, scale: int, fps: float,
                  start_us, caption: bool = False, backdrop=None) -> None:
    """Every window as one frame, written as it is made: memory does not grow with the stream. Frames are encoded
    on a second thread (OpenCV releases the GIL) while the next ones are drawn."""
    import cv2

    from evtools.formats.io import WriteBehind

    background_bgr = framer.background_rgb[::-1]
    width, height = framer.width * scale, framer.height * scale
    size = (width + width % 2, height + height % 2)
    # FFmpeg's per-frame warnings ("Failed to write frame") would repeat for every frame of a failure that the
    # checks below report in one line, and its codec probing prints tags it falls back from
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    # cv2 writes to a path and picks the container by its extension: a temporary name beside the target
    with atomic_path(output, suffix=extension) as temporary:
        writer, codec = _open_video(temporary, output, extension, fps, size)
        encoder = WriteBehind(_VideoFrames(writer), depth=4)
        try:
            count = 0
            folder = os.path.dirname(os.path.abspath(temporary))
            bounded = _within_frames(chunks, framer.window_us, output)
            for window_start_us, frame in _frames(with_progress(bounded, stream, f"rendering {stream.name}"), framer,
                                                  backdrop):
                image = upscale(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), scale)
                if caption:
                    image = _captioned(image, framer, window_start_us)
                encoder.write(_even(image, background_bgr))
                count += 1
                if count > MAX_FRAMES:
                    raise RenderError(f"{output}: more than {MAX_FRAMES:,} frames, one per --window-us "
                                      f"{framer.window_us} us; give a larger --window-us (or --start / --end)")
                if count == MANY_FRAMES:
                    log.warning("%s: %d frames so far, one per --window-us %d us: the video will play for more than "
                                "%.0f minutes at %g fps (a larger --window-us makes it shorter)", output, count,
                                framer.window_us, count / fps / 60, fps)
                if count % 32 == 0 and os.statvfs(folder).f_bavail == 0:  # OpenCV only prints write failures
                    raise RenderError(f"{output}: cannot write (No space left on device)")
            if not count:
                raise _nothing_to_draw(stream.name, framer, start_us)
        finally:
            encoder.close()  # the frames queued are encoded, then the writer released
        if os.path.getsize(temporary) == 0:
            raise RenderError(f"{output}: OpenCV wrote an empty video")
        written = cv2.VideoCapture(temporary)
        frames = int(written.get(cv2.CAP_PROP_FRAME_COUNT))
        written.release()
        if frames < count:  # a write that failed without a word (a full disk between two checks)
            raise RenderError(f"{output}: the video holds {frames} of its {count} frames (a full disk?)")
    note = ""
    if codec == "mp4v":
        note = (f"; MPEG-4 Part 2: this OpenCV build has no H.264 encoder (for H.264: ffmpeg -i {output} -c:v libx264 "
                "out.mp4)")
    log.info("render: %s frames of %g ms (%s) from %s events at %g fps -> %s%s", f"{count:,}",
             framer.window_us / 1e3, framer.mode, f"{framer.events_used:,}", fps, output, note)


class _VideoFrames:
    """A VideoWriter as a chunk writer (``write``, ``close``) for :class:`evtools.formats.io.WriteBehind`."""

    def __init__(self, writer) -> None:
        self.writer = writer

    def write(self, image: np.ndarray) -> None:
        self.writer.write(image)

    def close(self) -> None:
        self.writer.release()


def _render_map(path: str, output: str, value_range, colormap=None) -> None:
    """The ON and OFF maps of a thresholds file (its last map, for a series) as a matplotlib figure."""
    from evtools.formats.figures import save_figure
    from evtools.plots import PlotError, map_figure

    thresholds = read_thresholds(path)
    on, off, valid, units = thresholds.on, thresholds.off, thresholds.valid, thresholds.attributes["units"]
    try:
        figure = map_figure(on, off, valid, value_range=value_range, units=units, colormap=colormap)
    except PlotError as error:
        raise RenderError(f"{path}: {error}") from None
    save_figure(figure, output)
