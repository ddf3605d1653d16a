"""The distribution installs one top-level package, ``evtools`` (the repository's cli/ and formats/ inside it)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_the_wheel_has_one_top_level_package(tmp_path):
    # built from a copy of the sources, so that no earlier build/ folder (setuptools never empties it) can leak
    # stale modules into the wheel, and the repository stays untouched
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    for folder in ("evtools", "cli", "formats"):
        shutil.copytree(ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path),
                            str(source)], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    assert "Warning" not in build.stderr, build.stderr  # (issue 39: "Package 'evtools.data' is absent ...")
    (wheel,) = tmp_path.glob("evtools-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"evtools"}, top
    assert "evtools/cli/main.py" in names and "evtools/formats/aedat4.py" in names
    assert "evtools/_kernels/correct.py" in names and "evtools/metrics/thresholds.py" in names
    assert "evtools/estimation.py" in names and "evtools/estimate.py" not in names
    assert "evtools/data/mlpf.npz" in names  # the shipped weights
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "evtools = evtools.cli:run" in zipfile.ZipFile(wheel).read(entry_points).decode()


def _child(code: str, **environment) -> str:
    env = {key: value for key, value in __import__("os").environ.items() if key != "OPENBLAS_NUM_THREADS"}
    env.update(environment)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          check=True).stdout.strip()


MAIN = """
import sys
from evtools.cli import main
early = 'numpy' in sys.modules
sys.argv = ['evtools', 'info', '--help']
try:
    main.main()
except SystemExit:
    pass
import os
print(early, os.environ.get('OPENBLAS_NUM_THREADS'))
"""


def test_the_command_line_sets_blas_threads_before_numpy_loads():
    """The entry point runs before numpy is imported (``evtools`` loads its names lazily), so its one-thread BLAS
    default takes effect; a user's own setting wins."""
    assert _child(MAIN).split("\n")[-1] == "False 1"
    assert _child(MAIN, OPENBLAS_NUM_THREADS="3").split("\n")[-1] == "False 3"


def test_the_package_names_load_on_first_use():
    out = _child("import sys, evtools; a = 'numpy' in sys.modules; from evtools import read, EVENT_DTYPE, "
                 "StreamInfo; print(a, 'numpy' in sys.modules, read.__module__, sorted(evtools.__all__) == "
                 "sorted(n for n in evtools.__all__ if hasattr(evtools, n)), 'read' in dir(evtools))")
    assert out == "False True evtools.api True True"
    # submodules too, as attributes of the package (evtools.events was one when __init__ imported everything)
    out = _child("import evtools; print(evtools.events.EVENT_DTYPE.itemsize, evtools.metrics.__name__, "
                 "hasattr(evtools, 'no_such_thing'))")
    assert out == "16 evtools.metrics False"


def test_reading_a_file_loads_no_processor(tmp_path):
    """Issue 42 item 4: ``evtools.read`` imports the readers, not correction, estimation, the filters or the
    simulator (each a processor's module); taking a processor from the package documents its keywords then."""
    path = tmp_path / "a.csv"
    path.write_text("t,x,y,p\n0,1,1,1\n5,2,1,0\n")
    heavy = ("evtools.correction", "evtools.estimation", "evtools.filters", "evtools.simulation", "evtools.noise")
    out = _child(f"import sys, inspect, evtools; evtools.read({str(path)!r}); "
                 f"print([m for m in {heavy!r} if m in sys.modules], "
                 "'target' in inspect.signature(evtools.correct).parameters)")
    assert out == "[] True"
