"""Write a small synthetic event stream (a bar sweeping a 346 x 260 sensor, plus sparse noise) with evtools' writer.

Used by ``make demo`` until ``evtools simulate`` exists. Deterministic: the same bytes every run.
"""

import argparse

import numpy as np

from evtools.events import StreamInfo, make_events
from formats import create_events

WIDTH, HEIGHT = 346, 260


def sweeping_bar(duration_us: int = 2_000_000, speed_px_per_s: float = 400.0, seed: int = 0) -> np.ndarray:
    """A vertical bar 8 px wide moving right: ON events at its leading edge, OFF at its trailing edge, plus noise."""
    rng = np.random.default_rng(seed)
    per_column_us = 1e6 / speed_px_per_s
    columns = np.arange(int(duration_us / per_column_us))
    t_edge = (columns * per_column_us).astype(np.int64)
    t = np.repeat(t_edge, HEIGHT)[:, None] + np.array([0, int(8 * per_column_us)])
    x = np.repeat(columns % WIDTH, HEIGHT)
    y = np.tile(np.arange(HEIGHT), len(columns))
    signal = make_events(
        np.concatenate([t[:, 0], t[:, 1]]) + rng.integers(0, 300, 2 * len(x)),
        np.concatenate([x, x]), np.concatenate([y, y]),
        np.concatenate([np.ones(len(x), bool), np.zeros(len(x), bool)]),
    )
    n_noise = int(0.5 * WIDTH * HEIGHT * duration_us * 1e-6)
    noise = make_events(
        rng.integers(0, duration_us, n_noise), rng.integers(0, WIDTH, n_noise),
        rng.integers(0, HEIGHT, n_noise), rng.integers(0, 2, n_noise),
    )
    events = np.concatenate([signal, noise])
    return events[np.argsort(events["t"], kind="stable")].astype(signal.dtype)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    events = sweeping_bar()
    with create_events(args.output, StreamInfo(WIDTH, HEIGHT, metadata={"source": "evtools sample"})) as writer:
        writer.write(events)
    print(f"wrote {len(events):,} events to {args.output}")


if __name__ == "__main__":
    main()
