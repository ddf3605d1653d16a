"""The fuzz suite (issue 19): mutants of a seed file of every format are read to the end in a child process under a
memory and a time limit; each must read whole or be refused by an evtools error naming the file. A few dozen
mutants per format here (`make fuzz`: 2,000). See tests/fuzz.py. Also the reproducers the campaign found."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.conftest import data_file
from tests.fuzz import FORMATS, ROOT
from tests.helpers import assert_clean_error, run

EXAMPLES = 40


@pytest.mark.parametrize("name", FORMATS)
def test_mutants_read_whole_or_are_refused_cleanly(name):
    data_file("dvxplorer_sample.aedat4")  # the seeds are cut from the shared recordings
    result = subprocess.run([sys.executable, "-m", "tests.fuzz", name, str(EXAMPLES)], cwd=ROOT, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr[-4000:]
    counts = json.loads(result.stdout.strip().splitlines()[-1])
    assert counts["mutants"] == counts["read"] + counts["refused"] >= EXAMPLES // 2


def test_reproducers_give_one_line_errors_naming_the_file(tmp_path):
    """Item 7 and 11 of the issue: a RAW header with a size that is not a number or negative, a CSV whose events
    reach 32767 x 32767 (inferred: refused, with the option to give), a damaged HDF5."""
    bad_number = tmp_path / "a.raw"
    bad_number.write_bytes(b"% evt 3.0\n% format EVT3;width=1280;height=7a0\n% end\n" + bytes(64))
    assert_clean_error(run("info", bad_number, check=False), "a.raw", "not a number")
    negative = tmp_path / "b.raw"
    negative.write_bytes(b"% evt 3.0\n% format EVT3;width=1280;height=-20\n% end\n" + bytes(64))
    assert_clean_error(run("info", negative, check=False), "b.raw", "-20")
    huge = tmp_path / "c.csv"
    huge.write_text("t,x,y,p\n1,32766,32766,1\n2,1,1,0\n")
    assert_clean_error(run("bafilter", huge, "-o", tmp_path / "out.aedat4", check=False), "c.csv", "--sensor-size")
    assert not (tmp_path / "out.aedat4").exists()
    h5 = tmp_path / "d.h5"
    run("convert", data_file("dvxplorer_sample.aedat4"), "-o", h5)
    data = bytearray(h5.read_bytes())
    data[len(data) // 2: len(data) // 2 + 4096] = bytes(4096)  # a zeroed block inside the datasets
    h5.write_bytes(bytes(data))
    damaged = run("info", h5, check=False)
    assert damaged.returncode in (0, 1) and b"Traceback" not in damaged.stderr
    if damaged.returncode:
        assert_clean_error(damaged, "d.h5")


def test_files_cut_inside_their_header_are_refused(tmp_path):
    """AEDAT 2.0 and Prophesee RAW files that end inside a header line used to read as empty streams, exit 0."""
    for name, size, needle in (("dvs128_walk.aedat", 100, "truncated AEDAT 2.0 header"),
                               ("gen41_sample.evt3.raw", 50, "truncated Prophesee RAW header")):
        cut = tmp_path / name
        cut.write_bytes(data_file(name).read_bytes()[:size])
        assert_clean_error(run("info", cut, check=False), str(cut), needle)
