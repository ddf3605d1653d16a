"""Shared fixtures: the real recordings in ../shared/data (skipped when absent, a failure under CI)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

try:  # the repository's formats/ and cli/ are evtools.formats and evtools.cli only once installed (package-dir)
    import evtools.cli  # noqa: F401
    import evtools.formats  # noqa: F401
except ImportError:
    pytest.exit("evtools is not installed in this Python: run `make test`, or `pip install -e '.[test]'` and then "
                "pytest (the tests run the installed `evtools` command too)", returncode=4)

ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = ROOT.parent / "shared" / "data"


def data_file(name: str) -> Path:
    """Path of a reference recording in ../shared/data; skips the test when the folder is absent (never under CI)."""
    path = SHARED_DATA / name
    if not path.exists():
        if os.environ.get("CI") == "true":
            pytest.fail(f"{path} is missing: CI always has ../shared/data")
        pytest.skip(f"reference recording {path} not present (../shared/data is absent)")
    return path


@pytest.fixture(scope="session")
def dvxplorer_events() -> np.ndarray:
    """The 111,954 events of dvxplorer_sample.aedat4 as decoded by the independent `aedat` package."""
    import aedat

    from evtools.events import make_events

    decoder = aedat.Decoder(str(data_file("dvxplorer_sample.aedat4")))
    parts = [packet["events"] for packet in decoder if "events" in packet]
    events = np.concatenate(parts)
    return make_events(events["t"].astype(np.int64), events["x"], events["y"], events["on"])
