"""Simulation benchmark (issue 3): throughput in pixel-frames per second and peak memory of `evtools simulate`.

Two sources, as the issue asks: a 346 x 260 greyscale video of 1000 frames (the report's use; made here with
OpenCV's writer, a moving grating with a drifting dark disc) and ``scene:gradient`` at 640 x 480 (1 s at the
scenes' 1 kHz: 1001 frames), each with v2e's ``clean`` and ``noisy`` presets. For each, two measurements:

- ``simulate``: the pixel model alone (``DvsSimulator.process_labelled``), frames decoded or generated outside
  the timed part (the video's frames are uint8, as ``evtools simulate`` passes them: lin-log from a table; the
  scene's are float32: lin-log computed per pixel);
- ``CLI``: ``evtools simulate SOURCE --preset P -o OUT.aedat4`` end to end (start-up, decoding, writing).

Pixel-frames per second = width x height x frames / seconds; the target is >= 50 million on one core. Every
measurement runs in a fresh process, so its peak RSS (from ``wait4``) is its own.

Run: ``python -m tests.bench.bench_simulate [--frames N] [--dir SCRATCH]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tests.bench.common import measure_child, measure_command

VIDEO_SIZE = (346, 260)
VIDEO_FPS = 100.0
SCENE_SIZE = (640, 480)
SCENE_DURATION = "1s"
PRESETS = ("clean", "noisy")
SEED = 1
TARGET_PIXEL_FRAMES_PER_S = 50e6


def make_video(path: Path, frames: int, size: tuple[int, int] = VIDEO_SIZE, fps: float = VIDEO_FPS) -> None:
    """A greyscale mp4 of a diagonal sine grating moving 0.5 px per frame and a dark disc drifting across it."""
    import cv2

    width, height = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    if not writer.isOpened():
        raise SystemExit(f"OpenCV cannot write {path}")
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    for k in range(frames):
        grating = 128.0 + 60.0 * np.sin(2.0 * np.pi * (x + 0.5 * y - 0.5 * k) / 48.0)
        cx, cy = (0.3 * k) % width, height / 2 + height / 4 * np.sin(k / 50.0)
        disc = ((x - cx) ** 2 + (y - cy) ** 2) < 30.0 ** 2
        grey = np.clip(np.where(disc, 0.3 * grating, grating), 0, 255).astype(np.uint8)
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()


# ---- children: each prints one JSON line ----

def _simulator(width: int, height: int, preset: str):
    from evtools.cli.simulate import model_parameters
    from evtools.simulation import DvsSimulator

    return DvsSimulator(width, height, seed=SEED, **model_parameters(preset, {}))


def _run_timed(simulator, frames) -> dict:
    """Time the pixel model only; the frame iterator (decoding, scene generation) runs outside the clock."""
    spent = fetch = 0.0
    count = events = 0
    iterator = iter(frames)
    while True:
        start = time.perf_counter()
        item = next(iterator, None)
        fetch += time.perf_counter() - start
        if item is None:
            break
        t_us, frame = item
        start = time.perf_counter()
        chunk, _ = simulator.process_labelled(t_us, frame)
        spent += time.perf_counter() - start
        count += 1
        events += len(chunk)
    return {"frames": count, "events": events, "seconds": spent, "frame_seconds": fetch}


def child_video(path: str, preset: str) -> dict:
    from evtools.cli.simulate import video_source

    source = video_source(path, None, None)
    result = _run_timed(_simulator(source.width, source.height, preset), source.frames)
    return {**result, "pixels": source.width * source.height}


def child_scene(name: str, size: str, duration: str, preset: str) -> dict:
    from evtools.cli.options import Duration
    from evtools.cli.simulate import scene_source

    source = scene_source(name, size, Duration().convert(duration, None, None), {})  # "1s" as the CLI reads it
    result = _run_timed(_simulator(source.width, source.height, preset), source.frames)
    return {**result, "pixels": source.width * source.height}


CHILDREN = {"video": child_video, "scene": child_scene}


def measure(*args) -> dict:
    """One child in a fresh interpreter: its JSON result plus its peak RSS in MB."""
    return measure_child("bench_simulate", *args)


def row(source: str, preset: str, what: str, frames: int, pixel_frames: float, events: int | None,
        seconds: float, input_seconds: float | None, peak_mb: float) -> None:
    rate = pixel_frames / seconds
    verdict = "ok" if rate >= TARGET_PIXEL_FRAMES_PER_S else "BELOW"
    events_text = f"{events:,}" if events is not None else ""
    input_text = f"{input_seconds:.2f}" if input_seconds is not None else ""
    print(f"{source:22} {preset:6} {what:9} {frames:7,} {events_text:>11} {seconds:8.2f} {input_text:>8} "
          f"{rate / 1e6:9.1f} {peak_mb:8.0f}  {verdict} {TARGET_PIXEL_FRAMES_PER_S / 1e6:g}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=1000, help="frames of the 346 x 260 video (default 1000)")
    parser.add_argument("--dir", default=None, help="scratch folder (default: a temporary one)")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        name, *rest = args.child
        print(json.dumps(CHILDREN[name](*rest)))
        return

    evtools = str(Path(sys.executable).with_name("evtools"))
    with tempfile.TemporaryDirectory(dir=args.dir) as scratch:
        scratch = Path(scratch)
        video = scratch / "pattern.mp4"
        make_video(video, args.frames)
        # compile (or load) the kernels once, so that no measurement pays for it
        measure("scene", "gradient", "16x16", "10ms", "noisy")
        scene_size = f"{SCENE_SIZE[0]}x{SCENE_SIZE[1]}"
        print(f"pixel-frames/s of the pixel model (simulate; 'input s' = decoding or generating the frames, not "
              f"timed) and of `evtools simulate -o OUT.aedat4` end to end (CLI); seed {SEED}, one process each\n")
        print(f"{'source':22} {'preset':6} {'measured':9} {'frames':>7} {'events':>11} {'seconds':>8} {'input s':>8} "
              f"{'Mpx-fr/s':>9} {'peak MB':>8}  target")
        cases = [
            (f"video {VIDEO_SIZE[0]}x{VIDEO_SIZE[1]}", ("video", video), [str(video)]),
            (f"scene:gradient {scene_size}", ("scene", "gradient", scene_size, SCENE_DURATION),
             ["scene:gradient", "--size", scene_size, "--duration", SCENE_DURATION]),
        ]
        for label, child, command in cases:
            for preset in PRESETS:
                result = measure(*child, preset)
                pixel_frames = result["pixels"] * result["frames"]
                row(label, preset, "simulate", result["frames"], pixel_frames, result["events"], result["seconds"],
                    result["frame_seconds"], result["peak_mb"])
                out = scratch / "out.aedat4"
                cli = measure_command([evtools, "simulate", *command, "--preset", preset, "--seed", str(SEED),
                                       "-o", str(out)])
                row(label, preset, "CLI", result["frames"], pixel_frames, None, cli["seconds"], None, cli["peak_mb"])
                out.unlink()


if __name__ == "__main__":
    main()
